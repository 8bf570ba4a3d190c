"""NMEA 0183 from a byte stream, as a receiver's port gives it: framing, epochs and stamps.

Shared by the GNSS driver (drivers/gnss_node.py, which reads a serial port, a TCP stream or gpsd)
and the importer of receiver logs (ares.app.route_import, through `ubx_frame_length`), so that a
u-blox binary frame is recognised in one place.

- `NmeaStream` cuts the bytes into sentences (`$...*hh` and `!...` lines, without their line
  ending), whatever the reads' boundaries: a line split over two reads is whole once its end has
  come. u-blox UBX frames between the sentences (sync B5 62, class, id, little-endian length,
  payload, Fletcher-8 checksum) are skipped and counted when their checksum holds; anything
  else that is not a sentence (binary garbage, a line longer than any sentence, bytes outside
  printable ASCII, a sentence cut short by the next '$') is refused, counted by cause, and
  dropped up to the next '$', '!' or line end. A UBX frame has a byte budget (a claimed payload
  over `max_ubx_payload` is no frame) and a time budget: one still incomplete 100 ms (wall) after
  its sync was read is abandoned ("ubx abandoned") and the bytes after its sync are read again
  as NMEA. Stray bytes that look like a UBX header claiming 8 KB must not hold the NMEA behind
  them for seconds (and a real frame that long is of no use to the driver, which skips UBX).
  It does not check the NMEA checksum or parse the fields: the gnss node does
  (perception.nmea_parser); a bad checksum is the node's to refuse.
- `EpochGroups` gathers the sentences of one receiver epoch (the same time of day: a GGA and its
  GST), which the driver publishes as one GnssSentences message.
- `time_of_day` reads a sentence's time field; `stamp` turns it into stack time.
"""

from __future__ import annotations

import re
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

UBX_SYNC = b"\xb5\x62"
UBX_OVERHEAD = 8  # sync (2), class, id, length (2), checksum (2)
MAX_UBX_PAYLOAD = 8192  # u-blox's largest messages (RXM-RAWX, MGA) stay well below this
MAX_LINE = 256  # NMEA allows 82 characters; proprietary sentences and tag blocks run longer
UBX_WAIT_S = 0.1  # an incomplete UBX frame is waited for this long (wall), no longer
DAY_S = 86400.0

# In a sentence: printable ASCII except '$' and '!', which start the next one. Anything else ends it.
_LINE_END = re.compile(rb"[^\x20\x22\x23\x25-\x7e]")
# Between sentences: what may start something (a sentence, a UBX frame) or end a run of bytes.
_START = re.compile(rb"[$!\xb5\r\n]")
_TOD = re.compile(r"^(\d{2})(\d{2})(\d{2}(?:\.\d+)?)$")
# where each sentence type carries its UTC time of day (field 0 is the address)
_TIME_FIELD = {"GGA": 1, "GST": 1, "RMC": 1, "ZDA": 1, "GNS": 1, "GBS": 1, "GRS": 1, "GLL": 5}

NOT_A_FRAME = 0
INCOMPLETE = -1


def ubx_frame_length(data: bytes | bytearray, start: int, max_payload: int = 0xFFFF) -> int:
    """The length of the UBX frame at `start` (its sync bytes there) if its checksum holds;
    NOT_A_FRAME (0) if it does not, or its length is over `max_payload`; INCOMPLETE (-1) if
    `data` ends before that can be told."""
    if len(data) < start + 6:
        return INCOMPLETE
    length = data[start + 4] | (data[start + 5] << 8)
    if length > max_payload:
        return NOT_A_FRAME
    end = start + length + UBX_OVERHEAD
    if len(data) < end:
        return INCOMPLETE
    # Fletcher-8 over class..payload: A = sum of the bytes, B = sum of the running A's, which is
    # each byte weighted by how many running sums it is in
    body = np.frombuffer(bytes(data[start + 2 : end - 2]), dtype=np.uint8).astype(np.int64)
    a = int(body.sum()) & 0xFF
    b = int((body * np.arange(len(body), 0, -1)).sum()) & 0xFF
    return length + UBX_OVERHEAD if data[end - 2] == a and data[end - 1] == b else NOT_A_FRAME


def time_of_day(line: str) -> float | None:
    """The UTC time of day (s) a sentence carries (GGA, GST, RMC, ZDA, GLL, ...), or None."""
    fields = line.split("*", 1)[0].split(",")
    if not fields[0].startswith("$") or fields[0].startswith("$P") or len(fields[0]) < 4:
        return None  # AIS (!), proprietary ($P...): no time we know where to find
    index = _TIME_FIELD.get(fields[0][-3:])
    if index is None or index >= len(fields):
        return None
    match = _TOD.match(fields[index])
    if match is None:
        return None
    h, m, s = int(match[1]), int(match[2]), float(match[3])
    if h > 23 or m > 59 or s >= 61.0:
        return None
    return h * 3600.0 + m * 60.0 + s


Refuse = Callable[[str, str], None]


class NmeaStream:
    """Incremental NMEA framer: `feed(bytes, read_wall)` -> the sentences completed by them.

    Counts: `sentences`, `ubx_frames` (skipped), `malformed` by cause ("garbage", "too long",
    "non-ASCII", "truncated"); `on_refuse(cause, detail)` hears each refusal as it happens."""

    def __init__(
        self,
        max_line: int = MAX_LINE,
        max_ubx_payload: int = MAX_UBX_PAYLOAD,
        on_refuse: Refuse | None = None,
        ubx_wait_s: float = UBX_WAIT_S,
    ):
        self.max_line = max_line
        self.max_ubx_payload = max_ubx_payload
        self.on_refuse = on_refuse
        self.ubx_wait_s = ubx_wait_s
        self._ubx_since: float | None = None  # when the incomplete UBX frame at the buffer's start was first seen
        self.sentences = 0
        self.ubx_frames = 0
        self.malformed: Counter[str] = Counter()
        self._buf = bytearray()
        self._in_line = False  # _buf starts with a sentence's '$' or '!'
        self._dropping = False  # the bytes up to the next start or line end belong to a refused line

    @property
    def pending(self) -> int:
        """Bytes held for a sentence or frame not complete yet."""
        return len(self._buf)

    def feed(self, data: bytes, read_wall: float) -> list[tuple[str, float]]:
        """The sentences whose last byte is in `data` (read at wall time `read_wall`), in order."""
        self._buf += data
        buf = self._buf
        out: list[tuple[str, float]] = []
        i = 0
        while i < len(buf):
            if self._in_line:
                i = self._line(buf, i, out, read_wall)
                if i < 0:  # not complete yet: keep it from its '$'
                    return out
            else:
                i = self._between(buf, i, read_wall)
                if i < 0:
                    return out
        self._buf = bytearray()
        return out

    def _keep(self, buf: bytearray, start: int) -> int:
        self._buf = buf[start:]
        return -1

    def _line(self, buf: bytearray, start: int, out: list[tuple[str, float]], read_wall: float) -> int:
        """At a sentence's first byte: where scanning goes on, or -1 to wait for more bytes."""
        match = _LINE_END.search(buf, start + 1, start + self.max_line + 1)
        if match is None:
            if len(buf) - start <= self.max_line:
                return self._keep(buf, start)
            self._refuse("too long", bytes(buf[start : start + 40]))
            self._in_line = False
            return start + self.max_line
        end = match.start()
        byte = buf[end]
        self._in_line = False
        if byte in b"\r\n":
            out.append((buf[start:end].decode("ascii"), read_wall))
            self.sentences += 1
            return end + 1
        if byte in b"$!":
            self._refuse("truncated", bytes(buf[start:end]))
            self._in_line = True
            self._dropping = False
            return end
        if buf.startswith(UBX_SYNC, end) and self._frame(buf, end) != NOT_A_FRAME:
            # a binary frame inside a line: the line is lost; the frame is judged next
            self._refuse("truncated", bytes(buf[start:end]))
            self._dropping = False
            return end
        self._refuse("non-ASCII", bytes(buf[start : end + 1]))
        return end + 1

    def _between(self, buf: bytearray, start: int, read_wall: float) -> int:
        """Between sentences: skip to the next start, counting what is skipped."""
        match = _START.search(buf, start)
        end = len(buf) if match is None else match.start()
        if not self._dropping and buf[start:end].strip():
            self._refuse("garbage", bytes(buf[start : start + 40]))
        if match is None:
            return end
        byte = buf[end]
        if byte in b"\r\n":
            self._dropping = False
            return end + 1
        if byte in b"$!":
            self._in_line = True
            self._dropping = False
            return end
        length = self._frame(buf, end)  # 0xB5: a UBX frame, perhaps
        if length == INCOMPLETE:
            if end > 0 or self._ubx_since is None:  # a frame not seen before (a held one waits at 0)
                self._ubx_since = read_wall
            if read_wall - self._ubx_since <= self.ubx_wait_s:
                return self._keep(buf, end)
            self._ubx_since = None  # waited long enough: not a frame; what follows is read again
            self._refuse("ubx abandoned", bytes(buf[end : end + 8]))  # its bytes up to the next start with it
            return end + 1
        self._ubx_since = None
        if length > 0:
            self.ubx_frames += 1
            self._dropping = False
            return end + length
        if not self._dropping:
            self._refuse("garbage", bytes(buf[end : end + 40]))
        return end + 1

    def _frame(self, buf: bytearray, at: int) -> int:
        if len(buf) > at + 1 and buf[at + 1] != UBX_SYNC[1]:
            return NOT_A_FRAME
        if len(buf) == at + 1:
            return INCOMPLETE
        return ubx_frame_length(buf, at, self.max_ubx_payload)

    def _refuse(self, cause: str, sample: bytes) -> None:
        self.malformed[cause] += 1
        self._dropping = True
        if self.on_refuse is not None:
            self.on_refuse(cause, repr(sample[:40]))


@dataclass
class Epoch:
    """The sentences of one receiver epoch, and the wall time its last one was read."""

    tod: float | None
    lines: list[str] = field(default_factory=list)
    read_wall: float = 0.0
    has_gga: bool = False
    has_gst: bool = False


class EpochGroups:
    """Sentences gathered by epoch (the same time of day): an epoch is complete when a sentence of
    another epoch arrives, when `hold_s` (wall) has passed since its last sentence, or as soon as
    the port is drained once it holds a GGA and a GST. Sentences without a time go with the
    current epoch."""

    def __init__(self, hold_s: float):
        self.hold_s = hold_s
        self.current: Epoch | None = None

    def add(self, line: str, read_wall: float) -> Epoch | None:
        """Adds a sentence; returns the epoch it completes, if any."""
        tod = time_of_day(line)
        done = None
        current = self.current
        if current is not None and tod is not None and current.tod is not None and abs(tod - current.tod) > 1e-6:
            done, current = current, None
        if current is None:
            current = self.current = Epoch(tod)
        elif current.tod is None:
            current.tod = tod
        current.lines.append(line)
        current.read_wall = read_wall
        kind = line[3:6] if line.startswith("$") else ""
        current.has_gga |= kind == "GGA"
        current.has_gst |= kind == "GST"
        return done

    def due(self, wall: float, drained: bool) -> Epoch | None:
        """The current epoch if it is complete by time or by content (`drained`: nothing more
        waits on the port)."""
        current = self.current
        if current is None:
            return None
        if wall - current.read_wall >= self.hold_s or (drained and current.has_gga and current.has_gst):
            self.current = None
            return current
        return None
