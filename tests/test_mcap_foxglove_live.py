"""The live Foxglove bridge (ares.app.bus_record.foxglove_live): a WebSocket server on loopback that
speaks Foxglove's protocol, and what it logs from the bus (read back through an MCAP sink on the
bridge's own foxglove context)."""

from __future__ import annotations

import base64
import json
import os
import socket
import time

import foxglove
import numpy as np
import pytest
from mcap.reader import make_reader

from ares.app.bus_record.foxglove_live import FoxgloveBridge
from ares.core import config
from ares.core.clock import ManualClock
from ares.core.membus import MemoryNetwork
from ares.core.messages import OccupancyGrid, Pose

WAIT_S = 10.0  # for the bridge's worker thread (a loaded machine): a bound, not a measure


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def websocket_open(port: int) -> tuple[socket.socket, bytes]:
    """An RFC 6455 handshake asking for Foxglove's subprotocol; the reply's head and what follows."""
    sock = socket.create_connection(("127.0.0.1", port), timeout=WAIT_S)
    key = base64.b64encode(os.urandom(16)).decode()
    sock.sendall(
        (
            f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
            f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n"
            "Sec-WebSocket-Protocol: foxglove.sdk.v1\r\n\r\n"
        ).encode()
    )
    data = b""
    while b"\r\n\r\n" not in data:
        data += sock.recv(4096)
    return sock, data


class Frames:
    """The server's WebSocket frames, read in order (unmasked, as a server sends them)."""

    def __init__(self, sock: socket.socket, pending: bytes):
        self.sock, self.data = sock, pending

    def _need(self, n: int) -> None:
        while len(self.data) < n:
            self.data += self.sock.recv(65536)

    def next_text(self) -> dict:
        while True:
            self._need(2)
            length, at = self.data[1] & 0x7F, 2
            if length == 126:
                self._need(4)
                length, at = int.from_bytes(self.data[2:4], "big"), 4
            elif length == 127:
                self._need(10)
                length, at = int.from_bytes(self.data[2:10], "big"), 10
            self._need(at + length)
            opcode, payload = self.data[0] & 0x0F, self.data[at : at + length]
            self.data = self.data[at + length :]
            if opcode == 1:
                return json.loads(payload)


@pytest.fixture(scope="module")
def cfg():
    return config.core_defaults()  # the views need the core sections only


def pose(t: float) -> Pose:
    return Pose(
        t=t, x=10.0, y=5.0, z=0.0, yaw=0.5, v=1.0, yaw_rate=0.0, cov_xx=0.01, cov_xy=0.0, cov_yy=0.01,
        var_yaw=1e-4, var_v=0.01, position_std_m=0.1, rtk=True, gnss_age_s=0.1,
    )  # fmt: skip


def test_the_bridge_speaks_foxglove_on_loopback_and_advertises_the_views(cfg):
    port = free_port()
    bridge = FoxgloveBridge(cfg, utc_epoch=1_790_000_000.0, port=port)
    try:
        sock, head = websocket_open(port)
        with sock:
            status, _, rest = head.partition(b"\r\n\r\n")
            assert status.startswith(b"HTTP/1.1 101") and b"foxglove.sdk.v1" in status
            frames = Frames(sock, rest)
            info = frames.next_text()
            assert info["op"] == "serverInfo" and info["name"] == f"ARES {cfg['vehicle_id']}"
            advertised = frames.next_text()
            assert advertised["op"] == "advertise"
            schemas = {c["topic"]: c["schemaName"] for c in advertised["channels"]}
            assert schemas["foxglove/tf"] == "foxglove.FrameTransforms"
            assert schemas["foxglove/lidar/roof/points"] == "foxglove.PointCloud"
            assert schemas["foxglove/perception/grid"] == "foxglove.Grid"
    finally:
        bridge.close()


def test_the_bridge_logs_the_bus_and_its_views(tmp_path, cfg):
    bridge = FoxgloveBridge(cfg, utc_epoch=1_790_000_000.0, port=free_port())
    sink = foxglove.open_mcap(tmp_path / "seen.mcap", context=bridge.context)
    clock = ManualClock()
    network = MemoryNetwork(cfg["vehicle_id"])
    bus = network.bus("bridge", clock)
    bridge.attach(bus)
    feeder = network.bus("sim", clock)
    try:
        feeder.publish("localization/pose", pose(1.0))
        grid = OccupancyGrid(t=1.0, frame="vehicle", resolution_m=0.2, origin_x=-10, origin_y=-10,
                             cells=np.zeros((100, 100), "u1"))  # fmt: skip
        feeder.publish("perception/grid", grid)  # no client subscribed to its view: not converted
        deadline = time.monotonic() + WAIT_S
        while bridge.logged < 3 and time.monotonic() < deadline:
            time.sleep(0.02)
    finally:
        bridge.close(bus)
        sink.close()
    with open(tmp_path / "seen.mcap", "rb") as f:
        seen = {channel.topic: schema.name for schema, channel, _ in make_reader(f).iter_messages()}
    key = f"ares/{cfg['vehicle_id']}/localization/pose"
    assert seen[key] == "Pose"
    assert seen["foxglove/pose/location"] == "foxglove.LocationFix"
    assert seen["foxglove/tf"] == "foxglove.FrameTransforms"
    assert "foxglove/perception/grid" not in seen


def test_where_the_bridge_listens_defaults_to_loopback():
    from ares.app.bus_record.in_run import host_port

    assert host_port("127.0.0.1:8765") == ("127.0.0.1", 8765)
    assert host_port("9000") == ("127.0.0.1", 9000)
    assert host_port("0.0.0.0:9001") == ("0.0.0.0", 9001)
    assert host_port(":9002") == ("127.0.0.1", 9002)
    assert host_port("") == ("127.0.0.1", 8765)  # `--foxglove` alone
