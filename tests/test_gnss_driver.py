"""The GNSS driver (drivers/gnss_node.py) reading real wires: a pseudo-terminal written by the
simulator's side (simulator.nmea_wire), a receiver's TCP stream, and gpsd serving a receiver log
replayed by gpsfake (gpsd's own test harness). The driver and the perception gnss node run on one
in-memory bus with a manual clock, stepped by hand; the fixes that come out are compared with
the positions written into the wire. A device that goes away and comes back is reopened."""

from __future__ import annotations

import logging
import math
import os
import shutil
import signal
import socket
import subprocess
import time
from collections.abc import Callable
from pathlib import Path

import pynmea2
import pytest

from ares.core import config
from ares.core.clock import ManualClock
from ares.core.config import CoreConfig
from ares.core.geodesy import LocalFrame, origin_at
from ares.core.localhost import free_port
from ares.core.membus import MemoryNetwork
from ares.core.nmea_framing import sentence
from drivers.gnss_node import GnssDriver, GnssDriverParams
from perception.gnss import GnssParams
from perception.gnss_node import GnssNode
from simulator.nmea_wire import NmeaPty
from tests.helpers.gnss import PLACES, short_road
from tests.helpers.receiver_logs import UBLOX_F9P, write_log

LAT, LON, ALT, _ = PLACES["munich"]
DAY = 1_795_392_000.0  # a midnight UTC (2026-11-24)
START_TOD = 9 * 3600 + 47 * 60 + 30.0  # receiver_logs' start, 09:47:30 UTC
WAIT_S = 10.0  # the longest a wait on the wire may take before the test gives up (a loaded machine)


def make_cfg(gnss: dict, **driver) -> dict:
    cfg = config.build(
        CoreConfig, overrides={"vehicle_io": {"gnss": gnss}, "origin_utm": origin_at(LAT, LON, ALT).model_dump()}
    )
    cfg["gnss_driver"] = GnssDriverParams(**{"reopen_s": 0.02, **driver}).model_dump()
    cfg["gnss"] = GnssParams().model_dump()
    return cfg


class Rig:
    """The driver and the gnss node on one in-memory network, time moved by hand."""

    def __init__(self, cfg: dict, utc_epoch: float = DAY + START_TOD - 10.0):
        self.clock = ManualClock(utc_epoch=utc_epoch)
        network = MemoryNetwork()
        self.driver = GnssDriver(cfg, clock=self.clock, bus=network.bus("gnss_driver", self.clock))
        self.node = GnssNode(cfg, clock=self.clock, bus=network.bus("gnss", self.clock))
        self.driver.setup()
        self.node.setup()
        bus = network.bus("test", self.clock)
        self._messages = bus.subscribe("sensors/gnss", queue=100_000)
        self._fixes = bus.subscribe("gnss/fix", queue=100_000)
        self.messages: list = []
        self.fixes: list = []
        self.counts = self.driver.wires["gnss"]

    def step(self, t: float | None = None) -> None:
        t = self.clock.now() if t is None else t
        self.clock.set(t)
        self.driver.step_once(t)
        self.node.step_once(t)
        self.messages += [m for _, m in self._messages.drain()]
        self.fixes += [m for _, m in self._fixes.drain()]

    def step_until(self, done: Callable[[], bool], what: str, t: float | None = None, wait_s: float = WAIT_S) -> None:
        """Steps (at stack time t) until `done()`; the wire is real, so its bytes take a moment."""
        deadline = time.monotonic() + wait_s
        while True:
            self.step(t)
            if done():
                return
            if time.monotonic() > deadline:
                pytest.fail(f"after {wait_s} s: {what}; counts: {self.counts.status(0.0, 'gnss_driver')}")
            time.sleep(0.002)

    def close(self) -> None:
        self.driver.teardown()


def gga_gst(tod: float, lat: float, lon: float, alt: float) -> list[str]:
    """A simulator-like epoch: GGA (RTK fixed) and its GST."""
    h, m, s = int(tod // 3600), int(tod % 3600 // 60), tod % 60
    hhmmss = f"{h:02d}{m:02d}{s:05.2f}"
    la, lo = abs(lat), abs(lon)
    lat_text = f"{int(la):02d}{(la - int(la)) * 60:011.8f},{'N' if lat >= 0 else 'S'}"
    lon_text = f"{int(lo):03d}{(lo - int(lo)) * 60:011.8f},{'E' if lon >= 0 else 'W'}"
    return [
        sentence(f"GPGGA,{hhmmss},{lat_text},{lon_text},4,12,0.7,{alt:.3f},M,47.0,M,1.0,0001"),
        sentence(f"GPGST,{hhmmss},0.010,0.012,0.009,30.0,0.011,0.010,0.020"),
    ]


def drive(n: int, t0: float, utc_epoch: float) -> list[tuple[float, list[str], tuple[float, float]]]:
    """n epochs at 5 Hz along the short road from stack time t0: (t, lines, (lat, lon))."""
    frame = LocalFrame(origin_at(LAT, LON, ALT))
    road = short_road()
    out = []
    for k in range(n):
        t = t0 + 0.2 * k
        x, y, z, _ = road.point_at(2.0 * k)
        lat, lon = frame.to_latlon(x, y)
        out.append((t, gga_gst((utc_epoch + t) % 86400.0, lat, lon, ALT + z), (lat, lon)))
    return out


def assert_fixes_are(fixes: list, positions: list[tuple[float, float]]) -> None:
    assert len(fixes) == len(positions)
    for fix, (lat, lon) in zip(fixes, positions):
        # the log's 8 decimals of a minute: 2e-8 degrees
        assert math.isclose(fix.lat, lat, abs_tol=2e-9 * 60) and math.isclose(fix.lon, lon, abs_tol=2e-9 * 60)


# ---- a pseudo-terminal ---------------------------------------------------------------------------


def test_a_simulated_receiver_on_a_pseudo_terminal_gives_one_message_and_fix_per_epoch(tmp_path):
    link = tmp_path / "dev" / "gnss"
    pty = NmeaPty(link)
    rig = Rig(make_cfg({"source": "serial", "device": str(link)}))
    try:
        rig.step(0.9)  # opens the port
        assert rig.driver.port is not None and not rig.counts.connected
        epochs = drive(25, 1.0, rig.clock.utc_epoch)
        for k, (t, lines, _) in enumerate(epochs):
            rig.clock.set(t)
            assert pty.write(lines) == 0
            # its GGA and GST, the port drained: published at once, whatever the hold
            rig.step_until(lambda k=k: len(rig.messages) == k + 1, f"epoch {k} published", t)
        for msg, (t, lines, _) in zip(rig.messages, epochs):
            assert msg.sentences == lines
            assert msg.t == pytest.approx(t, abs=1e-6)  # the receiver's time of day, back in stack time
        assert_fixes_are(rig.fixes, [pos for _, _, pos in epochs])
        assert [f.t for f in rig.fixes] == [m.t for m in rig.messages]
        assert rig.counts.connected and rig.counts.received == 50 and rig.counts.published == 25
        assert not rig.counts.malformed and rig.counts.percentile_ms(50) is not None
    finally:
        rig.close()
        pty.close()
    assert not link.exists() and not link.is_symlink()


def test_a_burst_of_old_epochs_is_dropped_never_stamped_as_new(tmp_path):
    """A stream held up for 6 s, then 31 epochs at once: those older than 0.5 s when read are
    dropped and counted as stale. Before, all came out and the oldest (6 s) was stamped as now."""
    link = tmp_path / "gnss"
    pty = NmeaPty(link)
    rig = Rig(make_cfg({"source": "serial", "device": str(link)}))
    try:
        rig.step(0.9)
        for t, lines, _ in drive(5, 1.0, rig.clock.utc_epoch):  # a second of epochs as they come
            rig.clock.set(t)
            assert pty.write(lines) == 0
            rig.step_until(lambda t=t: rig.messages and rig.messages[-1].t == pytest.approx(t), "an epoch", t)
        held = drive(31, 2.0, rig.clock.utc_epoch)  # 2.0 .. 8.0 s, all written at 8.0
        rig.clock.set(8.0)
        assert pty.write([line for _, lines, _ in held for line in lines]) == 0
        rig.step_until(lambda: rig.counts.skipped.get("stale", 0) + len(rig.messages) == 5 + 31, "the burst", 8.0)
        fresh = [t for t, _, _ in held if 8.0 - t <= 0.5 + 1e-9]
        assert rig.counts.skipped["stale"] == 31 - len(fresh) == 28
        assert [m.t for m in rig.messages[5:]] == pytest.approx(fresh)  # their own times, not now
        assert len(rig.fixes) == 5 + len(fresh)
    finally:
        rig.close()
        pty.close()


@pytest.mark.parametrize(("ahead_s", "published"), [(3.0, True), (-3.0, False)])
def test_a_receiver_clock_off_from_ours_is_reported(tmp_path, caplog, ahead_s, published):
    """A computer whose clock is 3 s from the receiver's. Behind it, every fix looks 3 s from the
    future: stamped as read. Ahead of it, every fix looks 3 s old: dropped (a stream 3 s late for good
    looks the same), never stamped as new. Either way the offset is reported, with what to do."""
    link = tmp_path / "gnss"
    pty = NmeaPty(link)
    rig = Rig(make_cfg({"source": "serial", "device": str(link)}))
    try:
        rig.step(0.9)
        epochs = drive(10, 1.0, rig.clock.utc_epoch + ahead_s)
        for k, (t, lines, _) in enumerate(epochs):
            rig.clock.set(t)
            assert pty.write(lines) == 0
            rig.step_until(lambda k=k: len(rig.messages) + rig.counts.skipped.get("stale", 0) == k + 1, f"epoch {k}", t)
        if published:
            assert not rig.counts.skipped and [m.t for m in rig.messages] == pytest.approx([t for t, _, _ in epochs])
        else:
            assert rig.messages == [] and rig.counts.skipped == {"stale": 10}
        said = f"its time is {ahead_s:+.2f} s from the stack clock's"
        assert any("receiver clock" in r.message and said in r.message for r in caplog.records)
    finally:
        rig.close()
        pty.close()


def ubx(cls: int, ident: int, payload: bytes) -> bytes:
    body = bytes([cls, ident, len(payload) & 0xFF, len(payload) >> 8]) + payload
    a = b = 0
    for byte in body:
        a = (a + byte) & 0xFF
        b = (b + a) & 0xFF
    return b"\xb5\x62" + body + bytes([a, b])


NAV_PVT = ubx(0x01, 0x07, bytes(range(92)))


def log_ggas(lines: list[str]) -> list[tuple[float, float]]:
    """The positions of the log's GGAs that the gnss node accepts (a fix, a good checksum), in
    order, as pynmea2 reads them (a parser of its own, not the one under test)."""
    found = []
    for line in lines:
        try:
            parsed = pynmea2.parse(line, check=True)
        except (pynmea2.ParseError, ValueError):
            continue
        if isinstance(parsed, pynmea2.GGA) and parsed.gps_qual and int(parsed.gps_qual) > 0:
            found.append((parsed.latitude, parsed.longitude))
    return found


def time_of_day(line: str):
    """A sentence's time of day as pynmea2 reads it; None for one without (or not read)."""
    try:
        return getattr(pynmea2.parse(line), "timestamp", None)
    except (pynmea2.ParseError, ValueError):
        return None


def test_a_receivers_port_with_ubx_frames_then_unplugged_and_plugged_back(tmp_path, caplog):
    """A u-blox receiver's log (header text, two talkers' GGA, PUBX, a corrupt line) in the
    serial port's chunks, a UBX frame after each epoch's RMC: every GGA it holds becomes a fix
    at its position. Then the device goes (its link removed), is absent a while, and a new one
    appears under the same name: noticed, logged once per cause, reopened, read."""
    lines = write_log(short_road(), LAT, LON, ALT, UBLOX_F9P)[:1100]  # ~ 80 epochs, a corrupt line
    data = bytearray()
    frames = 0
    ends = []  # where each sentence is complete: its CR read
    for line in lines:
        data += line.encode() + b"\r\n"
        if line.startswith("$"):
            ends.append(len(data) - 2)
        if "RMC," in line:
            data += NAV_PVT
            frames += 1
    link = tmp_path / "ttyACM0"
    pty = NmeaPty(link)
    # a hold longer than any pause between the test's writes: only the next epoch closes one
    rig = Rig(make_cfg({"source": "serial", "device": str(link), "silent_after_s": 2.0}, epoch_hold_s=0.3))
    caplog.set_level(logging.INFO)
    try:
        rig.step(0.0)
        for i in range(0, len(data), 700):  # the port's reads: any boundaries
            os.write(pty.master, data[i : i + 700])
            complete = sum(1 for end in ends if end < i + 700)
            rig.step_until(lambda n=complete: rig.counts.received == n, f"{complete} sentences read")
        # the last epoch waits for the next or for the hold (wall time)
        rig.step_until(lambda: sum(len(m.sentences) for m in rig.messages) == rig.counts.received, "all published")
        expected = log_ggas(lines)
        assert len(expected) > 100  # GN and GP talkers: two GGAs an epoch
        assert_fixes_are(rig.fixes, expected)
        assert rig.counts.skipped == {"ubx": frames}
        sentences = [line for line in lines if line.startswith("$")]
        assert [s for m in rig.messages for s in m.sentences] == sentences  # the corrupt one too: not ours
        assert rig.counts.malformed == {"garbage": 3}  # the header's three text lines
        # one message per epoch: the sentences of one time of day (untimed ones with the epoch)
        for msg in rig.messages:
            assert len({time_of_day(s) for s in msg.sentences} - {None}) == 1

        pty.close()  # unplugged: the link goes, the terminal hangs up
        rig.step_until(lambda: rig.driver.port is None, "the device noticed gone")
        assert not rig.counts.connected
        deadline = time.monotonic() + 0.2
        while time.monotonic() < deadline:  # several reopen periods without the device
            rig.step()
            time.sleep(0.005)
        pty = NmeaPty(link)  # plugged back: a new terminal under the same name
        rig.step_until(lambda: rig.driver.port is not None, "the device reopened")
        before = len(rig.fixes)
        t = rig.clock.now() + 1.0
        for k, (_, epoch, _) in enumerate(drive(3, t, rig.clock.utc_epoch)):
            pty.write(epoch)
            rig.step_until(lambda k=k: len(rig.fixes) == before + k + 1, "a fix from the new device", t + k * 0.2)
        assert rig.counts.connected
        warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
        assert len([w for w in warnings if w.startswith("gnss: gone")]) == 1
        assert len([w for w in warnings if w.startswith("gnss: absent")]) == 1  # though tried again and again
    finally:
        rig.close()
        pty.close()


# ---- TCP -------------------------------------------------------------------------------------------


def listen(port: int) -> socket.socket:
    server = socket.socket()
    server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    server.bind(("127.0.0.1", port))
    server.listen(1)
    server.setblocking(False)
    return server


def accept(rig: Rig, server: socket.socket) -> socket.socket:
    """The driver's connection, stepping it meanwhile (it connects when a step finds it due)."""
    accepted: list[socket.socket] = []

    def connected() -> bool:
        try:
            accepted.append(server.accept()[0])
        except BlockingIOError:
            return False
        return True

    rig.step_until(connected, "the driver's connection")
    return accepted[0]


def test_a_receivers_tcp_stream_lost_and_back():
    port = free_port()
    server = listen(port)
    rig = Rig(make_cfg({"source": "tcp", "host": "127.0.0.1", "port": port}))
    epochs = drive(6, 1.0, rig.clock.utc_epoch)
    try:
        rig.step(0.5)
        conn = accept(rig, server)
        for k, (t, lines, _) in enumerate(epochs[:3]):
            conn.sendall("".join(f"{line}\r\n" for line in lines).encode())
            rig.step_until(lambda k=k: len(rig.fixes) == k + 1, f"fix {k}", t)
        conn.close()
        server.close()  # the receiver's server goes away
        rig.step_until(lambda: rig.driver.port is None, "the connection noticed closed", 1.5)
        assert not rig.counts.connected
        server = listen(port)  # and comes back
        conn = accept(rig, server)  # the driver tries again every reopen_s
        for k, (t, lines, _) in enumerate(epochs[3:], start=3):
            conn.sendall("".join(f"{line}\r\n" for line in lines).encode())
            rig.step_until(lambda k=k: len(rig.fixes) == k + 1, f"fix {k}", t)
        assert_fixes_are(rig.fixes, [pos for _, _, pos in epochs])
        assert [m.t for m in rig.messages] == pytest.approx([t for t, _, _ in epochs], abs=1e-6)
        assert rig.counts.connected and rig.counts.published == 6
        conn.close()
    finally:
        rig.close()
        server.close()


# ---- gpsd -------------------------------------------------------------------------------------------


def receiver_log(path: Path, n: int) -> list[tuple[float, float]]:
    """A receiver's log gpsd takes for an NMEA device: GGA, GST and RMC each epoch, at 5 Hz."""
    frame = LocalFrame(origin_at(LAT, LON, ALT))
    road = short_road()
    lines, positions = [], []
    for k in range(n):
        tod = START_TOD + 0.2 * k
        x, y, z, yaw = road.point_at(2.0 * k)
        lat, lon = frame.to_latlon(x, y)
        gga, gst = gga_gst(tod, lat, lon, ALT + z)
        rmc_fields = gga.split(",")[1:6]
        course = math.degrees(math.pi / 2 - yaw) % 360.0
        rmc = sentence(f"GPRMC,{rmc_fields[0]},A,{','.join(rmc_fields[1:5])},19.438,{course:.2f},241126,,,R")
        lines += [gga, gst, rmc]
        positions.append((lat, lon))
    path.write_text("".join(f"{line}\r\n" for line in lines))
    return positions


def test_gpsd_serving_a_receiver_log_replayed_by_gpsfake(tmp_path):
    """gpsfake starts gpsd (-n: it opens the device at once) on a pseudo-terminal it feeds the
    log into, the way gpsd's own regression tests run; the driver watches gpsd with NMEA
    pass-through. gpsd passes on what its device gave: the fixes are the log's, in order, up to
    its last epoch (the very first lines may go before gpsd has the device open)."""
    gpsfake = shutil.which("gpsfake")
    if gpsfake is None:
        pytest.fail("gpsfake is not installed: the Debian packages gpsd and gpsd-clients (scripts/setup.sh) provide it")
    log = tmp_path / "receiver.nmea"
    positions = receiver_log(log, 40)
    port = free_port()
    errors = (tmp_path / "gpsfake.err").open("w")
    proc = subprocess.Popen(
        [gpsfake, "-1", "-q", "-n", "-P", str(port), "-c", "0.005", str(log)],
        stdout=subprocess.DEVNULL,
        stderr=errors,
        start_new_session=True,  # gpsfake and its gpsd: one group, ended together
    )
    rig = Rig(make_cfg({"source": "gpsd", "host": "127.0.0.1", "port": port}))
    try:
        rig.step_until(
            lambda: len(rig.fixes) >= 1 and rig.fixes[-1].lat == pytest.approx(positions[-1][0], abs=1e-7),
            f"the log's last fix through gpsd (gpsfake: {(tmp_path / 'gpsfake.err').read_text()!r})",
            wait_s=15.0,  # ~2.5 s on an idle machine: gpsd opens the device in ~1 s
        )
        got = len(rig.fixes)
        assert got >= 10, f"only {got} of the log's {len(positions)} epochs came through gpsd"
        assert_fixes_are(rig.fixes, positions[-got:])
        detail = rig.counts.detail
        assert detail.startswith("gpsd 3.") and "/dev/pts/" in detail
        assert rig.counts.connected and not rig.counts.malformed
    finally:
        rig.close()
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGINT)  # gpsfake's own cleanup ends its gpsd
            try:
                proc.wait(5)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
        errors.close()


def test_the_simulators_side_never_stalls_and_replaces_a_stale_link(tmp_path):
    link = tmp_path / "run" / "gnss"
    link.parent.mkdir()
    link.symlink_to("/dev/pts/does-not-exist")  # left by a run that was killed
    pty = NmeaPty(link)
    try:
        assert os.path.realpath(link) == pty.slave_name
        lines = drive(1, 0.0, DAY)[0][1] * 50
        dropped = sum(pty.write(lines) for _ in range(200))  # nobody reads: the terminal fills up
        assert dropped > 0 and pty.dropped_lines == dropped
        assert pty.written_lines + pty.dropped_lines == 200 * len(lines)
    finally:
        pty.close()
    assert not link.is_symlink()
