"""RTCM 3 differential corrections: framing and checking, as a receiver's corrections port takes them.

A frame (RTCM 10403.3 §4): the preamble 0xD3, 6 reserved bits (0) and a 10-bit payload length
(up to 1023 bytes), the payload, and a 24-bit CRC (CRC-24Q, polynomial 0x1864CFB) over everything
before it. The payload starts with the 12-bit message number (1005: the base station's position,
1004/1012: legacy GPS/GLONASS observations, 1074-1127: multiple signal messages, 1230: GLONASS
biases) and, for all of those, the 12-bit reference station id.

`RtcmStream.feed(bytes)` cuts any stream (an NTRIP body, a serial port) into frames whatever the
reads' boundaries: a frame whose CRC fails is refused ("bad crc") and the search goes on from the
byte after its preamble, so one corrupt frame costs no other; bytes between frames are "garbage".
(A stray 0xD3 claiming a long frame holds the frames behind it until its length has come, a
second at most at a base station's 1 kB/s; its CRC then fails and they come out.) Frames are
counted by message number. Only whole, checked frames are forwarded to a receiver.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

PREAMBLE = 0xD3
HEADER = 3  # preamble, reserved bits and length
CRC_BYTES = 3
MAX_PAYLOAD = 1023
_POLY = 0x1864CFB


def _crc_table() -> list[int]:
    table = []
    for byte in range(256):
        crc = byte << 16
        for _ in range(8):
            crc <<= 1
            if crc & 0x1000000:
                crc ^= _POLY
        table.append(crc & 0xFFFFFF)
    return table


_TABLE = _crc_table()


def crc24q(data: bytes | bytearray | memoryview) -> int:
    crc = 0
    for byte in data:
        crc = ((crc << 8) & 0xFFFFFF) ^ _TABLE[(crc >> 16) ^ byte]
    return crc


@dataclass(frozen=True)
class RtcmFrame:
    raw: bytes  # the whole frame, preamble to CRC: what a receiver is sent

    @property
    def payload(self) -> bytes:
        return self.raw[HEADER:-CRC_BYTES]

    @property
    def message_type(self) -> int:
        p = self.raw
        return (p[HEADER] << 4) | (p[HEADER + 1] >> 4) if len(p) > HEADER + 1 else 0

    @property
    def station_id(self) -> int | None:
        """The reference station's id (the 12 bits after the message number), where it has one."""
        p = self.raw
        if len(p) < HEADER + 3:
            return None
        return ((p[HEADER + 1] & 0x0F) << 8) | p[HEADER + 2]


class RtcmStream:
    """Incremental RTCM 3 framer: `feed(bytes)` -> the whole, checked frames completed by them.

    Counts: `frames`, `by_type` (message number -> frames), `bytes_in`, `malformed` by cause
    ("bad crc", "garbage", "bad header": reserved bits set)."""

    def __init__(self) -> None:
        self.frames = 0
        self.bytes_in = 0
        self.by_type: Counter[int] = Counter()
        self.malformed: Counter[str] = Counter()
        self._buf = bytearray()
        self._in_garbage = False
        self._joining = False
        self.joined_mid_frame = 0  # refusals before a stream's first whole frame (see resync)

    @property
    def pending(self) -> int:
        return len(self._buf)

    def feed(self, data: bytes | bytearray) -> list[RtcmFrame]:
        self.bytes_in += len(data)
        buf = self._buf
        buf += data
        out: list[RtcmFrame] = []
        i = 0
        while True:
            start = buf.find(PREAMBLE, i)
            if start < 0:
                self._garbage(len(buf) > i)
                i = len(buf)
                break
            self._garbage(start > i)
            if len(buf) < start + HEADER:
                i = start
                break
            if buf[start + 1] & 0xFC:  # reserved bits: not a frame's header
                self._refuse("bad header")
                i = start + 1
                continue
            length = ((buf[start + 1] & 0x03) << 8) | buf[start + 2]
            end = start + HEADER + length + CRC_BYTES
            if len(buf) < end:
                i = start
                break
            body = bytes(buf[start : end - CRC_BYTES])
            if crc24q(body) != int.from_bytes(buf[end - CRC_BYTES : end], "big"):
                self._refuse("bad crc")
                i = start + 1
                continue
            got = RtcmFrame(bytes(buf[start:end]))
            self._joining = False
            self.frames += 1
            self.by_type[got.message_type] += 1
            self._in_garbage = False
            out.append(got)
            i = end
        del buf[:i]
        return out

    def resync(self) -> None:
        """A new stream (a new connection): what comes before its first whole frame is the end of
        a frame already under way when it was joined, skipped (`joined_mid_frame`), not refused."""
        self._buf = bytearray()
        self._joining = True

    def _garbage(self, present: bool) -> None:
        if present and not self._in_garbage:
            self._refuse("garbage")
        if present:
            self._in_garbage = True

    def _refuse(self, cause: str) -> None:
        if self._joining:
            self.joined_mid_frame += 1
        else:
            self.malformed[cause] += 1
        self._in_garbage = True  # what follows up to the next frame belongs to this refusal
