"""The simulated shuttle's corrections behind the wire: a base station, a real NTRIP caster, a 4G link.

With `ares run --wire`, the RTK corrections travel as they do on the shuttle: RTCM 3 from a base
station, served by an NTRIP caster, fetched over 4G by the vehicle's NTRIP client
(drivers/ntrip_node.py), written by the GNSS driver to the receiver's port, where the simulated
receiver takes them (simulator/corrections.py: its fix follows their age).

- `BaseStation`: RTKLIB's `str2str` (Debian's `rtklib`) serving an NTRIP caster (rev 1, basic
  authentication, one mount point and its source table), fed on its standard input with a real
  base station's RTCM 3, one epoch a second of stack time, over and over: a u-blox ZED-F9T's 1005,
  MSM7 (1077, 1087, 1097, 1127), 1230 and 4072 messages (simulator/data/base_station.rtcm3: gpsd's
  test log `test/daemon/ublox-zed-f9t-rtcm3.log`, BSD-2-Clause, its UBX frames taken out).
- `ModemRelay`: the vehicle's 4G modem, a TCP relay between the client and the caster. Where the
  tour has no 4G (a `no_4g` zone) or a fault stops the corrections, it passes nothing either way
  and closes every new connection at once: the client sees its stream go silent, then each try
  closed, and backs off, as over a dead link. Back in coverage, the stale connections are closed.
"""

from __future__ import annotations

import errno
import select
import shutil
import socket
import subprocess
import time
from importlib import resources
from pathlib import Path

from ares.core.wire.rtcm import RtcmStream

CASTER = "str2str"


def base_station_epochs(path: str | Path | None = None) -> list[bytes]:
    """The base station's RTCM, one epoch a piece: each starts at a 1005 (the station's position,
    sent first of every epoch by the F9T) or, without any, at the log's first message."""
    data = (
        Path(path).read_bytes()
        if path
        else resources.files("simulator").joinpath("data/base_station.rtcm3").read_bytes()
    )
    frames = RtcmStream().feed(data)
    if not frames:
        raise ValueError(f"{path or 'the base station log'}: no RTCM 3 frame in it")
    first_type = 1005 if any(f.message_type == 1005 for f in frames) else frames[0].message_type
    epochs: list[bytearray] = []
    for frame in frames:
        if frame.message_type == first_type or not epochs:
            epochs.append(bytearray())
        epochs[-1] += frame.raw
    return [bytes(e) for e in epochs]


class BaseStation:
    """`str2str` serving the mount point on `port`, its input an epoch of RTCM per `send`."""

    def __init__(self, port: int, mountpoint: str, user: str, password: str):
        if shutil.which(CASTER) is None:
            raise RuntimeError(
                f"--wire sends the RTK corrections through an NTRIP caster: RTKLIB's {CASTER} is not installed "
                "(Debian: apt-get install rtklib; scripts/setup.sh installs it)"
            )
        self.port = port
        self.mountpoint = mountpoint
        self.epochs = base_station_epochs()
        self.sent = 0
        types = "1005(1),1077(1),1087(1),1097(1),1127(1),1230(1)"
        table = f"ARES base;RTCM 3.3;{types};2;GPS+GLO+GAL+BDS;ARES;ESP;0;0;0;0;sim;none;B;N;0;"  # its STR line
        self.process = subprocess.Popen(  # its stderr: a status line a second, for nobody
            [CASTER, "-out", f"ntripc://{user}:{password}@:{port}/{mountpoint}:{table}"],
            stdin=subprocess.PIPE,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )

    def send(self) -> None:
        """The next epoch to the caster (the base station's second)."""
        if self.process.poll() is not None or self.process.stdin is None:
            return
        try:
            self.process.stdin.write(self.epochs[self.sent % len(self.epochs)])
            self.process.stdin.flush()
            self.sent += 1
        except (BrokenPipeError, OSError):
            pass  # the caster is gone: the client will find it so

    def ready(self, timeout_s: float = 3.0) -> bool:
        """Whether the caster accepts connections (it takes a few milliseconds to start)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            try:
                with socket.create_connection(("127.0.0.1", self.port), timeout=0.2):
                    return True
            except OSError:
                time.sleep(0.01)
        return False

    def close(self) -> None:
        if self.process.stdin is not None:
            try:
                self.process.stdin.close()
            except OSError:
                pass
        self.process.terminate()
        try:
            self.process.wait(timeout=2.0)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()


class _Pair:
    def __init__(self, client: socket.socket, upstream: socket.socket | None):
        self.client = client
        self.upstream = upstream
        self.connected = False


class ModemRelay:
    """A TCP relay on 127.0.0.1:`port` to the caster at `target`, cut while `up` is false."""

    def __init__(self, port: int, target: tuple[str, int]):
        self.target = target
        self.listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.listener.bind(("127.0.0.1", port))
        self.listener.listen(8)
        self.listener.setblocking(False)
        self.port = port
        self.pairs: list[_Pair] = []
        self.up = True
        self.bytes_down = 0  # caster -> vehicle
        self.bytes_up = 0
        self.cuts = 0  # times the link went down

    def set_up(self, up: bool) -> None:
        if up and not self.up:
            for pair in self.pairs:  # what was held through the outage is stale: the client reconnects
                self._close(pair)
            self.pairs = []
        elif not up and self.up:
            self.cuts += 1
        self.up = up

    def poll(self) -> None:
        """Moves what is waiting, without blocking (called every simulator step)."""
        self._accept()
        if not self.up:
            return
        for pair in list(self.pairs):
            if not self._connect(pair):
                continue
            for source, sink, attr in (
                (pair.upstream, pair.client, "bytes_down"),
                (pair.client, pair.upstream, "bytes_up"),
            ):
                if not self._move(pair, source, sink, attr):
                    break

    def _accept(self) -> None:
        while True:
            try:
                client, _ = self.listener.accept()
            except (BlockingIOError, InterruptedError):
                return
            client.setblocking(False)
            if not self.up:
                client.close()  # no coverage: the try ends at once (the client backs off)
                continue
            upstream = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            upstream.setblocking(False)
            code = upstream.connect_ex(self.target)
            if code not in (0, errno.EINPROGRESS):
                upstream.close()
                client.close()
                continue
            self.pairs.append(_Pair(client, upstream))

    def _connect(self, pair: _Pair) -> bool:
        if pair.connected:
            return True
        assert pair.upstream is not None  # made with the pair
        _, writable, _ = select.select([], [pair.upstream], [], 0)
        if not writable:
            return False
        if pair.upstream.getsockopt(socket.SOL_SOCKET, socket.SO_ERROR):
            self._drop(pair)
            return False
        pair.connected = True
        return True

    def _move(self, pair: _Pair, source, sink, attr: str) -> bool:
        while True:
            try:
                data = source.recv(65536)
            except (BlockingIOError, InterruptedError):
                return True
            except OSError:
                self._drop(pair)
                return False
            if not data:
                self._drop(pair)
                return False
            try:
                sink.sendall(data)
            except (BlockingIOError, InterruptedError, OSError):
                self._drop(pair)  # a few hundred bytes a second: a full buffer is a dead peer
                return False
            setattr(self, attr, getattr(self, attr) + len(data))

    def _drop(self, pair: _Pair) -> None:
        self._close(pair)
        if pair in self.pairs:
            self.pairs.remove(pair)

    @staticmethod
    def _close(pair: _Pair) -> None:
        for sock in (pair.client, pair.upstream):
            if sock is not None:
                sock.close()

    def close(self) -> None:
        for pair in self.pairs:
            self._close(pair)
        self.pairs = []
        self.listener.close()
