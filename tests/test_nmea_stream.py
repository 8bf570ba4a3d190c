"""The NMEA framer of the GNSS driver (ares.core.wire.nmea_stream): sentences out of a byte
stream however it is cut into reads, u-blox UBX frames skipped and counted, what is not a
sentence refused by cause; epochs grouped by time of day; device times mapped to stack time."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ares.app.route_import import strip_ubx
from ares.core.driver import device_stamp
from ares.core.nmea_framing import sentence
from ares.core.wire.nmea_stream import (
    INCOMPLETE,
    NOT_A_FRAME,
    EpochGroups,
    NmeaStream,
    time_of_day,
    ubx_frame_length,
)
from tests.helpers.gnss import PLACES, short_road
from tests.helpers.receiver_logs import UBLOX_F9P, write_log


def ubx(cls: int, ident: int, payload: bytes) -> bytes:
    """A UBX frame, its Fletcher-8 checksum computed the way u-blox's manual writes it."""
    body = bytes([cls, ident, len(payload) & 0xFF, len(payload) >> 8]) + payload
    a = b = 0
    for byte in body:
        a = (a + byte) & 0xFF
        b = (b + a) & 0xFF
    return b"\xb5\x62" + body + bytes([a, b])


NAV_PVT = ubx(0x01, 0x07, bytes(range(92)))  # with NULs, CRs, LFs and '$' inside
NAV_SAT = ubx(0x01, 0x35, bytes([0x24, 0x0D, 0x0A, 0x21] * 8))
ACK = ubx(0x05, 0x01, b"\x06\x8a")
GGA = sentence("GNGGA,094730.20,4808.22000000,N,01134.50000000,E,4,12,0.7,521.3,M,47.0,M,1.0,0001")
GST = sentence("GNGST,094730.20,0.012,0.010,0.008,35.0,0.010,0.009,0.020")
RMC = sentence("GNRMC,094730.20,A,4808.22000000,N,01134.50000000,E,1.944,90.00,231126,,,R")
GSV = sentence("GPGSV,3,1,10,02,45,123,44,05,60,240,46,07,12,310,38,13,33,045,41")
AIS = "!AIVDM,1,1,,A,13aEOK?P00PD2wVMdLDRhgvL289?,0*26"


BYTE_S = 10 / 115200  # a byte's time on a 115,200 bit/s line (each chunk is read as its last byte arrives)


def frame(data: bytes, chunks: list[int] | None = None) -> tuple[list[str], NmeaStream]:
    stream = NmeaStream()
    out = []
    if chunks is None:
        out = stream.feed(data, 1.0)
    else:
        i = 0
        for n in [*chunks, len(data)]:
            out += stream.feed(data[i : i + n], i * BYTE_S)
            i += n
    return [line for line, _ in out], stream


def test_sentences_split_over_reads_come_whole_with_the_time_their_last_byte_was_read():
    stream = NmeaStream()
    assert stream.feed(GGA[:30].encode(), 1.0) == []
    assert stream.pending == 30
    assert stream.feed(GGA[30:].encode() + b"\r", 2.0) == [(GGA, 2.0)]
    assert stream.feed(b"\n" + GST.encode(), 3.0) == []  # the LF of the CRLF: nothing
    assert stream.feed(b"\n" + AIS.encode() + b"\r\n", 4.0) == [(GST, 4.0), (AIS, 4.0)]
    assert (stream.sentences, stream.pending, dict(stream.malformed)) == (3, 0, {})


@pytest.mark.parametrize("end", [b"\r\n", b"\n", b"\r"])
def test_any_line_end(end):
    lines, stream = frame(end.join(s.encode() for s in (GGA, GST, RMC)) + end)
    assert lines == [GGA, GST, RMC] and not stream.malformed


def test_ubx_frames_between_sentences_are_skipped_and_counted():
    data = GGA.encode() + b"\r\n" + NAV_PVT + GST.encode() + b"\r\n" + NAV_SAT + ACK + RMC.encode() + b"\r\n" + ACK
    lines, stream = frame(data)
    assert lines == [GGA, GST, RMC]
    assert stream.ubx_frames == 4 and not stream.malformed
    # cut anywhere, a frame waits for its end: a frame split over two reads is still one frame
    for cut in range(1, len(data)):
        got, again = frame(data, [cut])
        assert got == lines and again.ubx_frames == 4 and not again.malformed


def test_a_broken_ubx_frame_is_refused_not_skipped():
    broken = bytearray(NAV_PVT)
    broken[-1] ^= 0xFF
    lines, stream = frame(GGA.encode() + b"\r\n" + bytes(broken) + GST.encode() + b"\r\n")
    # its bytes are garbage up to the next start: the '$' inside its payload, which begins a
    # "sentence" its next non-printable byte cuts short; the GST after it is whole
    assert lines == [GGA, GST]
    assert stream.ubx_frames == 0 and stream.malformed["garbage"] >= 1


def test_garbage_long_lines_and_non_ascii_are_refused_by_cause_and_cost_only_themselves():
    data = (
        b"\x00\x17\xfe\xff some noise\r\n"  # line noise between sentences
        + GGA.encode()
        + b"\r\n"
        + b"$GPXTE,"
        + b"9" * 400
        + b"\r\n"  # a line no receiver sends: refused when it passes the limit, up to its end
        + b"$GPGSV,3,1,10,02,45,\xe9\xff,46\r\n"  # non-ASCII bytes inside a sentence
        + b"$GNGGA,0947"  # cut short by the next sentence (bytes lost on the line)
        + GST.encode()
        + b"\r\n"
        + RMC.encode()
        + b"\r\n"
    )
    lines, stream = frame(data)
    assert lines == [GGA, GST, RMC]
    assert dict(stream.malformed) == {"garbage": 1, "too long": 1, "non-ASCII": 1, "truncated": 1}
    # the same, a byte at a time
    got, again = frame(data, [1] * (len(data) - 1))
    assert got == lines and again.malformed == stream.malformed


def test_a_bad_checksum_is_not_the_framers_to_refuse():
    bad = GGA[:-2] + "00"
    lines, stream = frame(f"{bad}\r\n{GST}\r\n".encode())
    assert lines == [bad, GST] and not stream.malformed


def test_the_shared_ubx_scanner_and_the_route_importers_strip_ubx_agree():
    assert ubx_frame_length(NAV_PVT, 0) == len(NAV_PVT)
    assert ubx_frame_length(NAV_PVT[:-1], 0) == INCOMPLETE
    assert ubx_frame_length(NAV_PVT[:5], 0) == INCOMPLETE
    assert ubx_frame_length(NAV_PVT[:-1] + b"\x00", 0) == NOT_A_FRAME
    assert ubx_frame_length(NAV_PVT, 0, max_payload=50) == NOT_A_FRAME
    text = b"\xb5\x62 is not a frame\r\n" + GGA.encode() + b"\r\n"
    assert strip_ubx(text + NAV_PVT + GST.encode() + ACK) == (text + GST.encode(), 2)


F9P_LOG = write_log(short_road(), *PLACES["munich"][:3], UBLOX_F9P)[:200]  # header (not all ASCII), epochs


def receiver_bytes() -> bytes:
    # the log as the receiver's port gives it: UBX frames between some sentences, noise once
    out = bytearray()
    for i, line in enumerate(F9P_LOG):
        out += line.encode("utf-8") + b"\r\n"
        out += (NAV_PVT, NAV_SAT, ACK, b"", b"")[i % 5]
        if i == 77:
            out += b"\x00\x00\xff"
    return bytes(out)


RECEIVER_BYTES = receiver_bytes()
WHOLE, WHOLE_STREAM = frame(RECEIVER_BYTES)


@settings(max_examples=60, deadline=None)
@given(cuts=st.lists(st.integers(0, 300), max_size=60))
def test_any_chunking_of_a_stream_gives_the_same_sentences(cuts):
    lines, stream = frame(RECEIVER_BYTES, cuts)
    assert lines == WHOLE
    assert (stream.ubx_frames, stream.malformed) == (WHOLE_STREAM.ubx_frames, WHOLE_STREAM.malformed)


def test_a_receiver_log_framed():
    lines, stream = WHOLE, WHOLE_STREAM
    sentences = [line for line in F9P_LOG if line.startswith(("$", "!"))]
    assert lines == sentences
    assert stream.ubx_frames == sum(1 for i in range(len(F9P_LOG)) if i % 5 < 3)
    # the header's text lines are not sentences (the first has non-ASCII letters), and the noise
    assert stream.malformed["garbage"] == 4  # three header lines with text, the noise


# ---- time and epochs -----------------------------------------------------------------------------


def test_a_stray_ubx_header_does_not_hold_the_nmea_behind_it():
    """Six bytes that look like a UBX header claiming an 8 KB frame, then the receiver's NMEA at 5 Hz:
    before, every sentence was held until 8 KB had come (6 s at this rate); now the header is
    abandoned 100 ms after its sync was read, and the sentences behind it come out, none lost."""
    stray = b"\xb5\x62\x01\x07\x00\x20"  # NAV-PVT, length 0x2000
    epoch = (GGA + "\r\n" + GST + "\r\n").encode()
    stream = NmeaStream()
    assert stream.feed(epoch, 0.0) != [] and stream.feed(stray, 0.01) == []
    got = []
    for k in range(1, 31):  # an epoch every 0.2 s
        got += [wall for _, wall in stream.feed(epoch, 0.2 * k)]
        if k == 1:
            assert len(got) == 2 and stream.malformed == {"ubx abandoned": 1}  # out at the next read
    assert len(got) == 60 and stream.pending == 0  # every sentence, each when read
    whole = NmeaStream(ubx_wait_s=1e9)  # with no time budget: the stream is held for 8 KB
    whole.feed(stray, 0.0)
    assert all(whole.feed(epoch, 0.2 * k) == [] for k in range(1, 31)) and whole.pending > 3000


def test_time_of_day_of_each_kind():
    assert time_of_day(GGA) == time_of_day(GST) == time_of_day(RMC) == 9 * 3600 + 47 * 60 + 30.2
    assert time_of_day(sentence("GPGLL,4808.22,N,01134.50,E,094731,A,D")) == 9 * 3600 + 47 * 60 + 31
    assert time_of_day(sentence("GPZDA,235959.99,23,11,2026,00,00")) == 86399.99
    for none in (GSV, AIS, sentence("PUBX,00,094730.20,4808.22"), sentence("GPGGA,,,,,,0,00,99.99,,,,,,"), "$GP"):
        assert time_of_day(none) is None
    assert time_of_day(sentence("GPGGA,256000.00,4808.22,N")) is None


def test_an_epochs_sentences_go_together():
    groups = EpochGroups(hold_s=0.05)
    next_gga = GGA.replace("094730.20", "094730.40")
    assert groups.add(GSV, 1.0) is None  # no time: goes with the epoch to come
    assert groups.add(GGA, 1.0) is None and groups.add(RMC, 1.01) is None
    assert groups.due(1.02, drained=True) is None  # no GST yet: wait
    assert groups.add(GST, 1.02) is None
    assert groups.due(1.021, drained=False) is None  # more is coming on the port
    done = groups.due(1.022, drained=True)  # a GGA and its GST, the port drained: at once
    assert done is not None and done.lines == [GSV, GGA, RMC, GST] and done.tod == time_of_day(GGA)
    assert done.read_wall == 1.02
    # without a GST: complete when the next epoch starts, or after hold_s
    assert groups.add(GGA, 2.0) is None
    done = groups.add(next_gga, 2.2)
    assert done is not None and done.lines == [GGA]
    assert groups.due(2.24, drained=True) is None
    done = groups.due(2.26, drained=True)
    assert done is not None and done.lines == [next_gga] and groups.due(9.0, drained=True) is None


def test_stamp_maps_the_time_of_day_onto_stack_time():
    utc_epoch = 1_795_392_000.0 + 9 * 3600 + 47 * 60  # stack time 0 is 09:47:00 UTC
    assert device_stamp(30.5, utc_epoch, 9 * 3600 + 47 * 60 + 30.2, 86400.0) == pytest.approx(30.2, abs=1e-6)
    assert device_stamp(30.5, utc_epoch, None, 86400.0) == 30.5  # no time: now
    assert device_stamp(30.5, utc_epoch, 9 * 3600 + 47 * 60 + 27.0, 86400.0) == 30.5  # more than 2 s old: now
    assert device_stamp(30.5, utc_epoch, 9 * 3600 + 47 * 60 + 30.6, 86400.0) == 30.5  # ahead of the clock: now
    # across midnight: 23:59:59.8 read at 00:00:00.1 the next day
    midnight = 1_795_392_000.0 + 86400 - 100.0  # stack time 100 is midnight
    assert device_stamp(100.1, midnight, 86399.8, 86400.0) == pytest.approx(99.8, abs=1e-6)
