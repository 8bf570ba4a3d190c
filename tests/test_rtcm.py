"""RTCM 3 framing (ares/core/wire/rtcm.py) on real base stations' streams (tests/data/rtcm, from
gpsd's test suite): every frame found, its CRC-24Q checked, counted by message number, as an
independent parser (pyrtcm) reads the same bytes; a corrupt frame costs no other."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pyrtcm import RTCMReader

from ares.core.wire.rtcm import RtcmStream, crc24q

DATA = Path(__file__).parent / "data" / "rtcm"
F9T = (DATA / "zed-f9t_msm7.rtcm3").read_bytes()
GRAS0 = (DATA / "gras0_1004_1012.rtcm3").read_bytes()


def independent(data: bytes) -> Counter[int]:
    """pyrtcm's message numbers of the stream."""
    import io

    found: Counter[int] = Counter()
    for _raw, parsed in RTCMReader(io.BytesIO(data)):
        found[int(parsed.identity)] += 1
    return found


@pytest.mark.parametrize(
    ("data", "types"),
    [
        (F9T, {1005: 26, 1077: 26, 1087: 26, 1097: 26, 1127: 26, 1230: 26, 4072: 26}),
        (GRAS0, {1004: 83, 1012: 84, 1006: 8, 1008: 8, 1013: 8, 1033: 8}),
    ],
    ids=["u-blox ZED-F9T base, MSM7", "EUREF GRAS0, legacy 1004/1012"],
)
def test_real_streams_frame_as_an_independent_parser_reads_them(data, types):
    stream = RtcmStream()
    frames = stream.feed(data)
    assert dict(stream.by_type) == types == dict(independent(data))
    assert not stream.malformed and stream.pending == 0 and b"".join(f.raw for f in frames) == data
    assert frames[0].station_id is not None


def test_crc24q_of_a_known_frame():
    frame = RtcmStream().feed(F9T)[0]
    assert crc24q(frame.raw[:-3]) == int.from_bytes(frame.raw[-3:], "big")
    assert crc24q(b"") == 0


@settings(max_examples=40, deadline=None)
@given(cuts=st.lists(st.integers(1, 400), max_size=40))
def test_any_chunking_gives_the_same_frames(cuts):
    stream, out, i = RtcmStream(), [], 0
    for n in [*cuts, len(F9T)]:
        out += stream.feed(F9T[i : i + n])
        i += n
    assert [f.raw for f in out] == [f.raw for f in RtcmStream().feed(F9T)]


def test_a_corrupt_frame_and_garbage_cost_no_other_frame():
    frames = RtcmStream().feed(F9T)
    broken = bytearray(frames[3].raw)
    broken[10] ^= 0x55  # a bit error in its payload: its CRC fails
    data = b"".join(f.raw for f in frames[:3]) + b"\x00junk\xff" + bytes(broken) + b"".join(f.raw for f in frames[4:])
    stream = RtcmStream()
    got = stream.feed(data)
    assert [f.raw for f in got] == [f.raw for f in frames[:3] + frames[4:]]
    assert stream.malformed == {"garbage": 1, "bad crc": 1}
    # a stream joined mid-frame (a new NTRIP connection): its first bytes are skipped, not refused
    joined = RtcmStream()
    joined.resync()
    assert len(joined.feed(F9T[50:])) == len(frames) - 1 and not joined.malformed and joined.joined_mid_frame >= 1
