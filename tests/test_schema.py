"""Bulk messages: a typed header plus raw little-endian arrays, decoded as views of the payload;
anything that does not match the schema is refused with a reason, never half-read."""

from __future__ import annotations

import struct

import numpy as np
import pydantic
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ares.core import schema
from ares.core.messages import OccupancyGrid, PointCloud
from ares.core.schema import BulkDecodeError


def cloud(n: int = 1000, seed: int = 0) -> PointCloud:
    rng = np.random.default_rng(seed)
    return PointCloud(
        t=3.25,
        sensor="roof",
        frame="lidar_roof",
        x=rng.normal(size=n).astype("<f4"),
        y=rng.normal(size=n).astype("<f4"),
        z=rng.normal(size=n).astype("<f4"),
        intensity=rng.random(n, dtype=np.float32),
        ring=rng.integers(0, 64, n).astype("u1"),
    )


def test_a_cloud_round_trips_and_its_arrays_view_the_payload():
    sent = cloud()
    payload = schema.encode(sent)
    got = schema.decode(payload, PointCloud)
    assert (got.t, got.sensor, got.frame, got.size) == (3.25, "roof", "lidar_roof", 1000)
    for name in PointCloud.ARRAYS:
        a = getattr(got, name)
        assert np.array_equal(a, getattr(sent, name)) and a.dtype == getattr(sent, name).dtype
        assert not a.flags.owndata and not a.flags.writeable  # a view of the received bytes
        assert a.ctypes.data % a.itemsize == 0  # aligned: fast to read


def test_a_grid_round_trips_with_its_shape():
    cells = np.full((100, 100), 255, dtype="u1")
    cells[40:60, 50] = 100
    grid = OccupancyGrid(t=1.0, frame="base_link", resolution_m=0.2, origin_x=-10.0, origin_y=-10.0, cells=cells)
    got = schema.decode(schema.encode(grid), OccupancyGrid)
    assert got.cells.shape == (100, 100) and np.array_equal(got.cells, cells) and got.resolution_m == 0.2


def test_the_sender_side_checks_the_arrays():
    with pytest.raises(pydantic.ValidationError, match="one entry per point"):
        PointCloud(
            t=0.0,
            sensor="s",
            frame="f",
            x=np.zeros(3, "<f4"),
            y=np.zeros(3, "<f4"),
            z=np.zeros(2, "<f4"),
            intensity=np.zeros(3, "<f4"),
            ring=np.zeros(3, "u1"),
        )
    with pytest.raises(pydantic.ValidationError, match="shape"):
        OccupancyGrid(t=0.0, frame="f", resolution_m=0.2, origin_x=0.0, origin_y=0.0, cells=np.zeros(10, "u1"))
    with pytest.raises(pydantic.ValidationError, match="cannot become"):
        PointCloud(
            t=0.0,
            sensor="s",
            frame="f",
            x=np.zeros(1, "<f4"),
            y=np.zeros(1, "<f4"),
            z=np.zeros(1, "<f4"),
            intensity=np.zeros(1, "<f4"),
            ring=np.array(["a"]),
        )


def test_float64_arrays_become_the_declared_float32():
    n = 4
    c = PointCloud(
        t=0.0,
        sensor="s",
        frame="f",
        x=np.arange(n, dtype=float),
        y=np.zeros(n),
        z=np.zeros(n),
        intensity=np.zeros(n),
        ring=np.zeros(n, dtype="u2"),
    )
    assert c.x.dtype == np.dtype("<f4") and c.ring.dtype == np.dtype("u1")


def _header(payload: bytes) -> tuple[dict, int]:
    import orjson

    (n,) = struct.unpack_from("<I", payload, 4)
    return orjson.loads(payload[8 : 8 + n]), n


def _with_header(payload: bytes, header: dict) -> bytes:
    """The same arrays under another header."""
    import orjson

    _, n = _header(payload)
    arrays = payload[-(-(8 + n) // 8) * 8 :]
    head = orjson.dumps(header)
    start = -(-(8 + len(head)) // 8) * 8
    return (payload[:4] + struct.pack("<I", len(head)) + head).ljust(start, b" ") + arrays


@pytest.mark.parametrize(
    "mutate, reason",
    [
        (lambda p: b"XXXX" + p[4:], "bad magic"),
        (lambda p: p[:6], "bad magic"),
        (lambda p: p[:4] + struct.pack("<I", 10**9) + p[8:], "header runs past"),
        (lambda p: p[:-100], "runs past the payload"),
        (lambda p: p[:8] + b"[" + p[9:], "malformed header"),
    ],
)
def test_broken_payloads_are_refused_with_a_reason(mutate, reason):
    with pytest.raises(BulkDecodeError, match=reason):
        schema.decode(mutate(bytes(schema.encode(cloud()))), PointCloud)


def test_arrays_that_do_not_match_their_declaration_are_refused():
    payload = bytes(schema.encode(cloud()))
    header, _ = _header(payload)
    wrong_dtype = {**header, "arrays": [{**a, "dtype": "<f8"} if a["name"] == "x" else a for a in header["arrays"]]}
    with pytest.raises(BulkDecodeError, match="x: dtype <f8, expected <f4"):
        schema.decode(_with_header(payload, wrong_dtype), PointCloud)
    missing = {**header, "arrays": [a for a in header["arrays"] if a["name"] != "ring"]}
    with pytest.raises(BulkDecodeError, match="expected"):
        schema.decode(_with_header(payload, missing), PointCloud)
    shorter = {**header, "arrays": [{**a, "shape": [999]} if a["name"] == "z" else a for a in header["arrays"]]}
    with pytest.raises(pydantic.ValidationError, match="one entry per point"):
        schema.decode(_with_header(payload, shorter), PointCloud)
    extra_field = {**header, "fields": {**header["fields"], "colour": "red"}}
    with pytest.raises(pydantic.ValidationError, match="colour"):
        schema.decode(_with_header(payload, extra_field), PointCloud)


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=600), st.integers(0, 2000))
def test_garbage_never_escapes_as_anything_but_a_refusal(garbage, cut):
    payload = bytes(schema.encode(cloud(20)))
    for candidate in (garbage, payload[:cut] + garbage, schema.MAGIC + garbage):
        try:
            schema.decode(candidate, PointCloud)
        except (BulkDecodeError, pydantic.ValidationError):
            pass
