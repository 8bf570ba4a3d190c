"""The NTRIP client (ares/core/wire/ntrip.py, drivers/ntrip_node.py) against a real caster: RTKLIB's
str2str serving a real base station's RTCM 3 (tests/data/rtcm) on loopback, started by each test.
Rev 1 and rev 2 requests, basic authentication refused and accepted, an unknown mount point
answered with the source table, the receiver's GGA sent upstream (str2str relays it back to its
own input with -b 1), a caster that goes away and comes back, and the frames that reach the
receiver's port through the GNSS driver."""

from __future__ import annotations

import shutil
import socket
import subprocess
import threading
import time
from pathlib import Path

import pytest

from ares.core.localhost import free_port
from ares.core.wire.ntrip import Dechunker, NtripClient, NtripSettings, parse_sourcetable, request
from ares.core.wire.rtcm import RtcmStream

DATA = Path(__file__).parent / "data" / "rtcm"
F9T = (DATA / "zed-f9t_msm7.rtcm3").read_bytes()
FRAMES = [f.raw for f in RtcmStream().feed(F9T)]
USER, PASSWORD, MOUNT = "shuttle", "s3cret", "F9T"
GGA = "$GPGGA,120000.00,4404.1300,N,12118.8600,W,4,12,0.7,1114.0,M,0.0,M,1.0,0001*4B"
WAIT_S = 5.0

pytestmark = pytest.mark.skipif(shutil.which("str2str") is None, reason="RTKLIB's str2str (scripts/setup.sh)")


class Caster:
    """str2str as an NTRIP caster on `port`, its input fed with the F9T log one epoch at a time (every
    20 ms: fifty base-station seconds a second), or its input a TCP server of the test's (`relay`)."""

    def __init__(self, port: int | None = None, relay_port: int | None = None):
        self.port = port or free_port()
        table = "Bend;RTCM 3.3;1005(1),1077(1);2;GPS;ARES;USA;44.07;-121.31;1;0"  # its STR line
        out = f"ntripc://{USER}:{PASSWORD}@:{self.port}/{MOUNT}:{table}"
        args = ["str2str", "-out", out]
        if relay_port is not None:
            args = ["str2str", "-in", f"tcpcli://127.0.0.1:{relay_port}", "-out", out, "-b", "1"]
        self.process = subprocess.Popen(
            args, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
        )
        self._stop = threading.Event()
        self._feeder = threading.Thread(target=self._feed, daemon=True) if relay_port is None else None
        if self._feeder is not None:
            self._feeder.start()
        deadline = time.monotonic() + WAIT_S
        while time.monotonic() < deadline:
            try:
                socket.create_connection(("127.0.0.1", self.port), timeout=0.2).close()
                return
            except OSError:
                time.sleep(0.005)
        raise AssertionError("str2str did not start")

    def _feed(self) -> None:
        epochs = [b"".join(FRAMES[i : i + 7]) for i in range(0, len(FRAMES), 7)]
        k = 0
        while not self._stop.is_set():
            try:
                assert self.process.stdin is not None
                self.process.stdin.write(epochs[k % len(epochs)])
                self.process.stdin.flush()
            except (BrokenPipeError, OSError, ValueError):
                return
            k += 1
            time.sleep(0.02)

    def close(self) -> None:
        self._stop.set()
        self.process.kill()
        self.process.wait()


@pytest.fixture
def caster():
    made = []

    def make(**kwargs):
        made.append(Caster(**kwargs))
        return made[-1]

    yield make
    for c in made:
        c.close()


def settings_for(port: int, **kw) -> NtripSettings:
    return NtripSettings(
        host="127.0.0.1",
        port=port,
        mountpoint=kw.pop("mountpoint", MOUNT),
        user=USER,
        password=kw.pop("password", PASSWORD),
        **{"backoff_min_s": 0.05, "backoff_max_s": 0.4, "silent_after_s": 0.5, **kw},
    )


def poll_until(client: NtripClient, done, what: str) -> list:
    frames = []
    deadline = time.monotonic() + WAIT_S
    while not done(frames):
        assert time.monotonic() < deadline, f"{what}: {client.state}, {client.events}"
        frames += client.poll()
        time.sleep(0.005)
    return frames


def is_a_run_of_the_log(frames) -> bool:
    """The frames are consecutive frames of the base station's log (a live stream, joined anywhere)."""
    raws = [f.raw for f in frames]
    start = FRAMES.index(raws[0])
    cycle = FRAMES * (len(raws) // len(FRAMES) + 2)
    return raws == cycle[start : start + len(raws)]


@pytest.mark.parametrize("version", [1, 2])
def test_a_mount_points_stream_in_rev_1_and_rev_2(caster, version):
    c = caster()
    client = NtripClient(settings_for(c.port, version=version))
    try:
        frames = poll_until(client, lambda f: len(f) >= 40, "40 frames")
        assert client.state == "streaming" and client.connects == 1 and not client.malformed
        assert is_a_run_of_the_log(frames)
        assert {f.message_type for f in frames} == {1005, 1077, 1087, 1097, 1127, 1230, 4072}
    finally:
        client.close()


def test_a_wrong_password_is_refused_and_tried_again_later_and_later(caster):
    c = caster()
    client = NtripClient(settings_for(c.port, password="wrong"))
    try:
        poll_until(client, lambda _: len(client.events) >= 3, "three refusals")
        causes = [cause for cause, _ in client.events]
        assert causes[:3] == ["unauthorized"] * 3 and client.frames == 0
        assert "401" in client.last_error
        delays = [float(text.rsplit("again in ", 1)[1].split()[0]) for _, text in client.events[:3]]
        assert delays == [0.05, 0.1, 0.2]  # doubling from backoff_min_s
    finally:
        client.close()


def test_an_unknown_mount_point_gets_the_source_table(caster):
    c = caster()
    client = NtripClient(settings_for(c.port, mountpoint="NOPE"))
    try:
        poll_until(client, lambda _: bool(client.events), "an answer")
        assert client.events[0][0] == "no such mount point"
        assert [m.name for m in client.mountpoints] == [MOUNT] and "F9T" in client.events[0][1]
        table = client.mountpoints[0]
        assert table.format == "RTCM 3.3" and table.lat == pytest.approx(44.07)
    finally:
        client.close()


def test_a_real_casters_source_table_parses():
    """SAPOS's answer to a rev 2 request for `/` (gpsd's test suite)."""
    text = (DATA / "sapos_sourcetable.log").read_text(encoding="latin-1")
    body = text[text.index("SOURCETABLE 200 OK") :]
    mounts = parse_sourcetable(body)
    assert len(mounts) == 4 and all(m.name and m.format.startswith("RTCM") for m in mounts)
    assert any(m.nmea for m in mounts)  # a VRS mount point: it wants the rover's GGA


def test_the_receivers_gga_goes_upstream(caster):
    """str2str with -b 1 relays what its clients send to its input: here a TCP server of the test's,
    which feeds the caster its RTCM and hears the GGA the client sends."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(1)
    heard = bytearray()
    stop = threading.Event()

    def base():
        server.settimeout(WAIT_S)
        conn, _ = server.accept()
        conn.settimeout(0.02)
        k = 0
        while not stop.is_set():
            conn.sendall(FRAMES[k % len(FRAMES)])
            k += 1
            try:
                heard.extend(conn.recv(4096))
            except TimeoutError:
                pass
        conn.close()

    thread = threading.Thread(target=base, daemon=True)
    thread.start()
    c = caster(relay_port=server.getsockname()[1])
    client = NtripClient(settings_for(c.port, gga_interval_s=0.1), gga=lambda: GGA)
    try:
        poll_until(client, lambda _: GGA.encode() in heard and client.gga_sent >= 2, "the GGA upstream")
        assert client.state == "streaming" and client.frames > 0
    finally:
        stop.set()
        client.close()
        thread.join(2.0)
        server.close()


def test_a_caster_that_goes_away_and_comes_back(caster):
    c = caster()
    client = NtripClient(settings_for(c.port))
    try:
        poll_until(client, lambda f: len(f) >= 10, "the stream")
        c.close()
        poll_until(client, lambda _: client.outages == 1 and client.state != "streaming", "the loss noticed")
        assert client.events and client.events[0][0] in ("closed by the caster", "link failed", "silent")
        back = caster(port=c.port)
        del back
        frames = poll_until(client, lambda f: len(f) >= 10, "the stream again")
        assert client.state == "streaming" and client.connects == 2 and is_a_run_of_the_log(frames)
    finally:
        client.close()


def test_a_rev_2_body_in_chunks_is_taken_whole():
    """A rev 2 caster's chunked transfer coding, in any cuts (the body: the real stream)."""
    body = b"".join(FRAMES[:20])
    chunked = b""
    for i in range(0, len(body), 333):
        piece = body[i : i + 333]
        chunked += f"{len(piece):x};ext=1\r\n".encode() + piece + b"\r\n"
    chunked += b"0\r\n\r\n"
    dechunk = Dechunker()
    out = b"".join(dechunk.feed(chunked[i : i + 7]) for i in range(0, len(chunked), 7))
    assert out == body and dechunk.done and dechunk.error is None
    bad = Dechunker()
    bad.feed(b"zz\r\n")
    assert bad.error is not None and "no number" in bad.error


def test_the_request_is_one_piece_with_its_authorization():
    rev1 = request(MOUNT, "caster.example", 2101, USER, PASSWORD, version=1, gga=GGA)
    assert rev1.startswith(b"GET /F9T HTTP/1.0\r\nUser-Agent: NTRIP ")
    assert b"Authorization: Basic c2h1dHRsZTpzM2NyZXQ=\r\n" in rev1 and rev1.endswith(GGA.encode() + b"\r\n")
    rev2 = request(MOUNT, "caster.example", 2101, None, None, version=2)
    assert b"Ntrip-Version: Ntrip/2.0\r\n" in rev2 and b"Host: caster.example:2101\r\n" in rev2
    assert b"Authorization" not in rev2 and rev2.endswith(b"\r\n\r\n")


def test_the_frames_reach_the_receivers_port_and_the_corrections_state_is_published(caster, tmp_path):
    """The NTRIP client's node and the GNSS driver on one in-memory bus: the caster's frames go
    out on gnss/rtcm, the driver writes them to the receiver's port (a pseudo-terminal here), and
    gnss/corrections says they stream and how old the newest is; the caster gone, it says down."""
    from ares.core import config
    from ares.core.clock import ManualClock
    from ares.core.config import CoreConfig
    from ares.core.membus import MemoryNetwork
    from drivers.gnss_node import GnssDriver, GnssDriverParams
    from drivers.ntrip_node import NtripClientNode, NtripClientParams
    from simulator.nmea_wire import NmeaPty

    c = caster()
    link = tmp_path / "gnss.tty"
    pty = NmeaPty(link)
    ntrip = {"host": "127.0.0.1", "port": c.port, "mountpoint": MOUNT, "user": USER, "password": PASSWORD}
    ntrip |= {"silent_after_s": 0.5, "backoff_min_s": 0.05, "backoff_max_s": 0.2}
    cfg = config.build(
        CoreConfig, overrides={"vehicle_io": {"gnss": {"source": "serial", "device": str(link)}, "ntrip": ntrip}}
    )
    cfg["gnss_driver"] = GnssDriverParams(reopen_s=0.02).model_dump()
    cfg["ntrip_client"] = NtripClientParams().model_dump()
    clock = ManualClock()
    network = MemoryNetwork()
    client = NtripClientNode(cfg, clock=clock, bus=network.bus("ntrip_client", clock))
    driver = GnssDriver(cfg, clock=clock, bus=network.bus("gnss_driver", clock))
    statuses = network.bus("test", clock).subscribe("gnss/corrections", queue=100)
    client.setup()
    driver.setup()
    received = RtcmStream()
    got: list = []
    t = 0.0
    try:
        deadline = time.monotonic() + WAIT_S
        while len(got) < 30:
            assert time.monotonic() < deadline, client.counters.detail
            t = round(t + 0.05, 3)
            clock.set(t)
            client.step_once(t)
            driver.step_once(t)
            got += received.feed(pty.read())
            time.sleep(0.005)
        assert is_a_run_of_the_log(got) and not received.malformed
        # the last frames reached the receiver's port in the last step: the client had them by then
        frames_until = t
        for _ in range(25):  # the state goes out once a (stack) second
            t = round(t + 0.05, 3)
            clock.set(t)
            client.step_once(t)
            driver.step_once(t)
        statuses.latch()
        status = [m for _, m in statuses.drain()][-1]
        # the age is stack time since the last frame: at most the stack time since `frames_until`
        # (more frames may have come since, on the caster's wall-clock schedule: younger, never older)
        assert status.link == "streaming" and status.age_s is not None
        assert status.age_s <= status.t - frames_until + 0.05 + 1e-9, (status.age_s, status.t, frames_until)
        assert status.source == f"ntrip 127.0.0.1:{c.port}/{MOUNT}" and status.station_id is not None
        assert driver.wires["gnss/rtcm"].published >= 30 and client.counters.connected
        c.close()
        deadline = time.monotonic() + WAIT_S
        until = t + 1.5  # a state goes out within a second
        while client.client.state == "streaming" or t < until:
            assert time.monotonic() < deadline
            t = round(t + 0.05, 3)
            clock.set(t)
            client.step_once(t)
            time.sleep(0.005)
        statuses.latch()
        status = [m for _, m in statuses.drain()][-1]
        assert status.link == "down" and status.outages == 1 and status.outage() is not None
    finally:
        client.teardown()
        driver.teardown()
        pty.close()


def test_behind_the_wire_a_4g_outage_degrades_the_simulated_fix_and_it_recovers():
    """The corrections' path of `ares run --wire` without the rest of the stack: the base station
    (str2str fed the F9T log, an epoch a simulated second) behind the simulated 4G relay, the NTRIP
    client, and the simulated receiver taking the frames. Once fixed, the relay is cut for 20
    simulated seconds: the fix goes RTK fixed -> float -> DGPS; back in coverage the client
    reconnects and the fix is RTK fixed again. Simulated time runs about 20x the wall's."""
    from simulator.base_station import BaseStation, ModemRelay
    from simulator.corrections import ReceiverCorrections
    from simulator.params import SimCorrectionsParams

    caster_port, relay_port = free_port(), free_port()
    base = BaseStation(caster_port, MOUNT, USER, PASSWORD)
    assert base.ready()
    modem = ModemRelay(relay_port, ("127.0.0.1", caster_port))
    client = NtripClient(settings_for(relay_port, silent_after_s=0.3, connect_timeout_s=0.3))
    receiver = ReceiverCorrections(SimCorrectionsParams())
    t = 0.0
    cut: float | None = None  # when the 4G is lost

    def run(until, what: str) -> None:
        nonlocal t
        deadline = time.monotonic() + 3 * WAIT_S
        while not until():
            assert time.monotonic() < deadline, f"{what}: {client.state} {client.events[-3:]}"
            modem.set_up(cut is None or not cut <= t < cut + 20.0)
            if abs(t - round(t)) < 1e-6:
                base.send()  # the base's second
            modem.poll()
            frames = client.poll()
            if frames:
                receiver.received(t, len(frames))
            t = round(t + 0.1, 3)
            time.sleep(0.005)

    try:
        run(lambda: receiver.kind(t).name == "fixed" and t >= 3.0, "the first corrections")
        cut = t
        run(lambda: t >= cut + 8.0, "8 s without 4G")
        assert receiver.kind(t).name == "float"  # the newest 7-8 s old
        run(lambda: t >= cut + 19.0, "19 s without 4G")
        assert receiver.kind(t).name == "dgps"
        run(lambda: t >= cut + 20.0 and receiver.kind(t).name == "fixed", "back in coverage: fixed again")
        assert modem.cuts == 1 and client.connects >= 2 and client.outages >= 1
    finally:
        client.close()
        modem.close()
        base.close()


def test_a_source_table_with_odd_fields_parses():
    odd = "STR;M1;x;RTCM 3.2;1004;²;GPS;N;DEU;nan;inf;1;9;sNTRIP;none;B;N;nan;\r\nSTR;M2\r\nENDSOURCETABLE\r\n"
    mounts = parse_sourcetable(odd)
    assert [m.name for m in mounts] == ["M1", "M2"]
    assert mounts[0].carrier == 0 and mounts[0].lat is None and mounts[0].lon is None and mounts[0].bitrate is None


def test_a_broken_chunked_body_ends_the_stream():
    """A rev 2 answer that says chunked and is not: the link is failed (and tried again), not left
    "streaming" with its bytes piling up."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(1)
    port = server.getsockname()[1]

    def caster() -> None:
        conn, _ = server.accept()
        conn.recv(4096)
        conn.sendall(b"HTTP/1.1 200 OK\r\nTransfer-Encoding: chunked\r\n\r\n" + b"".join(FRAMES[:5]))
        time.sleep(1.0)
        conn.close()

    thread = threading.Thread(target=caster, daemon=True)
    thread.start()
    client = NtripClient(settings_for(port, silent_after_s=5.0))
    try:
        poll_until(client, lambda _: bool(client.events), "the answer")
        assert client.events[0][0] == "bad answer" and "chunk size" in client.events[0][1]
        assert client.state == "idle" and client.outages == 1
    finally:
        client.close()
        thread.join(2.0)
        server.close()
