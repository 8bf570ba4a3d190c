"""The drive-by-wire bridge as a real process on a real router: modes, service, watchdog."""
import math
import threading
import time

import pytest

from ares.bus import Bus
from ares.clock import Clock
from ares.messages import CanFrame, DriveMode, PanelEvent, PanelInput, Setpoint

pytestmark = pytest.mark.stack


def wait_until(condition, timeout_s=5.0, what="condition"):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if condition():
            return time.monotonic()
        time.sleep(0.02)
    raise AssertionError(f"timed out waiting for {what}")


@pytest.fixture
def bridge(router, spawn_node):
    clock = Clock()
    bus = Bus(router, "test", clock)
    spawn_node("control.dbw_bridge", "dbw_bridge")
    car = bus.subscribe("dbw/car_state")
    actuators = bus.subscribe("dbw/actuators")
    reference = bus.subscribe("dbw/reference")
    events = bus.subscribe("events", queue=100)
    stop = threading.Event()

    def can_feed():   # a vehicle standing still, nobody touching the controls
        while not stop.is_set():
            bus.publish("sensors/can", CanFrame(t=clock.now(), wheel_speed_rad_s=0.0, speed_mps=0.0,
                                                steering_wheel_deg=0.0, throttle_pedal=0.0,
                                                brake_pedal=0.0, steering_torque=False))
            time.sleep(0.05)

    feeder = threading.Thread(target=can_feed, daemon=True)
    feeder.start()
    wait_until(lambda: car.latest is not None, 20.0, "the bridge's car state")
    yield bus, car, actuators, reference, events
    stop.set()
    feeder.join()
    bus.close()


def press(bus, what: PanelInput):
    bus.publish("vehicle/panel", PanelEvent(t=bus.clock.now(), input=what))


def test_manual_ready_automatic_and_back(bridge):
    bus, car, actuators, reference, events = bridge
    assert car.latest.mode == DriveMode.MANUAL
    refused = bus.call("set_automatic_mode")
    assert not refused.accepted and "button" in refused.reason.lower()
    wait_until(lambda: actuators.latest is not None and not actuators.latest.engaged, what="disengaged")

    press(bus, PanelInput.BUTTON)
    wait_until(lambda: car.latest.mode == DriveMode.READY, what="Ready")
    wait_until(lambda: actuators.latest.engaged, what="engaged in Ready")
    assert car.latest.v_command == 0.0 and car.latest.kappa_command == 0.0   # null setpoints

    accepted = bus.call("set_automatic_mode")
    assert accepted.accepted and accepted.mode == DriveMode.AUTOMATIC

    kappa = 0.05
    for _ in range(10):
        bus.publish("control/setpoint", Setpoint(t=bus.clock.now(), v=2.0, kappa=kappa, source="test"))
        time.sleep(0.05)
    wait_until(lambda: car.latest.v_command == 2.0, what="setpoint in use")
    wheelbase = 2.8
    expected_deg = math.degrees(40 * math.atan(kappa * wheelbase))
    assert reference.latest.steering_wheel_deg == pytest.approx(expected_deg, rel=1e-6)
    assert actuators.latest.drive_effort > 0 and actuators.latest.steer_effort > 0

    press(bus, PanelInput.THROTTLE_PEDAL)
    wait_until(lambda: car.latest.mode == DriveMode.MANUAL, what="Manual after a pedal")
    wait_until(lambda: not actuators.latest.engaged, what="disengaged after a pedal")
    kinds = [(m.kind, m.data.get("to")) for _, m in events.drain()]
    assert ("mode_change", "READY") in kinds and ("mode_change", "AUTOMATIC") in kinds
    assert ("mode_change", "MANUAL") in kinds


def test_setpoint_watchdog_stops_and_centres_then_recovers(bridge):
    bus, car, actuators, reference, events = bridge
    press(bus, PanelInput.BUTTON)
    wait_until(lambda: car.latest.mode == DriveMode.READY, what="Ready")
    assert bus.call("set_automatic_mode").accepted
    for _ in range(10):
        bus.publish("control/setpoint", Setpoint(t=bus.clock.now(), v=3.0, kappa=-0.08, source="test"))
        time.sleep(0.05)
    wait_until(lambda: car.latest.v_command == 3.0, what="setpoint in use")
    last_setpoint = time.monotonic()
    tripped_at = wait_until(lambda: car.latest.watchdog_tripped, 3.0, "the watchdog")
    assert 0.9 <= tripped_at - last_setpoint <= 1.5
    assert car.latest.v_command == 0.0 and car.latest.kappa_command == 0.0
    assert reference.latest.steering_wheel_deg == 0.0
    assert car.latest.mode == DriveMode.AUTOMATIC
    bus.publish("control/setpoint", Setpoint(t=bus.clock.now(), v=1.0, kappa=0.0, source="test"))
    wait_until(lambda: not car.latest.watchdog_tripped and car.latest.v_command == 1.0, what="recovery")
    assert any(m.kind == "watchdog" for _, m in events.drain())


def test_corrupt_setpoints_are_rejected_and_the_bridge_keeps_running(bridge):
    bus, car, actuators, reference, events = bridge
    key = bus.key("control/setpoint")
    for payload in (b"garbage", b'{"t": 0, "v": "fast", "kappa": 0, "source": "x"}',
                    b'{"t": 0, "v": 1e999, "kappa": 0, "source": "x"}'):
        bus.session.put(key, payload)
    seen = car.count
    wait_until(lambda: car.count > seen + 5, what="car state after corrupt input")
    assert car.latest.mode == DriveMode.MANUAL
