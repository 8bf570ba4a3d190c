"""The CAN driver (drivers/can_node.py) against the simulator's side of the wire (simulator/can_wire.py),
over a real python-can udp_multicast group in this process: the simulated board, body and IMU send
their frames, the driver node (in-memory bus, manual clock, stepped by hand) publishes them; the
driver sends the bridge's efforts and the body commands, and the simulator's poll() returns them.
Bad frames and a bus that disappears are counted on drivers/status and never stop the driver.

Each test has its own multicast group and UDP port, so parallel workers never hear each other.
Loopback multicast delivers at once; a bounded wait loop covers a scheduler's hiccup. The driver
judges the bus's health (silence, reopening) on a wall clock of its own, a manual one here: no test
waits for it, and none depends on how fast the machine is.
"""

from __future__ import annotations

import itertools
import os
import socket
import time

import can
import pytest

from ares.core import config
from ares.core.clock import ManualClock
from ares.core.config import CanDevice
from ares.core.membus import MemoryNetwork
from ares.core.messages import (
    ActuatorCommand,
    BodyCommand,
    BodyState,
    CanFrame,
    DriverStatus,
    Imu,
    PanelEvent,
    PanelInput,
)
from ares.core.wire.can_frames import checksum
from drivers.can_node import CanDriver
from simulator.can_wire import SimCanPort

PERIOD = 0.02  # the driver's 50 Hz
WAIT_S = 10.0  # wall: the longest a loopback datagram may take before a test gives up (a loaded machine)
_groups = itertools.count(1)

SAMPLE = CanFrame(
    t=0.0,
    wheel_speed_rad_s=7.1,
    speed_mps=1.99,
    steering_wheel_deg=-215.35,
    throttle_pedal=0.25,
    brake_pedal=0.0,
    steering_torque=False,
)
IMU = Imu(
    t=0.0,
    yaw=1.2345,
    roll=0.012,
    pitch=-0.034,
    gyro_x=0.001,
    gyro_y=-0.02,
    gyro_z=0.31,
    accel_x=0.4,
    accel_y=-0.2,
    accel_z=9.79,
)


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("", 0))
        return s.getsockname()[1]


def unique_device() -> CanDevice:
    n = next(_groups)
    return CanDevice(
        interface="udp_multicast", channel=f"239.83.{os.getpid() % 250}.{n % 250 + 1}", port=free_udp_port()
    )


class Rig:
    """The driver node on the in-memory bus and the simulator's port, on one multicast group."""

    def __init__(self, device: CanDevice, **params):
        cfg = config.core_defaults()
        cfg["vehicle_io"] = {"can": device.model_dump()}
        cfg["can_driver"] = params
        self.clock = ManualClock()
        self.wall = ManualClock()  # the driver's judge of the bus's health: moved by the tests alone
        network = MemoryNetwork()
        self.node = CanDriver(cfg, clock=self.clock, bus=network.bus("can_driver", self.clock), wall=self.wall)
        self.node.setup()
        self.sim = SimCanPort(device)
        self.bus = network.bus("test", self.clock)
        self.subs = {
            topic: self.bus.subscribe(topic, queue=1000)
            for topic in ("sensors/can", "sensors/imu", "vehicle/panel", "body/state", "drivers/status")
        }
        self.t = 0.0

    def step(self) -> float:
        self.t = round(self.t + PERIOD, 6)
        self.clock.set(self.t)
        self.node.step_once(self.t)
        return self.t

    def step_until(self, done) -> None:
        """Step until `done()` (each loopback datagram is there at once; this bounds a hiccup)."""
        deadline = time.monotonic() + WAIT_S
        while True:
            self.step()
            if done():
                return
            assert time.monotonic() < deadline, "nothing arrived on the multicast group"
            time.sleep(0.001)

    def got(self, topic: str) -> list:
        return [msg for _, msg in self.subs[topic].drain()]

    def status(self) -> DriverStatus:
        self.node.report(self.t, force=True)
        return self.got("drivers/status")[-1]

    def poll_until(self, count: int) -> tuple[list[ActuatorCommand], list[BodyCommand]]:
        commands: list[ActuatorCommand] = []
        bodies: list[BodyCommand] = []
        deadline = time.monotonic() + WAIT_S
        while len(commands) + len(bodies) < count:
            new_commands, new_bodies = self.sim.poll(self.t)
            commands += new_commands
            bodies += new_bodies
            assert time.monotonic() < deadline, "the simulator heard no command"
            time.sleep(0.001)
        return commands, bodies

    def close(self) -> None:
        self.node.teardown()
        self.sim.close()


@pytest.fixture
def rig():
    r = Rig(unique_device())
    yield r
    r.close()


def test_the_vehicles_frames_come_out_as_the_simulators_topics(rig):
    body = BodyState(t=0.0, doors="opening", ramp="stowed", entrance_clear=False, media=True, passengers=11)
    rig.sim.send_can(SAMPLE)
    rig.sim.send_imu(IMU)
    rig.sim.send_panel(PanelEvent(t=0.0, input=PanelInput.BRAKE_PEDAL, value=0.6))
    rig.sim.send_body(body)
    seen: dict[str, list] = {topic: [] for topic in ("sensors/can", "sensors/imu", "vehicle/panel", "body/state")}

    def all_four() -> bool:
        for topic, found in seen.items():
            found += rig.got(topic)
        return all(seen.values())

    rig.step_until(all_four)
    (can_frame,), (imu,), (panel,), (state,) = seen.values()
    assert can_frame.t == imu.t == panel.t == state.t <= rig.t  # stamped with the step that read them
    assert can_frame.model_dump(exclude={"t"}) == pytest.approx(SAMPLE.model_dump(exclude={"t"}), abs=1e-3)
    assert imu.model_dump(exclude={"t"}) == pytest.approx(IMU.model_dump(exclude={"t"}), abs=1e-3)
    assert (panel.input, panel.value) == (PanelInput.BRAKE_PEDAL, pytest.approx(0.6, rel=1e-6))
    assert state == body.model_copy(update={"t": state.t})
    status = rig.status()
    assert status.device == "can" and status.driver == "can_driver" and status.connected
    assert status.received == 8 and status.published == 4 and status.lost == 0 and status.malformed == {}
    assert status.latency_p50_ms is not None and status.latency_p50_ms >= 0.0


def test_each_actuator_command_goes_out_once_and_body_commands_all(rig):
    rig.bus.publish("dbw/actuators", ActuatorCommand(t=rig.t, engaged=True, steer_effort=0.25, drive_effort=-0.5))
    rig.bus.publish("body/command", BodyCommand(t=rig.t, doors="close"))
    rig.bus.publish("body/command", BodyCommand(t=rig.t, ramp="stow", media=True))
    rig.step()
    (command,), bodies = rig.poll_until(3)
    assert (
        command.engaged and command.steer_effort == pytest.approx(0.25) and command.drive_effort == pytest.approx(-0.5)
    )
    assert command.t == rig.t  # stamped by the simulator's poll
    assert [(b.doors, b.ramp, b.media) for b in bodies] == [("close", None, False), (None, "stow", True)]

    # no new command: nothing goes out, so the board's watchdog sees the bridge's silence. Judged by
    # what arrives first after five steps without one: the body command sent after them (the group
    # keeps one sender's order), not anything sent before it
    for _ in range(5):
        rig.step()
    rig.bus.publish("body/command", BodyCommand(t=rig.t, doors="open"))
    rig.step()
    assert rig.poll_until(1) == ([], [BodyCommand(t=rig.t, doors="open")])

    # two efforts within one step (a late step): only the newest is still worth sending
    for effort in (0.1, 0.2):
        rig.bus.publish("dbw/actuators", ActuatorCommand(t=rig.t, engaged=True, steer_effort=effort, drive_effort=0.0))
    rig.step()
    (newest,), _ = rig.poll_until(1)
    assert newest.steer_effort == pytest.approx(0.2)
    rig.step_until(lambda: rig.status().skipped.get("own direction") == 5)  # its own frames, looped back
    status = rig.status()
    assert status.skipped == {"superseded command": 1, "own direction": 5}
    assert "sent Body_Command 3, DBW_Command 2" in status.detail
    assert rig.sim.lost == 0 and not rig.sim.refused


def test_lost_and_malformed_frames_are_counted_by_cause_and_reading_goes_on(rig):
    rig.sim.send_can(SAMPLE)  # counter 0
    rig.step_until(lambda: bool(rig.got("sensors/can")))
    rig.sim.encoder.encode(SAMPLE)  # counter 1: a sample the bus lost, its three frames unseen
    wire = rig.sim.bus
    speed = rig.node.codec.by_name["VehicleSpeed"]
    corrupt = rig.sim.encoder.encode(SAMPLE)[2]  # counter 2: only its VehicleSpeed frame sent, corrupted
    corrupt.data[0] ^= 0xFF
    wire.send(corrupt)
    wire.send(can.Message(arbitration_id=0x555, is_extended_id=False, data=bytes(8)))
    wire.send(can.Message(arbitration_id=speed.frame_id, is_extended_id=False, data=bytes(4)))
    wild = bytearray(speed.length)
    wild[0:2] = (0x8000).to_bytes(2, "little")  # a wheel speed of -65.536 rad/s: one step beyond its range
    wild[4] = 2  # a counter the board could send next
    wild[speed.checksum_byte] = checksum(speed, wild)
    wire.send(can.Message(arbitration_id=speed.frame_id, is_extended_id=False, data=wild))
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as raw:  # a datagram on the group that is no frame
        raw.sendto(b"\x00garbage", (rig.sim.device.channel, rig.sim.device.port))
    rig.step_until(lambda: sum(rig.status().malformed.values()) == 5)
    rig.sim.send_can(SAMPLE)  # counter 3
    rig.step_until(lambda: bool(rig.got("sensors/can")))
    status = rig.status()
    assert status.malformed == {
        "bad checksum": 1,
        "unknown id": 1,
        "bad length": 1,
        "out of range": 1,
        "undecodable": 1,
    }
    # VehicleSpeed: 0, then 2 (the wild frame; 1 lost), then 3; SteeringWheel and Pedals: 0 then 3
    assert status.lost == 1 + 2 + 2
    assert status.published == 2 and status.connected


def test_a_bus_that_disappears_is_reopened(caplog):
    rig = Rig(unique_device(), reopen_s=0.25)
    try:
        rig.sim.send_can(SAMPLE)
        rig.step_until(lambda: bool(rig.got("sensors/can")))
        rig.node._bus.shutdown()  # the socket closes under the driver, as when the interface goes away
        rig.step()
        assert not rig.status().connected and "bus failed" in caplog.text
        rig.bus.publish("dbw/actuators", ActuatorCommand(t=rig.t, engaged=False, steer_effort=0.0, drive_effort=0.0))
        rig.wall.advance(0.2)
        rig.step()  # no bus yet (reopen_s not out): the command is dropped, not kept to go out stale later
        assert rig.status().skipped == {"commands while disconnected": 1}
        rig.wall.advance(0.05)
        rig.step()  # reopen_s after the failure: opened again
        rig.sim.send_can(SAMPLE)
        rig.step_until(lambda: bool(rig.got("sensors/can")))
        assert rig.status().connected
    finally:
        rig.close()


def test_a_device_that_cannot_be_opened_is_retried_without_stopping_the_driver(caplog):
    # 192.0.2.1 (TEST-NET-1) is no multicast group: joining it fails at once, without a name lookup
    device = CanDevice(interface="udp_multicast", channel="192.0.2.1", port=free_udp_port())
    cfg = config.core_defaults()
    cfg["vehicle_io"] = {"can": device.model_dump()}
    clock = ManualClock()
    network = MemoryNetwork()
    node = CanDriver(cfg, clock=clock, bus=network.bus("can_driver", clock))
    node.setup()
    statuses = network.bus("test", clock).subscribe("drivers/status", queue=10)
    for i in range(3):
        clock.set(i * PERIOD)
        node.step_once(i * PERIOD)
    assert "cannot open" in caplog.text
    (_, status), *_ = statuses.drain()
    assert not status.connected and status.received == 0
    node.teardown()


def test_a_bus_of_only_garbage_is_not_connected():
    """Frames that are all refused (bad checksums, unknown ids) are no vehicle speaking: before, they
    kept `connected` true; now the bus goes silent, is reopened, and each frame is counted."""
    rig = Rig(unique_device(), silent_after_s=0.2)
    try:
        rig.sim.send_can(SAMPLE)
        rig.step_until(lambda: bool(rig.got("sensors/can")))
        assert rig.status().connected
        wire = rig.sim.bus
        sent = 100
        for _ in range(sent):  # 0.5 s of garbage, a frame every 5 ms: longer than the silence
            wire.send(can.Message(arbitration_id=0x555, is_extended_id=False, data=bytes(8)))
            rig.wall.advance(0.005)
            rig.step()
        status = rig.status()
        assert not status.connected and sent // 2 < status.malformed["unknown id"] <= sent  # (a reopen drops a few)
        rig.sim.send_can(SAMPLE)  # the vehicle again
        rig.step_until(lambda: bool(rig.got("sensors/can")))
        assert rig.status().connected
    finally:
        rig.close()


def test_a_vehicle_gone_silent_marks_the_bus_disconnected():
    rig = Rig(unique_device(), silent_after_s=0.2)
    try:
        assert not rig.status().connected  # open, but the vehicle has not spoken yet
        rig.sim.send_can(SAMPLE)
        rig.step_until(lambda: bool(rig.got("sensors/can")))
        assert rig.status().connected
        rig.wall.advance(0.19)
        rig.step()
        assert rig.status().connected  # not silent yet
        rig.wall.advance(0.02)
        rig.step()
        assert not rig.status().connected
        # reopened at once: the vehicle is heard again with no more time for a reopening
        rig.sim.send_can(SAMPLE)
        rig.step_until(lambda: bool(rig.got("sensors/can")))
        assert rig.status().connected
    finally:
        rig.close()


def test_latencies_are_kept_in_bounded_memory():
    """A driver's counters after a day's worth of frames at 80 a second would have held every
    latency (about 220 MB); now only the window the percentiles are taken over."""
    import logging

    from ares.core.driver import LATENCY_WINDOW, WireCounters

    counters = WireCounters("can", logging.getLogger("test"))
    now = time.time()
    for _ in range(50_000):
        counters.put(read_wall=now)
    held = [len(v) for v in vars(counters).values() if hasattr(v, "__len__") and not isinstance(v, str)]
    assert max(held) == LATENCY_WINDOW and counters.published == 50_000
    assert counters.percentile_ms(50) is not None
