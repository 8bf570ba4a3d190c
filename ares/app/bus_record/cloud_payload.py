"""A point cloud's bus payload stored compactly in a recording, and given back byte for byte.

On the bus a sweep travels as the bulk format of ares/core/schema.py: float32 x, y, z and
intensity and a ring byte, 17 bytes a point. A recording keeps instead the points' integers on the
sensor's grid (ares/core/cloud_grid.py: ring, azimuth step, range step, intensity byte) with the
payload's own header, verbatim, so the payload can be rebuilt exactly:

    b"ARG1" | u32 header length | the bulk header (JSON, as it travelled) | u32 points | u32 off-grid
    | ring | azimuth deltas, low bytes | high bytes | range deltas, low | high | intensity
    | off-grid indices (u32) | their x, y, z, intensity (float32)

Each column of bytes on its own, and the azimuths and ranges as differences from the point
before (mod 2^16), because that is what the chunk's zstd then compresses best (docs/recording.md:
1.8 bytes a point from 17; the float32 payload itself compresses to 11). A payload that is not a
well-formed cloud, or whose points are mostly off the grid, is stored as it travelled.
"""

from __future__ import annotations

import struct

import numpy as np
import orjson

from ares.core import cloud_grid
from ares.core.schema import ALIGN, MAGIC

GRID_MAGIC = b"ARG1"
ENCODING = "ares.cloud-grid"  # the channel's message encoding
_U32 = struct.Struct("<I")
_ARRAYS = (("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4"), ("ring", "|u1"))
MAX_OFF_GRID_SHARE = 0.25  # beyond, the integers no longer pay: the payload is stored as it is


class CloudPayloadError(ValueError):
    pass


def _layout(head: bytes, payload_len: int) -> tuple[int, int] | None:
    """(start of the arrays, points) of a cloud payload laid out as ares.core.schema.encode_bulk
    lays it out; None for anything else."""
    try:
        described = orjson.loads(head)["arrays"]
    except (orjson.JSONDecodeError, KeyError, TypeError):
        return None
    if not isinstance(described, list) or len(described) != len(_ARRAYS):
        return None
    n = None
    offset = 0
    for d, (name, dtype) in zip(described, _ARRAYS, strict=True):
        if not isinstance(d, dict) or d.get("name") != name or d.get("dtype") != dtype:
            return None
        shape = d.get("shape")
        if not (isinstance(shape, list) and len(shape) == 1 and isinstance(shape[0], int)):
            return None
        n = shape[0] if n is None else n
        if shape[0] != n or d.get("offset") != offset:
            return None
        offset += -(-n * np.dtype(dtype).itemsize // ALIGN) * ALIGN
    start = -(-(8 + len(head)) // ALIGN) * ALIGN
    if n is None or start + offset != payload_len:
        return None
    return start, n


def _split(values: np.ndarray) -> tuple[bytes, bytes]:
    delta = np.diff(values, prepend=np.uint16(0)).astype(np.uint16)  # wraps mod 2^16
    as_bytes = delta.view(np.uint8)
    return as_bytes[0::2].tobytes(), as_bytes[1::2].tobytes()


def _join(low: np.ndarray, high: np.ndarray) -> np.ndarray:
    delta = np.empty(len(low), dtype=np.uint16)
    as_bytes = delta.view(np.uint8)
    as_bytes[0::2], as_bytes[1::2] = low, high
    return np.cumsum(delta, dtype=np.uint16)  # the sum wraps as the differences did


def grid_from(described: dict) -> cloud_grid.Grid:
    """The grid a channel's metadata describes (Grid.describe); ValueError for one it does not."""
    kind = described.get("kind", "sensor")
    try:
        if kind == "sensor":
            return cloud_grid.SensorGrid(tuple(float(e) for e in described["elevations_deg"]))
        if kind == "velodyne":
            from ares.core.wire.velodyne_grid import VelodyneGrid

            return VelodyneGrid.from_description(described)
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"a {kind} grid described without {exc}") from None
    raise ValueError(f"an unknown kind of grid: {kind!r}")


def compact(payload: bytes | bytearray | memoryview, grid: cloud_grid.Grid) -> tuple[bytes, int]:
    """(what the recording stores, points off the grid); the payload itself when it does not pay."""
    view = memoryview(payload)
    if view.nbytes < 8 or bytes(view[:4]) != MAGIC:
        return bytes(view), 0
    head_len = _U32.unpack_from(view, 4)[0]
    head = bytes(view[8 : 8 + head_len])
    layout = _layout(head, view.nbytes)
    if layout is None:
        return bytes(view), 0
    start, n = layout
    arrays = {}
    offset = start
    for name, dtype in _ARRAYS:
        arrays[name] = np.frombuffer(view, dtype=dtype, count=n, offset=offset)
        offset += -(-n * np.dtype(dtype).itemsize // ALIGN) * ALIGN
    on_grid = cloud_grid.to_grid(grid, arrays["x"], arrays["y"], arrays["z"], arrays["intensity"], arrays["ring"])
    if len(on_grid.off) > MAX_OFF_GRID_SHARE * max(n, 1):
        return bytes(view), len(on_grid.off)
    parts = [
        GRID_MAGIC,
        _U32.pack(len(head)),
        head,
        _U32.pack(n),
        _U32.pack(len(on_grid.off)),
        on_grid.ring.tobytes(),
        *_split(on_grid.azimuth),
        *_split(on_grid.range),
        on_grid.intensity.tobytes(),
        on_grid.off.astype("<u4").tobytes(),
        on_grid.off_xyzi.astype("<f4").tobytes(),
    ]
    return b"".join(parts), len(on_grid.off)


def restore(stored: bytes | memoryview, grid: cloud_grid.Grid | None) -> bytes:
    """The payload as it travelled on the bus."""
    view = memoryview(stored)
    if bytes(view[:4]) != GRID_MAGIC:
        return bytes(view)  # stored as it travelled
    if grid is None:
        raise CloudPayloadError("a cloud on a sensor grid, but the channel names no grid")
    try:
        head_len = _U32.unpack_from(view, 4)[0]
        head = bytes(view[8 : 8 + head_len])
        at = 8 + head_len
        n, k = _U32.unpack_from(view, at)[0], _U32.unpack_from(view, at + 4)[0]
        at += 8
        planes = []
        for _ in range(6):
            planes.append(np.frombuffer(view, dtype=np.uint8, count=n, offset=at))
            at += n
        off = np.frombuffer(view, dtype="<u4", count=k, offset=at).astype(np.intp)
        off_xyzi = np.frombuffer(view, dtype="<f4", count=4 * k, offset=at + 4 * k).reshape(k, 4)
    except (struct.error, ValueError) as exc:
        raise CloudPayloadError(f"a malformed cloud on a sensor grid: {exc}") from None
    cloud = cloud_grid.GridCloud(
        ring=planes[0],
        azimuth=_join(planes[1], planes[2]),
        range=_join(planes[3], planes[4]),
        intensity=planes[5],
        off=off,
        off_xyzi=off_xyzi,
    )
    columns = dict(zip(("x", "y", "z", "intensity"), cloud_grid.from_grid(grid, cloud), strict=True))
    columns["ring"] = planes[0]
    start = -(-(8 + head_len) // ALIGN) * ALIGN
    out = bytearray(start)
    out[:4] = MAGIC
    _U32.pack_into(out, 4, head_len)
    out[8 : 8 + head_len] = head
    for name, dtype in _ARRAYS:
        data = np.ascontiguousarray(columns[name], dtype=dtype).tobytes()
        out += data
        out += bytes(-len(data) % ALIGN)
    return bytes(out)
