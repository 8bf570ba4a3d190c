"""A Velodyne's packets kept in place of its clouds (ares/core/wire/velodyne_packets.py): the driver
publishes each step's packets before the clouds they finish; the decoder it used makes the very
same clouds from them (real captures, tests/data/lidar, and a stream that falls silent mid-rotation);
a recording keeps the packets, not the clouds, gives the clouds back when read, and `ares replay
--node lidar_driver` compares the decoding with what the driver published."""

from __future__ import annotations

import socket
import time
from pathlib import Path

import numpy as np
import pytest

from ares.app import run_config
from ares.app.bus_record import mcap_replay
from ares.app.bus_record.recorder import McapRecorder
from ares.core import config, schema
from ares.core.clock import ManualClock
from ares.core.localhost import free_port
from ares.core.membus import MemoryNetwork
from ares.core.messages import LidarPackets, PointCloud
from ares.core.wire.velodyne_packets import PacketDecoder, packets_message, packets_of
from drivers.velodyne_node import VelodyneDriver
from tests.test_velodyne_driver import UTC_EPOCH, sweep_packets, take

CAPTURES = Path(__file__).parent / "data" / "lidar"


class Driven:
    """The driver on the in-memory bus, its packets and clouds as published, in order."""

    def __init__(self, device: dict, silent_after_s: float = 30.0, driver_lidar: str = "packets"):
        self.cfg = {
            "vehicle_io": {"lidars": {"front_left": device}},
            "lidar_driver": {"silent_after_s": silent_after_s},
            "recording": {"driver_lidar": driver_lidar},
        }
        self.clock = ManualClock(100.0, utc_epoch=UTC_EPOCH)
        network = self.network = MemoryNetwork()
        self.node = VelodyneDriver(self.cfg, clock=self.clock, bus=network.bus("lidar_driver", self.clock))
        self.node.setup()
        self.packets = network.bus("test", self.clock).subscribe("lidar/front_left/packets", queue=10_000)
        self.clouds = network.bus("test2", self.clock).subscribe("lidar/front_left/points", queue=10_000)
        self.got_packets: list[LidarPackets] = []
        self.got_clouds: list[PointCloud] = []

    def step(self, dt: float = 0.02) -> None:
        t = round(self.clock.now() + dt, 6)
        self.clock.set(t)
        self.node.step_once(t)
        self.got_packets += take(self.packets)
        self.got_clouds += take(self.clouds)

    def device(self):
        return config.core(self.cfg).vehicle_io.lidars["front_left"]

    def close(self) -> None:
        self.node.teardown()


def rebuilt(driven: Driven) -> list[PointCloud]:
    decoder = PacketDecoder("front_left", driven.device(), driven.node.params.truncated_below_deg)
    return [cloud for message in driven.got_packets for cloud in decoder.feed(message)]


def same_clouds(made: list[PointCloud], published: list[PointCloud]) -> None:
    assert len(made) == len(published)
    for a, b in zip(made, published, strict=True):
        assert bytes(schema.encode(a)) == bytes(schema.encode(b))  # stamp, points, rings: byte for byte


@pytest.mark.parametrize(
    ("capture", "model", "rate_hz", "whole"),
    [("VLP-16_early_20Hz.pcap", "VLP-16", 20.0, 50), ("VLP-16_dual.pcap", "VLP-16", 10.0, 4),
     ("HDL-32E.pcap", "HDL-32E", 11.77, 11)],
)  # fmt: skip
def test_the_clouds_made_again_from_a_real_captures_packets_are_the_drivers(capture, model, rate_hz, whole):
    driven = Driven({"model": model, "pcap": str(CAPTURES / capture), "port": 2368, "rate_hz": rate_hz})
    try:
        for _ in range(250):
            driven.step()
    finally:
        driven.close()
    assert len(driven.got_clouds) == whole
    assert driven.got_packets[-1].flushed  # the capture's end: the rotation under way finished as it was
    assert sum(len(m.sizes) for m in driven.got_packets) == driven.node.wires["lidar/front_left"].received
    same_clouds(rebuilt(driven), driven.got_clouds)


def test_a_rotation_finished_because_the_stream_fell_silent_is_made_again_too():
    """A sweep without its last packets, then silence: the driver publishes what it had once the
    sensor counts as silent; the packets' message says so and the decoder does the same."""
    port = free_port()
    driven = Driven({"model": "VLP-16", "address": "127.0.0.1", "port": port}, silent_after_s=0.2)
    out = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        driven.step()  # binds
        first, _ = sweep_packets("VLP-16", 100.05)
        second, _ = sweep_packets("VLP-16", 100.15)
        for packet in first + second[:-4]:  # the second sweep short of its last 4 packets
            out.sendto(packet, ("127.0.0.1", port))
        deadline = time.monotonic() + 10.0
        while len(driven.got_clouds) < 1 and time.monotonic() < deadline:
            driven.step()
        time.sleep(0.3)  # silent, by the wall clock
        deadline = time.monotonic() + 10.0
        while not any(m.flushed for m in driven.got_packets) and time.monotonic() < deadline:
            driven.step()
            time.sleep(0.01)
    finally:
        out.close()
        driven.close()
    assert len(driven.got_clouds) == 2 and driven.got_packets[-1].flushed and not len(driven.got_packets[-1].sizes)
    same_clouds(rebuilt(driven), driven.got_clouds)


def test_no_packets_published_when_the_recording_keeps_clouds():
    driven = Driven(
        {"model": "VLP-16", "pcap": str(CAPTURES / "VLP-16_dual.pcap"), "port": 2368}, driver_lidar="clouds"
    )
    try:
        for _ in range(100):
            driven.step()
    finally:
        driven.close()
    assert len(driven.got_clouds) == 4 and not driven.got_packets


def test_packets_travel_whole_and_a_torn_message_is_refused():
    packets = [(bytes([k]) * (1206 - k), 1.5 + k) for k in range(3)]
    message = packets_message(2.0, "roof", 10.0, packets)
    again = schema.decode(bytes(schema.encode(message)), LidarPackets)
    assert list(packets_of(again)) == packets and not again.flushed and again.epoch == 10.0
    with pytest.raises(ValueError, match="as many bytes"):
        LidarPackets(t=1.0, sensor="roof", epoch=0.0, sizes=np.array([10], dtype="<u2"), received=np.array([1.0]),
                     data=np.zeros(1, np.uint8))  # fmt: skip


# ---- in a recording ----------------------------------------------------------------------------------


def recorded_run(tmp_path: Path, driver_lidar: str) -> tuple[Path, Driven]:
    """The dual-return capture through the driver, its bus recorded as `ares run --wire` records it."""
    capture = {"model": "VLP-16", "pcap": str(CAPTURES / "VLP-16_dual.pcap"), "port": 2368}
    cfg = run_config.build((), {"lidars": True, "wire": True})
    cfg["vehicle_io"] = {**cfg.get("vehicle_io", {}), "lidars": {"front_left": capture}}
    cfg["recording"] = {**cfg.get("recording", {}), "driver_lidar": driver_lidar}
    path = tmp_path / f"{driver_lidar}.mcap"
    driven = Driven(capture, driver_lidar=driver_lidar)
    recorder = McapRecorder(path, cfg, utc_epoch=UTC_EPOCH)
    assert recorder.packet_lidars == (["front_left"] if driver_lidar == "packets" else [])
    recorder.attach(driven.network.bus("recorder", driven.clock))
    recorder.start()
    try:
        for _ in range(100):
            driven.step()
    finally:
        driven.close()
    stats = recorder.close()
    assert stats.left_to_packets == (4 if driver_lidar == "packets" else 0)
    return path, driven


def test_a_recording_keeps_the_packets_and_gives_the_clouds_back(tmp_path):
    path, driven = recorded_run(tmp_path, "packets")
    channels = {c["topic"].rsplit("/", 1)[-1] for c in mcap_replay.info(path)["channels"]}
    assert "packets" in channels and "points" not in channels
    recording = mcap_replay.open_recording(path)
    clouds = [
        schema.decode(m.payload, PointCloud) for m in recording.messages() if m.topic == "lidar/front_left/points"
    ]
    same_clouds(clouds, driven.got_clouds)
    with pytest.raises(ValueError, match="its clouds are not"):
        mcap_replay.replay_node(path, "lidar_driver")


def test_the_drivers_decoding_replays_identically_from_a_recording_of_both(tmp_path):
    path, driven = recorded_run(tmp_path, "both")
    result = mcap_replay.replay_node(path, "lidar_driver")
    assert result.ok and result.outputs == 4 and result.steps == len(driven.got_packets)
    assert result.unrecorded_steps == 0
