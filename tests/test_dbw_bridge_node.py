"""The drive-by-wire bridge node on the in-memory bus, stepped by hand: the mode machine of Fig. 17
(button, set_automatic_mode, pedals, steering wheel), setpoints through Ackermann to the inner
loops, the 1 s setpoint watchdog and the standstill brake, as dbw/actuators, dbw/car_state and
the events it publishes show them. Its contract: what it declares, and nothing beyond."""

from __future__ import annotations

import math

import pytest

from ares.core import config, topics
from ares.core.clock import ManualClock
from ares.core.membus import MemoryNetwork
from ares.core.messages import CanFrame, DriveMode, EventLevel, Imu, MovementCommand, PanelEvent, PanelInput
from ares.core.node import ContractError
from control import dbw_bridge_node as dbw_bridge
from control.dbw_bridge_node import DbwBridge

PERIOD = 0.1  # the bridge's 10 Hz
SHUTTLE_WHEELBASE = 2.8  # ares_shuttle, the default vehicle
SHUTTLE_MAX_KAPPA = math.tan(0.31) / 2.8
SHUTTLE_MAX_SPEED = 4.0
STANDSTILL_BRAKE = 0.5  # dbw_bridge.standstill_brake_effort
STANDING = {
    "wheel_speed_rad_s": 0.0,
    "speed_mps": 0.0,
    "steering_wheel_deg": 0.0,
    "throttle_pedal": 0.0,
    "brake_pedal": 0.0,
    "steering_torque": False,
}


def steering_wheel_deg(kappa: float) -> float:
    """DBW paper eq. 13 on the shuttle: alpha = 40 atan(kappa S), in degrees."""
    return math.degrees(40 * math.atan(kappa * SHUTTLE_WHEELBASE))


class BridgeOnTheBus:
    """The bridge node and a test process on one in-memory network; time moves when told."""

    def __init__(self, cfg: dict):
        self.clock = ManualClock()
        self.network = MemoryNetwork()
        self.node = DbwBridge(cfg, clock=self.clock, bus=self.network.bus("dbw_bridge", self.clock))
        self.node.setup()
        self.bus = self.network.bus("test", self.clock)
        self.actuators = self.bus.subscribe("dbw/actuators", queue=1000)
        self.car = self.bus.subscribe("dbw/car_state", queue=1000)
        self.reference = self.bus.subscribe("dbw/reference")
        self.measure = self.bus.subscribe("dbw/measure")
        self.events = self.bus.subscribe("events", queue=1000)

    def step(self, t: float, can: dict | None = STANDING, **can_changes):
        """One period at stack time t, the CAN frame of that moment published just before it."""
        self.clock.set(t)
        if can is not None:
            self.bus.publish("sensors/can", CanFrame(t=t, **{**can, **can_changes}))
        self.node.step_once(t)
        return self.car.latest, self.actuators.latest

    def imu(self, pitch: float) -> None:
        """An IMU reading at rest with this pitch (REP-103: a climb's is negative)."""
        g = 9.81
        self.bus.publish(
            "sensors/imu",
            Imu(
                t=self.clock.now(), yaw=0.0, roll=0.0, pitch=pitch, gyro_x=0.0, gyro_y=0.0, gyro_z=0.0,
                accel_x=-g * math.sin(pitch), accel_y=0.0, accel_z=g * math.cos(pitch),
            ),
        )  # fmt: skip

    def press(self, what: PanelInput) -> None:
        self.bus.publish("vehicle/panel", PanelEvent(t=self.clock.now(), input=what))

    def setpoint(self, v: float, kappa: float, stamp: float | None = None, emergency: bool = False) -> None:
        t = self.clock.now() if stamp is None else stamp
        self.bus.publish("movement/command", MovementCommand(t=t, v=v, kappa=kappa, emergency=emergency, source="test"))

    def set_automatic_mode(self):
        return self.bus.call("set_automatic_mode")

    def new_events(self) -> list:
        return [event for _, event in self.events.drain()]

    def mode_changes(self) -> list[tuple[str, str, str]]:
        return [(e.data["from"], e.data["to"], e.data["cause"]) for e in self.new_events() if e.kind == "mode_change"]

    def arm(self, t: float) -> float:
        """Button at t, set_automatic_mode, then (2.0, 0.05) every period up to t + 1.0; returns
        the time of the next period, t + 1.1."""
        self.press(PanelInput.BUTTON)
        self.step(t)
        assert self.set_automatic_mode().accepted
        for now in ticks(t + PERIOD, t + 1.0):
            self.setpoint(2.0, 0.05, stamp=now)  # produced just before the bridge's period
            self.step(now)
        assert self.car.latest.mode == DriveMode.AUTOMATIC and self.car.latest.v_command == 2.0
        self.new_events()
        return round(t + 1.1, 9)


def ticks(start: float, stop: float) -> list[float]:
    """Stack times of the bridge's periods from start up to stop, both included."""
    count = round((stop - start) / PERIOD)
    return [round(start + k * PERIOD, 9) for k in range(count + 1)]


@pytest.fixture
def bridge(run_config) -> BridgeOnTheBus:
    # the DBW paper's 1 s watchdog (the stack's is shorter: the movement manager sends at 50 Hz)
    return BridgeOnTheBus(config.deep_merge(run_config, {"dbw_bridge": {"setpoint_timeout_s": 1.0}}))


# ---- the contract ---------------------------------------------------------------------------------


def test_the_contract_is_the_documented_one():
    # DBW paper §4 as the node documents it: navigation setpoints, the control panel and the CAN
    # readings in; efforts, the inner loops' references and measurements and the car's state
    # out; the software half of the Manual -> Ready -> Automatic switch as a service
    assert "navigation setpoints in, actuator efforts out" in dbw_bridge.__doc__
    assert {i.topic: i.attr for i in DbwBridge.inputs()} == {
        "movement/command": "setpoints",
        "vehicle/panel": "panel",
        "sensors/can": "can",
        "sensors/imu": "imu",
    }
    assert {o.topic: o.attr for o in DbwBridge.outputs()} == {
        "dbw/actuators": "actuators",
        "dbw/reference": "reference",
        "dbw/measure": "measure",
        "dbw/car_state": "car_state",
    }
    assert DbwBridge.services() == {"set_automatic_mode": "_set_automatic_mode"}
    # every setpoint and every driver action is handled, none is lost between two periods
    assert DbwBridge.setpoints.queue == 64 and DbwBridge.panel.queue == 64
    assert topics.topic("vehicle/panel").reliable


def test_the_contract_refuses_anything_undeclared(bridge):
    declared = bridge.node.bus.publisher("dbw/car_state")
    assert declared.topic == "dbw/car_state"
    # the command topic has one publisher, the movement manager: never the bridge itself
    with pytest.raises(ContractError, match="does not declare"):
        bridge.node.bus.publish("movement/command", MovementCommand(t=0.0, v=1.0, kappa=0.0, source="dbw_bridge"))
    with pytest.raises(ContractError, match="does not declare"):
        bridge.node.bus.publisher("path/match")
    with pytest.raises(ContractError, match="outside its contract"):
        bridge.node.bus.subscribe("localization/pose")
    with pytest.raises(ContractError, match="outside its contract"):
        bridge.node.bus.serve("set_automatic_mode", lambda request: None)
    assert bridge.network.published[bridge.bus.key("movement/command")] == 0


def test_everything_the_bridge_publishes_is_declared(bridge):
    bridge.step(0.0)
    t = bridge.arm(0.1)
    bridge.press(PanelInput.BRAKE_PEDAL)
    bridge.step(t)
    fed = {bridge.bus.key(topic) for topic in ("sensors/can", "vehicle/panel", "movement/command")}
    declared = {bridge.bus.key(o.topic) for o in DbwBridge.outputs()} | {bridge.bus.key("events")}
    assert set(bridge.network.published) - fed == declared


# ---- the mode machine through the bus ------------------------------------------------------------


def test_starts_in_manual_and_refuses_automatic_before_the_button(bridge):
    car, actuators = bridge.step(0.0)
    assert car.mode == DriveMode.MANUAL and not car.engaged
    assert not actuators.engaged and actuators.steer_effort == 0.0 and actuators.drive_effort == 0.0
    refused = bridge.set_automatic_mode()
    assert not refused.accepted and refused.mode == DriveMode.MANUAL
    assert "button" in refused.reason.lower()
    # setpoints in Manual move nothing
    bridge.setpoint(2.0, 0.05)
    car, actuators = bridge.step(0.1)
    assert car.mode == DriveMode.MANUAL and (car.v_command, car.kappa_command) == (0.0, 0.0)
    assert not actuators.engaged and actuators.drive_effort == 0.0
    assert bridge.mode_changes() == []


def test_the_button_arms_ready_with_null_setpoints_and_the_brake_held(bridge):
    bridge.step(0.0)
    bridge.press(PanelInput.BUTTON)
    car, actuators = bridge.step(0.1)
    assert car.mode == DriveMode.READY and car.engaged and not car.watchdog_tripped
    assert (car.v_command, car.kappa_command) == (0.0, 0.0)
    assert actuators.engaged and actuators.steer_effort == 0.0
    assert actuators.drive_effort == -STANDSTILL_BRAKE  # standing still: the board holds the brake
    assert bridge.mode_changes() == [("MANUAL", "READY", "BUTTON")]
    # Ready sends null setpoints whatever navigation asks
    bridge.setpoint(2.0, 0.05)
    car, actuators = bridge.step(0.2)
    assert car.mode == DriveMode.READY and (car.v_command, car.kappa_command) == (0.0, 0.0)
    assert bridge.reference.latest.steering_wheel_deg == 0.0 and bridge.reference.latest.wheel_speed_deg_s == 0.0
    # and the button again goes back to Manual
    bridge.press(PanelInput.BUTTON)
    car, actuators = bridge.step(0.3)
    assert car.mode == DriveMode.MANUAL and not actuators.engaged
    assert bridge.mode_changes() == [("READY", "MANUAL", "BUTTON")]


def test_automatic_drives_the_setpoints_through_ackermann_to_the_inner_loops(bridge):
    bridge.step(0.0)
    bridge.press(PanelInput.BUTTON)
    bridge.step(0.1)
    accepted = bridge.set_automatic_mode()
    assert accepted.accepted and accepted.mode == DriveMode.AUTOMATIC
    assert bridge.mode_changes() == [("MANUAL", "READY", "BUTTON"), ("READY", "AUTOMATIC", "SET_AUTOMATIC")]
    kappa = 0.05
    bridge.setpoint(2.0, kappa)
    bridge.imu(0.0)  # on the flat (the hill-hold lets go at once)
    car, actuators = bridge.step(0.2)
    assert car.mode == DriveMode.AUTOMATIC and not car.watchdog_tripped
    assert (car.v_command, car.kappa_command) == (2.0, kappa)
    reference = bridge.reference.latest
    assert reference.steering_wheel_deg == pytest.approx(steering_wheel_deg(kappa), rel=1e-9)
    theta = math.atan(kappa * SHUTTLE_WHEELBASE)
    assert reference.wheel_speed_deg_s == pytest.approx(math.degrees(2.0 / (math.cos(theta) * 0.28)), rel=1e-9)
    # standing still with the wheel centred: both loops push towards the reference, no brake
    assert actuators.engaged and actuators.steer_effort > 0 and actuators.drive_effort > 0
    # asking again while Automatic changes nothing
    again = bridge.set_automatic_mode()
    assert again.accepted and again.mode == DriveMode.AUTOMATIC and "already" in again.reason
    assert bridge.mode_changes() == []


def test_measurements_are_reported_as_speed_and_curvature(bridge):
    bridge.step(0.0, can=None)
    assert bridge.measure.latest is None  # no CAN reading yet: nothing to report
    kappa, v = -0.08, 1.5
    theta = math.atan(kappa * SHUTTLE_WHEELBASE)
    bridge.step(
        0.1, wheel_speed_rad_s=v / (math.cos(theta) * 0.28), speed_mps=v, steering_wheel_deg=steering_wheel_deg(kappa)
    )
    measured = bridge.measure.latest
    assert measured.kappa == pytest.approx(kappa, rel=1e-9) and measured.v == pytest.approx(v, rel=1e-9)
    assert measured.steering_wheel_deg == pytest.approx(steering_wheel_deg(kappa))
    assert bridge.car.latest.speed_mps == v and bridge.car.latest.steering_wheel_deg == measured.steering_wheel_deg


@pytest.mark.parametrize(
    "action",
    [PanelInput.THROTTLE_PEDAL, PanelInput.BRAKE_PEDAL, PanelInput.STEERING_WHEEL, PanelInput.BUTTON],
    ids=lambda action: action.value,
)
def test_a_driver_action_or_the_button_takes_an_automatic_vehicle_back_to_manual(bridge, action):
    t = bridge.arm(0.0)
    bridge.press(action)
    bridge.setpoint(2.0, 0.05)  # navigation keeps talking: it no longer drives
    car, actuators = bridge.step(t)
    assert car.mode == DriveMode.MANUAL and not car.engaged
    assert not actuators.engaged and actuators.steer_effort == 0.0 and actuators.drive_effort == 0.0
    assert bridge.mode_changes() == [("AUTOMATIC", "MANUAL", action.value)]
    # back to Automatic only by the paper's path again: the service alone is refused
    assert not bridge.set_automatic_mode().accepted


@pytest.mark.parametrize(
    "action",
    [PanelInput.THROTTLE_PEDAL, PanelInput.BRAKE_PEDAL, PanelInput.STEERING_WHEEL],
    ids=lambda action: action.value,
)
def test_a_driver_action_in_ready_gives_manual(bridge, action):
    bridge.press(PanelInput.BUTTON)
    bridge.step(0.0)
    bridge.press(action)
    car, actuators = bridge.step(0.1)
    assert car.mode == DriveMode.MANUAL and not actuators.engaged
    assert bridge.mode_changes() == [("MANUAL", "READY", "BUTTON"), ("READY", "MANUAL", action.value)]


@pytest.mark.parametrize(
    "reading, cause",
    [
        ({"throttle_pedal": 0.2}, "THROTTLE_PEDAL"),
        ({"brake_pedal": 0.2}, "BRAKE_PEDAL"),
        ({"steering_torque": True}, "STEERING_WHEEL"),
    ],
)
def test_pedals_and_steering_torque_on_can_take_over_should_a_panel_event_be_missed(bridge, reading, cause):
    t = bridge.arm(0.0)
    car, actuators = bridge.step(t, **reading)
    assert car.mode == DriveMode.MANUAL and not actuators.engaged
    assert bridge.mode_changes() == [("AUTOMATIC", "MANUAL", cause)]


def test_pedal_noise_below_the_threshold_is_not_a_driver_action(bridge):
    t = bridge.arm(0.0)
    bridge.setpoint(2.0, 0.05)
    car, actuators = bridge.step(t, throttle_pedal=0.04, brake_pedal=0.04)  # pedal_pressed is 0.05
    assert car.mode == DriveMode.AUTOMATIC and actuators.engaged and car.v_command == 2.0
    assert bridge.mode_changes() == []


# ---- the setpoint watchdog -------------------------------------------------------------------------


def test_automatic_without_any_setpoint_stands_still_and_says_so(bridge):
    bridge.press(PanelInput.BUTTON)
    bridge.step(0.0)
    assert bridge.set_automatic_mode().accepted
    car, actuators = bridge.step(0.1)
    assert car.mode == DriveMode.AUTOMATIC and car.watchdog_tripped and car.setpoint_age_s is None
    assert (car.v_command, car.kappa_command) == (0.0, 0.0) and actuators.drive_effort == -STANDSTILL_BRAKE
    watchdog = [e for e in bridge.new_events() if e.kind == "watchdog"]
    assert len(watchdog) == 1 and watchdog[0].level == EventLevel.FAULT


def test_one_second_without_setpoints_stops_and_centres_the_steering_then_it_recovers(bridge):
    last_setpoint = round(bridge.arm(0.0) - PERIOD, 9)
    # a second after the last setpoint the bridge still drives it ...
    for now in ticks(last_setpoint + PERIOD, last_setpoint + 1.0):
        car, _ = bridge.step(now, speed_mps=2.0, wheel_speed_rad_s=7.0)
        assert not car.watchdog_tripped and (car.v_command, car.kappa_command) == (2.0, 0.05)
    assert car.setpoint_age_s == pytest.approx(1.0)
    assert [e for e in bridge.new_events() if e.kind == "watchdog"] == []
    # ... and one period later it stops and centres the steering, still in Automatic
    car, actuators = bridge.step(
        round(last_setpoint + 1.1, 9), speed_mps=2.0, wheel_speed_rad_s=7.0, steering_wheel_deg=steering_wheel_deg(0.05)
    )
    assert car.mode == DriveMode.AUTOMATIC and car.watchdog_tripped
    assert (car.v_command, car.kappa_command) == (0.0, 0.0)
    assert bridge.reference.latest.steering_wheel_deg == 0.0 and bridge.reference.latest.wheel_speed_deg_s == 0.0
    assert actuators.engaged and actuators.drive_effort < 0 and actuators.steer_effort < 0
    tripped = [e for e in bridge.new_events() if e.kind == "watchdog"]
    assert len(tripped) == 1 and tripped[0].level == EventLevel.FAULT and "1.10 s" in tripped[0].message
    # said once, not at every period
    bridge.step(round(last_setpoint + 1.2, 9))
    assert bridge.car.latest.watchdog_tripped and bridge.new_events() == []
    # fresh setpoints: it drives again
    bridge.setpoint(1.0, 0.0)
    car, _ = bridge.step(round(last_setpoint + 1.3, 9))
    assert not car.watchdog_tripped and (car.v_command, car.kappa_command) == (1.0, 0.0)
    recovered = bridge.new_events()
    assert [(e.kind, e.level) for e in recovered] == [("watchdog", EventLevel.INFO)]


def test_the_movement_managers_emergency_stop_brakes_fully_and_holds_the_wheel(bridge):
    t = bridge.arm(0.0)
    bridge.setpoint(0.0, 0.05, stamp=t, emergency=True)
    car, actuators = bridge.step(t)
    assert actuators.engaged and actuators.drive_effort == -1.0
    assert car.mode == DriveMode.AUTOMATIC and (car.v_command, car.kappa_command) == (0.0, 0.05)
    bridge.setpoint(1.0, 0.0, stamp=round(t + PERIOD, 9))  # re-armed: the gate's commands drive again
    _, actuators = bridge.step(round(t + PERIOD, 9))
    assert actuators.drive_effort > -1.0


def test_a_setpoint_older_than_the_timeout_when_it_arrives_is_not_driven(bridge):
    t = bridge.arm(0.0)
    for now in ticks(t, t + 1.0):  # navigation goes quiet: the watchdog stops the car
        bridge.step(now)
    assert bridge.car.latest.watchdog_tripped
    stamped = round(t - PERIOD, 9)  # then a backlog arrives: produced 1.2 s ago
    bridge.setpoint(2.0, 0.05, stamp=stamped)
    car, _ = bridge.step(round(t + 1.1, 9))
    assert car.watchdog_tripped and (car.v_command, car.kappa_command) == (0.0, 0.0)


# ---- the command gate, the inner loops, the standstill brake -------------------------------------


def test_setpoints_beyond_the_vehicle_are_limited(bridge):
    t = bridge.arm(0.0)
    bridge.setpoint(10.0, -1.0)
    car, _ = bridge.step(t)
    assert car.v_command == SHUTTLE_MAX_SPEED and car.kappa_command == pytest.approx(-SHUTTLE_MAX_KAPPA)
    assert "limited" in car.reason
    assert bridge.reference.latest.steering_wheel_deg == pytest.approx(-math.degrees(40 * 0.31))


@pytest.mark.parametrize("speed_mps, braked", [(0.0, True), (0.29, True), (1.0, False)])
@pytest.mark.parametrize("pitch", [0.0, None])  # on the flat, said by the IMU or not known
def test_the_brake_is_held_for_a_zero_speed_setpoint_only_near_standstill(bridge, speed_mps, braked, pitch):
    t = bridge.arm(0.0)
    bridge.setpoint(0.0, 0.0)
    if pitch is not None:
        bridge.imu(pitch)
    _, actuators = bridge.step(t, speed_mps=speed_mps, wheel_speed_rad_s=speed_mps / 0.28)
    if braked:
        assert actuators.drive_effort <= -STANDSTILL_BRAKE
    else:  # from 1 m/s: no hold; the brake assist closes the whole gap in 0.5 s (a stop has no deadband),
        # without a pitch also against the steepest descent's pull (15 %), within its 3 m/s^2
        pull = 0.0 if pitch is not None else 9.81 * math.sin(math.atan(0.15))
        wanted = min(1.0 / 0.5 + pull, 3.0) * (2450 + 2 * 75) / 10000.0
        assert actuators.drive_effort == pytest.approx(-wanted, abs=1e-3)


@pytest.mark.parametrize(
    "speed_mps, command_mps, assisted, deadband",
    [(3.0, 2.6, False, 0.5), (3.0, 2.0, True, 0.5), (3.5, 0.0, True, 0.0), (0.4, 0.0, True, 0.0)],
)
def test_the_brake_helps_the_speed_loop_only_for_a_gap_beyond_its_deadband(
    bridge, speed_mps, command_mps, assisted, deadband
):
    """A moving command's gap within 0.5 m/s is the PI's alone; a stop (a zero command) has none."""
    t = bridge.arm(0.0)
    bridge.setpoint(command_mps, 0.0)
    bridge.imu(0.0)  # on the flat
    _, actuators = bridge.step(t, speed_mps=speed_mps, wheel_speed_rad_s=speed_mps / 0.28)
    wanted = min((speed_mps - command_mps - deadband) / 0.5, 3.0) * (2450 + 2 * 75) / 10000.0
    if assisted:
        assert actuators.drive_effort <= -wanted + 1e-3
        if speed_mps >= 0.3:  # above the standstill brake's speed: the assist's effort itself
            assert actuators.drive_effort == pytest.approx(-wanted, abs=1e-3)
    else:  # tracking: the PI alone, gently
        assert actuators.drive_effort > -0.1


def test_the_brake_takes_a_descents_pull_from_the_imu(bridge):
    t = bridge.arm(0.0)
    bridge.setpoint(0.0, 0.0)
    bridge.imu(math.atan(0.12))  # REP-103: a descent's pitch is positive
    _, actuators = bridge.step(t, speed_mps=0.5, wheel_speed_rad_s=0.5 / 0.28)
    pull = (2450 + 12 * 75) * 9.81 * math.sin(math.atan(0.12)) / 10000.0  # fully loaded
    assert actuators.drive_effort == pytest.approx(-(0.5 / 0.5 * (2450 + 2 * 75) / 10000.0 + pull), abs=1e-3)


def test_no_brake_when_the_setpoint_asks_to_move_off(bridge):
    t = bridge.arm(0.0)
    bridge.setpoint(1.0, 0.0)
    bridge.imu(0.0)  # on the flat
    _, actuators = bridge.step(t)
    assert actuators.drive_effort > 0


@pytest.mark.parametrize("pitch", [-0.139, None])  # a 14 % climb, said by the IMU or assumed without one
def test_a_start_on_a_climb_stands_on_the_brake_until_the_loop_asks_enough_to_hold_it(bridge, pitch):
    # the shuttle fully loaded (2,450 + 12 x 75 kg) on 14 %: m g sin = 4,560 N; its motor at
    # standstill pushes 1,930 N/(m/s) x 11.1 m/s x effort, so an effort of 0.213 holds it
    # (15 %, assumed without a pitch: 0.225)
    bridge.press(PanelInput.BUTTON)
    bridge.step(0.0)
    assert bridge.set_automatic_mode().accepted
    hold = 3350 * 9.81 * math.sin(-pitch if pitch is not None else math.atan(0.15)) / (1930 * 11.1)
    efforts = []
    for now in ticks(PERIOD, 3.0):
        bridge.setpoint(min(0.8 * now, 2.0), 0.0, stamp=now)  # the movement manager's ramp from standstill
        if pitch is not None:
            bridge.imu(pitch)
        _, actuators = bridge.step(now)
        efforts.append(actuators.drive_effort)
    released = next(k for k, e in enumerate(efforts) if e > 0)
    assert released > 0 and all(e == -STANDSTILL_BRAKE for e in efforts[:released])
    assert efforts[released] >= hold and efforts[released - 1] > -1.0  # let go once the loop's effort holds
    assert all(e > 0 for e in efforts[released:])  # once let go, never braking again on the way up
    assert bridge.node.board.hold_effort(pitch) == pytest.approx(hold, rel=1e-6)


def test_re_engaging_starts_the_inner_loops_afresh(bridge):
    t = bridge.arm(0.0)  # a second of steering towards 319 deg winds the integral up
    bridge.press(PanelInput.BUTTON)
    bridge.step(t)  # Manual
    bridge.press(PanelInput.BUTTON)
    _, actuators = bridge.step(round(t + PERIOD, 9))
    # Ready, everything centred and still: only a leftover integral could turn the wheel
    assert actuators.engaged and actuators.steer_effort == 0.0 and actuators.drive_effort == -STANDSTILL_BRAKE


def test_corrupt_setpoints_are_rejected_and_the_bridge_keeps_running(bridge):
    t = bridge.arm(0.0)
    key = bridge.bus.key("movement/command")
    encoding = "application/json;MovementCommand"
    for payload in (
        b"garbage",
        b'{"t": 0, "v": "fast", "kappa": 0, "source": "x"}',
        b'{"t": 0, "v": 1e999, "kappa": 0, "source": "x"}',
    ):
        bridge.network.put(key, encoding, payload)
    car, actuators = bridge.step(t)
    assert bridge.node.bus.rejects.by_reason["malformed"] == 3
    assert car.mode == DriveMode.AUTOMATIC and (car.v_command, car.kappa_command) == (2.0, 0.05)
    # none of them fed the watchdog: past the timeout after the last good setpoint it stops
    car, _ = bridge.step(round(t + 1.0, 9))
    assert car.watchdog_tripped


def test_a_restarted_bridge_process_finds_the_boards_mode_and_a_first_start_is_manual(
    run_config, tmp_path, monkeypatch
):
    from ares.core.recording import INCARNATION_ENV

    monkeypatch.setenv(config.RUN_CONFIG_ENV, str(tmp_path / "config.json"))
    first = BridgeOnTheBus(run_config)
    t = first.arm(0.0)
    assert (tmp_path / "dbw_bridge.json").exists()
    monkeypatch.setenv(INCARNATION_ENV, "1")  # killed, and started again by the supervisor
    again = BridgeOnTheBus(run_config)
    again.clock.set(t)
    car, actuators = again.step(t)
    assert car.mode == DriveMode.AUTOMATIC and car.watchdog_tripped and actuators.drive_effort < 0  # stopped
    again.setpoint(1.5, 0.0)
    car, _ = again.step(round(t + PERIOD, 9))
    assert not car.watchdog_tripped and car.v_command == 1.5  # commands again: it drives on
    monkeypatch.setenv(INCARNATION_ENV, "0")  # a new run's first start: Manual, whatever was kept
    fresh = BridgeOnTheBus(run_config)
    car, _ = fresh.step(0.0)
    assert car.mode == DriveMode.MANUAL
