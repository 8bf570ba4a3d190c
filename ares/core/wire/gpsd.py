"""Byte streams over TCP without blocking, and a minimal client of gpsd's JSON protocol.

`TcpStream` is a non-blocking TCP connection (the connect too): a receiver's NMEA server is read
with it directly, and gpsd through `GpsdClient`. The client sends
`?WATCH={"enable":true,"nmea":true}` (gpsd then passes the receiver's NMEA through as it comes,
instead of its own JSON reports), keeps what gpsd says about itself (VERSION, DEVICES, DEVICE,
WATCH) for the driver's status, and hands the NMEA lines on as bytes to the same framer as a
serial port's (ares.core.wire.nmea_stream.NmeaStream). gpsd's protocol:
https://gpsd.gitlab.io/gpsd/gpsd_json.html
"""

from __future__ import annotations

import errno
import json
import select
import socket
from collections.abc import Callable

GPSD_PORT = 2947
READ_SIZE = 65536
MAX_JSON_LINE = 65536  # gpsd's longest report (a SKY with many satellites) is a few kB


class TcpStream:
    """A TCP connection opened and read without blocking: `read()` gives what has arrived (b""
    while nothing has, or while the connection is still being made) and raises ConnectionError
    when the peer has closed it or refused it."""

    def __init__(self, host: str, port: int):
        self.address = (host, port)
        info = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0]
        self.sock = socket.socket(info[0], info[1], info[2])
        self.sock.setblocking(False)
        self.established = False
        self._closed = False  # the peer closed it after the last bytes read
        err = self.sock.connect_ex(info[4])
        if err not in (0, errno.EINPROGRESS, errno.EWOULDBLOCK):
            self.sock.close()
            raise ConnectionRefusedError(err, f"cannot connect to {host}:{port}: {errno.errorcode.get(err, err)}")
        self.established = err == 0

    def fileno(self) -> int:
        return self.sock.fileno()

    def _ready(self) -> bool:
        if self.established:
            return True
        _, writable, _ = select.select([], [self.sock], [], 0)
        if not writable:
            return False
        err = self.sock.getsockopt(socket.SOL_SOCKET, socket.SO_ERROR)
        if err:
            raise ConnectionRefusedError(err, f"cannot connect to {self.address[0]}:{self.address[1]}")
        self.established = True
        return True

    def read(self) -> bytes:
        if self._closed:
            raise ConnectionResetError(f"{self.address[0]}:{self.address[1]} closed the connection")
        if not self._ready():
            return b""
        chunks: list[bytes] = []
        while True:
            try:
                data = self.sock.recv(READ_SIZE)
            except (BlockingIOError, InterruptedError):
                break
            if not data:
                if chunks:  # what came before the end is still good
                    self._closed = True
                    break
                raise ConnectionResetError(f"{self.address[0]}:{self.address[1]} closed the connection")
            chunks.append(data)
            if len(data) < READ_SIZE:
                break
        return b"".join(chunks)

    def send(self, data: bytes) -> bool:
        """Sends `data` once connected; False while the connection is still being made."""
        if not self._ready():
            return False
        self.sock.sendall(data)  # a few bytes on a fresh connection: never blocks
        return True

    def send_some(self, data: bytes) -> int:
        """Sends what the socket takes now, without waiting; how much that was (0 while connecting)."""
        if not self._ready():
            return 0
        try:
            return self.sock.send(data)
        except (BlockingIOError, InterruptedError):
            return 0

    def close(self) -> None:
        self.sock.close()


class GpsdClient:
    """gpsd's NMEA pass-through: `read()` gives the receiver's NMEA lines (with their line ends),
    what gpsd says about itself kept in `version`, `devices` and `watching`. A JSON line that is
    not JSON goes to `on_refuse("gpsd JSON", ...)`."""

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = GPSD_PORT,
        device: str | None = None,
        on_refuse: Callable[[str, str], None] | None = None,
    ):
        self.stream = TcpStream(host, port)
        watch: dict[str, object] = {"enable": True, "nmea": True}
        if device:
            watch["device"] = device
        self._watch = f"?WATCH={json.dumps(watch, separators=(',', ':'))}\n".encode()
        self._sent = False
        self.on_refuse = on_refuse
        self.version = ""  # gpsd's release
        self.devices: list[str] = []  # the receivers gpsd serves (their paths)
        self.watching = False  # gpsd has confirmed the WATCH
        self._partial = b""

    def fileno(self) -> int:
        return self.stream.fileno()

    @property
    def detail(self) -> str:
        devices = ", ".join(self.devices) or "no device yet"
        return f"gpsd {self.version or '?'} at {self.stream.address[0]}:{self.stream.address[1]}: {devices}"

    def read(self) -> bytes:
        """The NMEA lines that have arrived (complete lines, with their ends); ConnectionError
        when gpsd has gone."""
        if not self._sent:
            self._sent = self.stream.send(self._watch)
            if not self._sent:
                return b""
        data = self._partial + self.stream.read()
        lines = data.split(b"\n")
        self._partial = lines.pop()
        if len(self._partial) > MAX_JSON_LINE:
            self._refuse("too long", self._partial[:40])
            self._partial = b""
        nmea = []
        for line in lines:
            if line.startswith(b"{"):
                self._report(line)
            else:
                nmea.append(line + b"\n")
        return b"".join(nmea)

    def _report(self, line: bytes) -> None:
        try:
            report = json.loads(line)
        except ValueError:
            self._refuse("gpsd JSON", line[:40])
            return
        if not isinstance(report, dict):
            self._refuse("gpsd JSON", line[:40])
            return
        kind = report.get("class")
        if kind == "VERSION":
            self.version = str(report.get("release", ""))
        elif kind == "DEVICES":
            self.devices = [str(d.get("path", "?")) for d in report.get("devices", []) if isinstance(d, dict)]
        elif kind == "DEVICE":
            path = str(report.get("path", "?"))
            if report.get("activated") in (0, None, "") and "activated" in report:  # closed by gpsd
                self.devices = [d for d in self.devices if d != path]
            elif path not in self.devices:
                self.devices.append(path)
        elif kind == "WATCH":
            self.watching = bool(report.get("enable"))

    def _refuse(self, cause: str, sample: bytes) -> None:
        if self.on_refuse is not None:
            self.on_refuse(cause, repr(sample))

    def close(self) -> None:
        self.stream.close()
