"""NTRIP: RTK corrections from a caster over TCP (the ARES vehicle's over 4G, ARES §3.1, §3.8.1).

The client asks a caster for a mount point's stream and gets RTCM 3 back:

- **Rev 1** (`GET /MOUNT HTTP/1.0`, a `User-Agent` that starts with "NTRIP"): the caster answers
  `ICY 200 OK` and the raw stream follows.
- **Rev 2** (`GET /MOUNT HTTP/1.1`, `Ntrip-Version: Ntrip/2.0`, `Host`): `HTTP/1.1 200 OK`, its
  body often in chunked transfer encoding (un-chunked here). Casters that speak only rev 1
  (RTKLIB's str2str) answer a rev 2 request with `ICY 200 OK`: taken as well.
- Basic authentication (`Authorization: Basic base64(user:password)`); a wrong one: 401.
- An unknown mount point: the caster sends its **source table** (`SOURCETABLE 200 OK`, or a rev 2
  `HTTP/1.1 200 OK` with `Content-Type: gnss/sourcetable`): `STR;` lines, one per mount point,
  up to `ENDSOURCETABLE` (`parse_sourcetable`).
- **GGA upstream:** a VRS caster computes corrections for where the rover is, so the client
  sends the receiver's latest GGA sentence on the same connection, every `gga_interval_s`.

`NtripClient` runs the connection without blocking (a step polls it): connect, request, header,
stream; RTCM frames checked by CRC (ares.core.wire.rtcm); a link that fails, closes or goes
silent is reopened after a back-off that doubles from `backoff_min_s` to `backoff_max_s` and
starts again once data flows. Every state change is kept for the driver to report.
"""

from __future__ import annotations

import base64
import errno
import math
import select
import socket
import time
from collections import Counter
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

from ares.core.wire.rtcm import RtcmFrame, RtcmStream

USER_AGENT = "NTRIP ARES/1.0"
MAX_HEADER = 16384  # a caster's answer header; a source table may run long (its body is kept apart)
MAX_SOURCETABLE = 1 << 20

_RESOLVER = ThreadPoolExecutor(max_workers=1, thread_name_prefix="ntrip-dns")  # a lookup may take seconds

# link states
IDLE, CONNECTING, REQUESTED, STREAMING, FAILED = "idle", "connecting", "requested", "streaming", "failed"


def request(
    mountpoint: str,
    host: str,
    port: int,
    user: str | None,
    password: str | None,
    version: int = 2,
    gga: str | None = None,
) -> bytes:
    """The request for a mount point ("" for the source table), in one piece: some casters drop a
    request that arrives in two writes."""
    path = "/" + mountpoint.lstrip("/")
    lines = [f"GET {path} HTTP/{'1.1' if version == 2 else '1.0'}", f"User-Agent: {USER_AGENT}"]
    if version == 2:
        lines += [f"Host: {host}:{port}", "Ntrip-Version: Ntrip/2.0", "Connection: close"]
    if user is not None:
        token = base64.b64encode(f"{user}:{password or ''}".encode()).decode("ascii")
        lines.append(f"Authorization: Basic {token}")
    if gga and version == 2:
        lines.append(f"Ntrip-GGA: {gga}")
    head = ("\r\n".join(lines) + "\r\n\r\n").encode("ascii")
    return head + (f"{gga}\r\n".encode("ascii") if gga and version == 1 else b"")


@dataclass(frozen=True)
class MountPoint:
    """One `STR` line of a source table (NTRIP 2.0, §2.1: 19 fields)."""

    name: str
    identifier: str
    format: str  # "RTCM 3.2", ...
    format_details: str  # message types and their rates: "1005(10),1077(1),..."
    carrier: int  # 0 none, 1 L1, 2 L1+L2
    nav_system: str  # "GPS+GLO+GAL+BDS"
    network: str
    country: str
    lat: float | None
    lon: float | None
    nmea: bool  # the caster wants the rover's GGA (a VRS or a nearest-base mount point)
    solution: int  # 0 a single base, 1 a network
    authentication: str  # "N" none, "B" basic, "D" digest
    fee: bool
    bitrate: int | None


def _number(text: str) -> float | None:
    try:
        value = float(text)
    except ValueError:
        return None
    return value if math.isfinite(value) else None


def _count(text: str) -> int | None:
    return int(text) if text.isascii() and text.isdigit() else None


def parse_sourcetable(text: str) -> list[MountPoint]:
    """The mount points (STR lines) of a source table; CAS and NET lines and anything else skipped."""
    found = []
    for line in text.splitlines():
        if not line.startswith("STR;"):
            continue
        f = line.split(";")
        f += [""] * (19 - len(f))
        found.append(
            MountPoint(
                name=f[1],
                identifier=f[2],
                format=f[3],
                format_details=f[4],
                carrier=_count(f[5]) or 0,
                nav_system=f[6],
                network=f[7],
                country=f[8],
                lat=_number(f[9]),
                lon=_number(f[10]),
                nmea=f[11] == "1",
                solution=_count(f[12]) or 0,
                authentication=f[15] or "N",
                fee=f[16] == "Y",
                bitrate=_count(f[17]),
            )
        )
    return found


class Dechunker:
    """HTTP/1.1 chunked transfer coding, incrementally: `feed(bytes)` -> the body's bytes."""

    def __init__(self) -> None:
        self._buf = bytearray()
        self._left = 0  # bytes of the current chunk still to come
        self._crlf = 0  # a chunk's closing CRLF still to skip
        self.done = False
        self.error: str | None = None

    def feed(self, data: bytes) -> bytes:
        if self.done or self.error is not None:
            return b""  # nothing more is taken: the caller ends the stream
        self._buf += data
        out = bytearray()
        buf = self._buf
        while buf and not self.done and self.error is None:
            if self._left:
                take = min(self._left, len(buf))
                out += buf[:take]
                del buf[:take]
                self._left -= take
                if not self._left:
                    self._crlf = 2
                continue
            if self._crlf:
                skip = min(self._crlf, len(buf))
                del buf[:skip]
                self._crlf -= skip
                continue
            end = buf.find(b"\r\n")
            if end < 0:
                if len(buf) > 64:
                    self.error = "a chunk size line over 64 bytes"
                break
            size_text = bytes(buf[:end]).split(b";")[0].strip()
            del buf[: end + 2]
            try:
                self._left = int(size_text, 16)
            except ValueError:
                self.error = f"a chunk size that is no number: {size_text[:20]!r}"
                break
            if self._left == 0:
                self.done = True
        return bytes(out)


@dataclass
class Answer:
    """The caster's answer to a request, as far as it has come."""

    status: str = ""  # its first line
    headers: dict[str, str] = field(default_factory=dict)
    kind: str = ""  # "stream", "sourcetable", "unauthorized", "refused", "" (not yet)
    chunked: bool = False


def read_answer(head: bytes) -> Answer:
    """The kind of answer a caster's header (up to its blank line) is."""
    lines = head.decode("latin-1").split("\r\n")
    answer = Answer(status=lines[0].strip())
    for line in lines[1:]:
        if ":" in line:
            name, value = line.split(":", 1)
            answer.headers[name.strip().lower()] = value.strip()
    status = answer.status.upper()
    code = status.split()[1] if len(status.split()) > 1 else ""
    answer.chunked = "chunked" in answer.headers.get("transfer-encoding", "").lower()
    if status.startswith("SOURCETABLE") or "sourcetable" in answer.headers.get("content-type", ""):
        answer.kind = "sourcetable"
    elif status.startswith("ICY 200") or (status.startswith("HTTP/") and code == "200"):
        answer.kind = "stream"
    elif code == "401":
        answer.kind = "unauthorized"
    else:
        answer.kind = "refused"
    return answer


@dataclass(frozen=True)
class NtripSettings:
    host: str
    port: int
    mountpoint: str
    user: str | None = None
    password: str | None = None
    version: int = 2
    gga_interval_s: float = 10.0  # 0: never
    connect_timeout_s: float = 5.0
    silent_after_s: float = 5.0  # streaming, no byte for this long: the link is gone
    backoff_min_s: float = 1.0
    backoff_max_s: float = 30.0


class NtripClient:
    """One caster's mount point, polled without blocking: `poll(wall)` -> the RTCM frames come.

    `state`: idle (waiting to connect), connecting, requested (waiting for the answer), streaming.
    Counts: `connects`, `outages` (a stream that was flowing and stopped), `frames`/`by_type` and
    `malformed` (from the RTCM framer), `bytes_in`, and `last_frame_wall`. `events` holds
    (cause, text) of each failure, for the driver to log once per cause; `mountpoints` the source
    table the caster sent, if it did."""

    def __init__(self, settings: NtripSettings, gga: Callable[[], str | None] = lambda: None):
        self.settings = settings
        self.gga = gga  # the receiver's latest GGA sentence, for a caster that wants it
        self.state = IDLE
        self.rtcm = RtcmStream()
        self.connects = 0
        self.outages = 0
        self.failures = 0  # in a row: the back-off's exponent
        self.events: list[tuple[str, str]] = []
        self.last_error = ""
        self.mountpoints: list[MountPoint] = []
        self.last_frame_wall: float | None = None
        self.gga_sent = 0
        self._sock: socket.socket | None = None
        self._lookup: Future[list[Any]] | None = None
        self._addresses: list[tuple[Any, ...]] | None = None  # (family, kind, proto, address) of the caster
        self._next_address = 0  # the next failure tries the next address
        self._retry_at = 0.0
        self._deadline = 0.0
        self._head = bytearray()
        self._answer: Answer | None = None
        self._dechunk: Dechunker | None = None
        self._table = bytearray()
        self._heard_at = 0.0
        self._gga_due = 0.0
        self._wall = 0.0

    @property
    def frames(self) -> int:
        return self.rtcm.frames

    @property
    def by_type(self) -> Counter[int]:
        return self.rtcm.by_type

    @property
    def malformed(self) -> Counter[str]:
        return self.rtcm.malformed

    @property
    def bytes_in(self) -> int:
        return self.rtcm.bytes_in

    @property
    def where(self) -> str:
        s = self.settings
        return f"{s.host}:{s.port}/{s.mountpoint}"

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def poll(self, wall: float | None = None) -> list[RtcmFrame]:
        wall = time.monotonic() if wall is None else wall
        self._wall = wall
        if self.state == IDLE and wall >= self._retry_at:
            self._connect(wall)
        if self.state == CONNECTING:
            self._finish_connect(wall)
        if self.state in (REQUESTED, STREAMING):
            return self._read(wall)
        return []

    # ---- the connection ----------------------------------------------------------------------
    def _connect(self, wall: float) -> None:
        s = self.settings
        self._head, self._answer, self._dechunk, self._table = bytearray(), None, None, bytearray()
        if self._addresses is None:  # the caster's name, looked up on a thread of its own: DNS may hang
            if self._lookup is None:
                self._lookup = _RESOLVER.submit(socket.getaddrinfo, s.host, s.port, type=socket.SOCK_STREAM)
                self._deadline = wall + s.connect_timeout_s
            if not self._lookup.done():
                if wall > self._deadline:
                    self._lookup = None
                    self._fail(wall, "cannot resolve", f"{s.host}: no answer in {s.connect_timeout_s:g} s")
                return
            try:
                self._addresses = [info[:3] + (info[4],) for info in self._lookup.result()]
            except OSError as exc:
                self._fail(wall, "cannot resolve", f"{s.host}: {exc}")
                return
            finally:
                self._lookup = None
        for family, kind, proto, address in (
            self._addresses[self._next_address :] + self._addresses[: self._next_address]
        ):
            self._next_address = (self._next_address + 1) % len(self._addresses)
            try:
                sock = socket.socket(family, kind, proto)
            except OSError as exc:  # out of descriptors, an address family this host has not
                self._fail(wall, "cannot connect", f"{self.where}: {exc}")
                return
            sock.setblocking(False)
            code = sock.connect_ex(address)
            if code in (0, errno.EINPROGRESS, errno.EWOULDBLOCK):
                self._sock = sock
                self.state = CONNECTING
                self._deadline = wall + s.connect_timeout_s
                return
            sock.close()
            error = errno.errorcode.get(code, str(code))
        self._addresses = None  # looked up again next time: the caster may have moved
        self._fail(wall, "cannot connect", f"{self.where}: {error}")

    def _finish_connect(self, wall: float) -> None:
        assert self._sock is not None  # connecting
        _, writable, _ = select.select([], [self._sock], [], 0)
        if not writable:
            if wall > self._deadline:
                self._fail(wall, "cannot connect", f"{self.where}: no answer in {self.settings.connect_timeout_s:g} s")
            return
        code = self._sock.getsockopt(socket.SOL_SOCKET, socket.SO_ERROR)
        if code:
            self._fail(wall, "cannot connect", f"{self.where}: {errno.errorcode.get(code, code)}")
            return
        s = self.settings
        try:
            self._sock.sendall(request(s.mountpoint, s.host, s.port, s.user, s.password, s.version, self.gga()))
        except OSError as exc:
            self._fail(wall, "cannot connect", f"{self.where}: {exc}")
            return
        self.state = REQUESTED
        self._deadline = wall + s.connect_timeout_s

    def _read(self, wall: float) -> list[RtcmFrame]:
        assert self._sock is not None  # requested or streaming
        chunks = []
        ended: tuple[str, str] | None = None
        while True:
            try:
                data = self._sock.recv(65536)
            except (BlockingIOError, InterruptedError):
                break
            except OSError as exc:
                ended = ("link failed", str(exc))
                break
            if not data:
                ended = ("closed by the caster", self.where)
                break
            chunks.append(data)
        frames = self._frames(chunks, wall)  # what came before a close: a 401, a source table, frames
        if ended is not None:
            if self.state in (REQUESTED, STREAMING):
                if self.state == REQUESTED and self._head:
                    self._refused(wall, read_answer(bytes(self._head)))
                else:
                    self._lost(wall, *ended)
            return frames
        if self.state == REQUESTED and wall > self._deadline:
            self._fail(
                wall, "no answer", f"{self.where}: no answer to the request in {self.settings.connect_timeout_s:g} s"
            )
        elif self.state == STREAMING:
            if wall - self._heard_at > self.settings.silent_after_s:
                self._lost(wall, "silent", f"{self.where}: no byte for {self.settings.silent_after_s:g} s")
            else:
                self._send_gga(wall)
        return frames

    def _frames(self, chunks: list[bytes], wall: float) -> list[RtcmFrame]:
        frames: list[RtcmFrame] = []
        for data in chunks:
            if self.state == REQUESTED:
                data = self._take_header(data, wall)
            if self.state == STREAMING and data:
                self._heard_at = wall
                body = self._dechunk.feed(data) if self._dechunk is not None else data
                got = self.rtcm.feed(body)
                if got:
                    self.last_frame_wall = wall
                    self.failures = 0  # corrections flow: the next failure starts the back-off afresh
                frames += got
                if self._dechunk is not None and (self._dechunk.error or self._dechunk.done):
                    self._lost(wall, "bad answer", f"{self.where}: {self._dechunk.error or 'the stream ended'}")
                    break
            elif self.state == REQUESTED and self._answer is not None and self._answer.kind == "sourcetable":
                self._take_sourcetable(data, wall)
        return frames

    def _take_header(self, data: bytes, wall: float) -> bytes:
        """The answer's header from the first bytes; the rest of `data` is its body."""
        if self._answer is not None:  # a source table's body still coming
            return data
        self._head += data
        end = self._head.find(b"\r\n\r\n")
        first_line = self._head.find(b"\r\n")
        if self._head.upper().startswith(b"ICY 200") and first_line >= 0:
            end, skip = first_line, 2  # rev 1: "ICY 200 OK\r\n", then the stream at once
            if self._head[first_line:].startswith(b"\r\n\r\n"):
                skip = 4
        elif end >= 0:
            skip = 4
        else:
            if len(self._head) > MAX_HEADER:
                self._fail(wall, "bad answer", f"{self.where}: no end of header in {MAX_HEADER} bytes")
            elif self._head.startswith(b"HTTP/1.0 401") or self._head.startswith(b"HTTP/1.1 401"):
                self._refused(wall, read_answer(bytes(self._head)))  # str2str's 401 has no blank line
            return b""
        answer = read_answer(bytes(self._head[:end]))
        body = bytes(self._head[end + skip :])
        self._head = bytearray()
        if answer.kind == "stream":
            self.state = STREAMING
            self.connects += 1
            self.rtcm.resync()  # a live stream is joined mid-frame: its first bytes are no refusal
            self._heard_at = wall
            self._gga_due = wall + (self.settings.gga_interval_s or float("inf"))
            self._dechunk = Dechunker() if answer.chunked else None
            self._answer = answer
            return body
        if answer.kind == "sourcetable":
            self._answer = answer
            self._take_sourcetable(body, wall)
            return b""
        self._refused(wall, answer)
        return b""

    def _take_sourcetable(self, data: bytes, wall: float) -> None:
        assert self._answer is not None  # a source table's answer
        if self._answer.chunked and self._dechunk is None:
            self._dechunk = Dechunker()
        self._table += self._dechunk.feed(data) if self._dechunk is not None else data
        if b"ENDSOURCETABLE" in self._table or len(self._table) > MAX_SOURCETABLE:
            self.mountpoints = parse_sourcetable(self._table.decode("latin-1"))
            names = ", ".join(m.name for m in self.mountpoints[:12]) or "none"
            more = f" and {len(self.mountpoints) - 12} more" if len(self.mountpoints) > 12 else ""
            self._fail(
                wall,
                "no such mount point",
                f"{self.where}: the caster has no mount point {self.settings.mountpoint!r}: {names}{more}",
            )

    def _refused(self, wall: float, answer: Answer) -> None:
        if answer.kind == "unauthorized":
            self._fail(wall, "unauthorized", f"{self.where}: {answer.status} (user {self.settings.user!r})")
        else:
            self._fail(wall, "refused", f"{self.where}: {answer.status or 'no answer'}")

    def _send_gga(self, wall: float) -> None:
        if wall < self._gga_due or self._sock is None:
            return
        self._gga_due = wall + self.settings.gga_interval_s
        sentence = self.gga()
        if not sentence:
            return
        try:
            self._sock.send(sentence.encode("ascii") + b"\r\n")
            self.gga_sent += 1
        except (BlockingIOError, InterruptedError):
            pass  # the kernel's buffer is full: the next one goes at the next interval
        except OSError as exc:
            self._lost(wall, "link failed", str(exc))

    def _lost(self, wall: float, cause: str, detail: str) -> None:
        if self.state == STREAMING:
            self.outages += 1
        self._fail(wall, cause, detail)

    def _fail(self, wall: float, cause: str, detail: str) -> None:
        self.close()
        self.state = IDLE
        delay = min(self.settings.backoff_max_s, self.settings.backoff_min_s * 2**self.failures)
        self.failures += 1
        self._retry_at = wall + delay
        self.last_error = f"{cause}: {detail}"
        self.events.append((cause, f"{detail}; again in {delay:g} s"))

    @property
    def retry_in_s(self) -> float:
        """Seconds to the next try, on the clock `poll` is given."""
        return max(self._retry_at - self._wall, 0.0) if self.state == IDLE else 0.0
