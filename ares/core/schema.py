"""Message base classes and their wire formats.

Small messages are `Msg`: JSON, validated on receipt (extra fields, missing fields, wrong types
and non-finite numbers are all rejected). Every message carries `t`, the stack time (s) at which
it was produced; freshness is always judged from it.

Bulk messages: a small typed header plus raw little-endian arrays, decoded without a copy.
Point clouds (three LiDARs, ~190,000 points every 100 ms) and occupancy grids are too big for
JSON. A `BulkMsg` is a pydantic model whose scalar fields form a JSON header and whose
`Array(...)` fields are numpy arrays of a declared dtype and shape. On the wire:

    b"ARB1" | u32 header length | header JSON | padding to 8 bytes | array 1 | padding | array 2 ...

The header carries the scalar fields and, for each array, its dtype, shape and byte offset.
Decoding checks the magic, the header against the schema, each array's dtype and shape against
its declaration and its bytes against the payload's length, then returns `np.frombuffer` views
of the received payload: read-only, and not a byte copied. A message whose arrays disagree with
each other (points of different lengths) fails the model's own validator, like any bad message.
"""

from __future__ import annotations

import math
import struct
from typing import Any, ClassVar, TypeVar, cast

import numpy as np
import orjson
import pydantic
from pydantic import BaseModel, ConfigDict

MAGIC = b"ARB1"
ALIGN = 8
_HEADER_LEN = struct.Struct("<I")

Payload = bytes | bytearray  # what encode gives: a big bulk message stays a bytearray, one copy fewer


class Msg(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    t: float = 0.0

    @classmethod
    def schema_name(cls) -> str:
        return cls.__name__


M = TypeVar("M", bound=Msg)


def encode_json(msg: Msg) -> bytes:
    # the model's serializer called straight: model_dump_json with its defaults, the same bytes,
    # less its per-call overhead and str round trip (a good part of a small message's cost)
    return msg.__pydantic_serializer__.to_json(msg)


def decode_json(payload: Payload, schema: type[M]) -> M:
    # likewise model_validate_json's own validator, on the bytes as received
    return cast(M, schema.__pydantic_validator__.validate_json(payload))


class BulkDecodeError(ValueError):
    pass


class Array:
    """Declares an array field: its dtype (little-endian) and shape, None for any length."""

    def __init__(self, dtype: str, shape: tuple[int | None, ...] = (None,), doc: str = ""):
        self.dtype = np.dtype(dtype).newbyteorder("<") if np.dtype(dtype).itemsize > 1 else np.dtype(dtype)
        self.shape = tuple(shape)
        self.doc = doc

    def check(self, name: str, value: Any) -> np.ndarray:
        arr = np.asarray(value)
        if arr.dtype != self.dtype:
            if not np.can_cast(arr.dtype, self.dtype, casting="same_kind"):
                raise ValueError(f"{name}: dtype {arr.dtype} cannot become {self.dtype}")
            arr = arr.astype(self.dtype)  # sender side only: received arrays already match
        if arr.ndim != len(self.shape) or any(w is not None and w != n for w, n in zip(self.shape, arr.shape)):
            raise ValueError(f"{name}: shape {arr.shape}, expected {self.describe_shape()}")
        return arr

    def describe_shape(self) -> str:
        return (
            "("
            + ", ".join("n" if w is None else str(w) for w in self.shape)
            + ("," if len(self.shape) == 1 else "")
            + ")"
        )


class BulkMsg(Msg):
    """Base of the bulk messages: declare arrays as `name: Annotated[np.ndarray, Array(...)]`."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, arbitrary_types_allowed=True)

    ARRAYS: ClassVar[dict[str, Array]] = {}

    @classmethod
    def __pydantic_init_subclass__(cls, **kwargs: Any) -> None:
        super().__pydantic_init_subclass__(**kwargs)
        cls.ARRAYS = {
            name: spec for name, field in cls.model_fields.items() for spec in field.metadata if isinstance(spec, Array)
        }

    @pydantic.model_validator(mode="before")
    @classmethod
    def _arrays(cls, data: Any) -> Any:
        if isinstance(data, dict):
            data = dict(data)
            for name, spec in cls.ARRAYS.items():
                if name in data:
                    data[name] = spec.check(name, data[name])
        return data

    def header_fields(self) -> dict[str, Any]:
        return self.model_dump(exclude=set(self.ARRAYS))


B = TypeVar("B", bound=BulkMsg)


def encode_bulk(msg: BulkMsg) -> Payload:
    header = msg.header_fields()
    arrays = []
    offset = 0
    chunks: list[tuple[int, memoryview]] = []
    for name in msg.ARRAYS:
        arr = np.ascontiguousarray(getattr(msg, name))
        arrays.append({"name": name, "dtype": arr.dtype.str, "shape": list(arr.shape), "offset": offset})
        chunks.append((offset, arr.data.cast("B")))
        offset += -(-arr.nbytes // ALIGN) * ALIGN
    head = orjson.dumps({"fields": header, "arrays": arrays})
    start = -(-(len(MAGIC) + _HEADER_LEN.size + len(head)) // ALIGN) * ALIGN
    out = bytearray(start + offset)
    out[:4] = MAGIC
    _HEADER_LEN.pack_into(out, 4, len(head))
    out[8 : 8 + len(head)] = head
    for at, data in chunks:
        out[start + at : start + at + data.nbytes] = data
    return bytes(out) if len(out) < 65536 else out  # bytearray avoids one more copy of a big payload


def decode_bulk(payload: bytes | bytearray | memoryview, schema: type[B]) -> B:
    """The message, its arrays viewing `payload` (no copy). BulkDecodeError or
    pydantic.ValidationError on anything that does not match the schema."""
    view = memoryview(payload)
    if view.nbytes < 8 or bytes(view[:4]) != MAGIC:
        raise BulkDecodeError("not a bulk message (bad magic)")
    (head_len,) = _HEADER_LEN.unpack_from(view, 4)
    if 8 + head_len > view.nbytes:
        raise BulkDecodeError("header runs past the payload")
    try:
        head = orjson.loads(view[8 : 8 + head_len])
        fields, described = dict(head["fields"]), list(head["arrays"])
    except (orjson.JSONDecodeError, KeyError, TypeError, ValueError) as exc:
        raise BulkDecodeError(f"malformed header: {exc}") from None
    start = -(-(8 + head_len) // ALIGN) * ALIGN
    # the description is checked field by field before numpy sees any of it: a hostile header
    # must cost no more than a well-formed one, and fail as a refusal, not as numpy's exception
    if not all(isinstance(d, dict) and set(d) == {"name", "dtype", "shape", "offset"} for d in described):
        raise BulkDecodeError("malformed header: each array needs exactly name, dtype, shape and offset")
    names = [d["name"] for d in described]
    if not all(isinstance(n, str) for n in names) or sorted(names) != sorted(schema.ARRAYS):
        raise BulkDecodeError(f"arrays {names!r:.200}, expected {sorted(schema.ARRAYS)}")
    for d in described:
        spec = schema.ARRAYS[d["name"]]
        if d["dtype"] != spec.dtype.str:
            raise BulkDecodeError(f"array {d['name']}: dtype {str(d['dtype'])[:20]}, expected {spec.dtype.str}")
        shape, offset = d["shape"], d["offset"]
        if not (
            isinstance(shape, list)
            and len(shape) == len(spec.shape)
            and isinstance(offset, int)
            and all(isinstance(n, int) and n >= 0 for n in shape)
            and offset >= 0
        ):
            raise BulkDecodeError(f"array {d['name']}: bad shape or offset")
        count = math.prod(shape)
        if start + offset + count * spec.dtype.itemsize > view.nbytes:
            raise BulkDecodeError(f"array {d['name']}: runs past the payload")
        fields[d["name"]] = np.frombuffer(view, dtype=spec.dtype, count=count, offset=start + offset).reshape(shape)
    return schema.model_validate(fields)


def encode(msg: Msg) -> Payload:
    return encode_bulk(msg) if isinstance(msg, BulkMsg) else encode_json(msg)


def decode(payload: Payload, schema: type[M]) -> M:
    """Validate one payload against its schema; pydantic.ValidationError or BulkDecodeError."""
    if issubclass(schema, BulkMsg):
        return decode_bulk(payload, schema)
    return decode_json(payload, schema)


def is_bulk(schema: type[Msg]) -> bool:
    return issubclass(schema, BulkMsg)
