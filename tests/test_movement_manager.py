"""The movement and awareness managers as nodes (managers/movement_node.py, managers/awareness_node.py) on
the in-memory bus with a manual clock: what reaches movement/command, the events the black box
keeps (emergency stop, controlled stop, re-arm with the operator's name), and the awareness
level from the sensors' messages and the supervisor's table."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ares.core import config
from ares.core.clock import ManualClock
from ares.core.membus import MemoryNetwork
from ares.core.messages import (
    AwarenessState,
    BodyState,
    CarState,
    DriveMode,
    Imu,
    MissionStatus,
    ObstacleState,
    ProcessState,
    ProcessStatus,
    RearmRequest,
    Setpoint,
    SpeedLimits,
    SupervisorState,
)
from managers.awareness_node import AwarenessManager
from managers.movement_node import MovementManager
from tests.helpers.commands import call_signed
from tests.helpers.stack import make_run_config

PERIOD = 0.02
_CFG = make_run_config(7447)  # hypothesis tests take no function-scoped fixture; no port is opened


class Gate:
    def __init__(self, cfg: dict, lidars: bool = False):
        self.cfg = cfg = config.deep_merge(cfg, {"lidars": lidars})
        self.clock = ManualClock()
        self.network = MemoryNetwork()
        self.node = MovementManager(cfg, clock=self.clock, bus=self.network.bus("movement_manager", self.clock))
        self.node.setup()
        self.bus = self.network.bus("test", self.clock)
        self.commands = self.bus.subscribe("movement/command", queue=1000)
        self.status = self.bus.subscribe("movement/status")
        self.events = self.bus.subscribe("events", queue=1000)
        self.t = 0.0

    def run(
        self,
        seconds: float,
        *,
        command=(2.0, 0.01),
        limit: float | None = 3.0,
        level: int | None = 0,
        causes=(),
        obstacle: float | None = None,
        bridge_emergency: bool = False,
        mission: float | str | None = "drive",
        doors: str | None = "closed",
    ):
        for _ in range(round(seconds / PERIOD)):
            t = self.t = round(self.t + PERIOD, 9)
            self.clock.set(t)
            if command is not None:
                self.bus.publish("control/setpoint", Setpoint(t=t, v=command[0], kappa=command[1], source="mpc"))
            if limit is not None:
                self.bus.publish(
                    "speed/limits",
                    SpeedLimits(
                        t=t,
                        s=5.0,
                        section=0,
                        kind="cruise",
                        limit_mps=limit,
                        next_section=1,
                        next_limit_mps=limit,
                        distance_to_next_m=10.0,
                    ),
                )
            self.bus.publish(
                "dbw/car_state",
                CarState(
                    t=t,
                    mode=DriveMode.AUTOMATIC,
                    engaged=True,
                    watchdog_tripped=False,
                    setpoint_age_s=0.02,
                    v_command=0.0,
                    kappa_command=0.0,
                    speed_mps=0.0,
                    steering_wheel_deg=0.0,
                    emergency=bridge_emergency,
                ),
            )
            if obstacle is not None:
                self.bus.publish(
                    "obstacle/state",
                    ObstacleState(
                        t=t,
                        score=0.5,
                        band="slow",
                        nearest_m=4.0,
                        limit_mps=obstacle,
                        length_m=8.0,
                        cells=4,
                        area_x=[],
                        area_y=[],
                    ),
                )
            if mission is not None:
                self.bus.publish(
                    "mission/status",
                    MissionStatus(
                        t=t,
                        goal_id=1,
                        state="DRIVING",
                        kind="drive" if mission == "drive" else "tour",
                        poi=None,
                        action=None,
                        distance_m=None,
                        eta_s=None,
                        limit_mps=None if mission == "drive" else mission,
                        ready_to_move=doors == "closed",
                    ),
                )
            if doors is not None:
                self.bus.publish("body/state", BodyState(t=t, doors=doors, ramp="stowed", entrance_clear=True))
            if level is not None:
                self.bus.publish("awareness/state", AwarenessState(t=t, level=level, causes=list(causes)))
            self.node.step_once(t)
            self.node.bus.poll_services()
        return self.commands.latest, self.status.latest

    def kinds(self) -> list[tuple[str, str]]:
        return [(e.kind, e.message) for _, e in self.events.drain()]


@pytest.fixture
def gate(run_config) -> Gate:
    return Gate(run_config)


def test_the_command_follows_the_control_manager_under_the_speed_limit(gate):
    command, status = gate.run(3.0)
    assert (command.v, command.kappa, command.emergency, command.source) == (2.0, 0.01, False, "mpc")
    command, status = gate.run(0.1, limit=1.2)
    assert command.v == 1.2 and status.limited_by == "speed" and status.limits == {"speed": 1.2}


def test_with_lidars_the_obstacle_managers_limit_is_required(run_config):
    gate = Gate(run_config, lidars=True)
    command, status = gate.run(3.0, obstacle=0.8)
    assert command.v == 0.8 and status.limited_by == "obstacle"
    command, status = gate.run(1.0)  # the obstacle manager falls silent
    assert status.stopping and "obstacle limit missing" in status.reason


def test_a_missing_input_stops_under_control_and_the_shuttle_goes_on_when_it_returns(gate):
    gate.run(3.0)
    gate.kinds()
    command, status = gate.run(1.5, limit=None)  # missing once older than limit_timeout_s (1 s)
    assert status.stopping and "speed limit missing" in status.reason and command.source == "stop"
    assert command.v == pytest.approx(2.0 - 0.48 * 1.0, abs=0.03)  # slowing at the stop's deceleration
    command, status = gate.run(3.0)
    assert not status.stopping and command.v == 2.0
    assert [k for k, _ in gate.kinds()] == ["controlled_stop", "controlled_stop"]


def test_level_1_latches_until_an_operator_rearms_and_the_event_names_them(gate):
    gate.run(2.0)
    command, status = gate.run(0.1, level=1, causes=["lidar roof: blind"])
    assert command.emergency and command.v == 0.0 and status.latched and status.latch_cause == "lidar roof: blind"
    refused = call_signed(gate.bus, gate.cfg, "movement/rearm", RearmRequest(operator="ana"))
    assert not refused.accepted and "level 1 persists" in refused.reason
    command, _ = gate.run(1.0)  # cleared, still latched
    assert command.emergency
    accepted = call_signed(gate.bus, gate.cfg, "movement/rearm", RearmRequest(operator="ana"))
    assert accepted.accepted
    command, status = gate.run(1.0)
    assert not command.emergency and command.v > 0.0 and not status.latched
    events = [e for _, e in gate.events.drain()]
    stops = [e for e in events if e.kind == "emergency_stop"]
    rearms = [e for e in events if e.kind == "rearm"]
    assert len(stops) == 1 and stops[0].data["cause"] == "lidar roof: blind"
    assert [(e.data["operator"], e.data["accepted"]) for e in rearms] == [("ana", False), ("ana", True)]


def test_an_unsigned_rearm_is_refused_and_the_stop_stays_latched(gate):
    """Any process with the bus's password may call movement/rearm: only a command signed with the
    vehicle's command key (its API's, its CLI's) re-arms, under the signed name."""
    gate.run(2.0)
    gate.run(0.1, level=1, causes=["lidar roof: blind"])
    gate.run(1.0)  # cleared, still latched
    refused = gate.bus.call("movement/rearm", RearmRequest(operator="ana"))
    assert not refused.accepted and "an unsigned command" in refused.reason
    command, status = gate.run(1.0)
    assert command.emergency and status.latched
    accepted = call_signed(gate.bus, gate.cfg, "movement/rearm", RearmRequest(operator="mallory"), "ana")
    assert accepted.accepted
    command, status = gate.run(1.0)
    assert not command.emergency and not status.latched
    events = [e for _, e in gate.events.drain()]
    assert [(e.data["service"], e.data["claimed"]) for e in events if e.kind == "command_refused"] == [
        ("movement/rearm", "ana")
    ]
    assert [(e.data["operator"], e.data["accepted"]) for e in events if e.kind == "rearm"] == [("ana", True)]


def test_a_restarted_movement_manager_keeps_the_emergency_stop_the_bridge_is_in(run_config):
    gate = Gate(run_config)
    command, status = gate.run(1.0, bridge_emergency=True)
    assert command.emergency and status.latched
    assert status.latch_cause == "emergency stop in force when the movement manager started"
    assert call_signed(gate.bus, gate.cfg, "movement/rearm", RearmRequest(operator="ana")).accepted
    command, _ = gate.run(1.0)
    assert not command.emergency


def test_nothing_goes_out_before_the_bridge_is_heard_for_a_second(run_config):
    gate = Gate(run_config)
    gate.node.step_once(0.5)
    assert gate.commands.latest is None


def imu(t: float, k: int) -> Imu:
    return Imu(
        t=t,
        yaw=0.1,
        roll=0.0,
        pitch=0.0,
        gyro_x=0.001 * k,
        gyro_y=0.0,
        gyro_z=0.0,
        accel_x=0.0,
        accel_y=0.0,
        accel_z=9.81,
    )


def test_the_awareness_manager_reports_a_frozen_imu_and_a_dead_process(run_config):
    cfg = config.deep_merge(run_config, {"lidars": False})
    clock = ManualClock()
    network = MemoryNetwork()
    node = AwarenessManager(cfg, clock=clock, bus=network.bus("awareness_manager", clock))
    node.setup()
    bus = network.bus("test", clock)
    states = bus.subscribe("awareness/state")
    events = bus.subscribe("events", queue=100)
    from tests.helpers.gnss import fix

    def run(t0: float, t1: float, frozen: bool = False, mpc=ProcessState.RUNNING) -> AwarenessState:
        k = round(t0 * 50)
        while k < round(t1 * 50):
            t = k / 50
            clock.set(t)
            bus.publish("sensors/imu", imu(t, 0 if frozen else k))
            if k % 10 == 0:
                bus.publish("gnss/fix", fix(t))
                bus.publish(
                    "supervisor/state",
                    SupervisorState(t=t, processes=[ProcessStatus(name="mpc", state=mpc, safety_relevant=True)]),
                )
            if k % 25 == 0:
                node.step_once(t)
            k += 1
        return states.latest

    assert run(0.0, 3.0).level == 0
    state = run(3.0, 4.5, frozen=True)
    assert state.level == 2 and state.causes[0].startswith("imu: frozen") and state.sensors["imu"] != "ok"
    state = run(4.5, 6.0, mpc=ProcessState.RESTARTING)
    assert state.level == 2 and state.causes == ["process mpc: restarting"]
    assert run(6.0, 7.0).level == 0
    changes = [(e.data["level_from"], e.data["level_to"]) for _, e in events.drain() if e.kind == "awareness"]
    # one event per cause: "frozen for 0.5 s", "... for 1.0 s" are the same cause
    assert changes == [(0, 2), (2, 0), (0, 2), (2, 0)]


def test_the_mission_limit_applies_and_a_missing_mission_or_body_stops_the_shuttle(run_config):
    gate = Gate(run_config)
    command, status = gate.run(3.0)
    assert command.v == pytest.approx(2.0) and "mission" not in status.limits  # a drive: no limit
    command, status = gate.run(1.0, mission=1.2)
    assert command.v == pytest.approx(1.2) and status.limited_by == "mission"
    command, status = gate.run(1.0, mission=None)  # the mission manager gone
    assert status.stopping and status.limits["mission"] is None and "mission limit missing" in status.reason
    command, status = gate.run(3.0)
    assert not status.stopping and command.v > 1.5
    command, status = gate.run(1.0, doors=None)
    assert status.stopping and "body limit missing" in status.reason


@pytest.mark.parametrize("doors", ["opening", "open", "closing"])
def test_a_door_not_closed_holds_the_shuttle_whatever_the_mission_says(run_config, doors):
    gate = Gate(run_config)
    gate.run(3.0)
    command, status = gate.run(0.1, doors=doors)  # a door that opens by itself: a limit of 0 at once
    assert command.v == 0.0 and status.limited_by == "body"
    command, status = gate.run(5.0, doors=doors)
    assert command.v == 0.0


@settings(max_examples=60, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.sampled_from(["closed", "opening", "open", "closing", None]),
            st.sampled_from(["stowed", "deploying", "deployed", "stowing"]),
            st.floats(0.0, 4.0),
            st.one_of(st.none(), st.floats(0.0, 4.0)),
        ),
        min_size=1,
        max_size=25,
    )
)
def test_no_command_to_move_while_a_door_is_not_closed_or_the_ramp_is_out(steps):
    """Whatever the control manager and the mission ask: while the doors' latest report says not
    closed or the ramp not stowed, the command is 0; with no report for longer than the body's
    max age (unknown), it never speeds up (a controlled stop)."""
    gate = Gate(_CFG)
    max_age = gate.node.params.body_timeout_s
    last = None  # (doors, ramp, stamp) of the latest report
    before = 0.0
    for doors, ramp, wanted, mission in steps:
        for _ in range(5):
            t = gate.t = round(gate.t + PERIOD, 9)
            gate.clock.set(t)
            gate.bus.publish("control/setpoint", Setpoint(t=t, v=wanted, kappa=0.0, source="mpc"))
            gate.bus.publish(
                "speed/limits",
                SpeedLimits(
                    t=t,
                    s=5.0,
                    section=0,
                    kind="cruise",
                    limit_mps=4.0,
                    next_section=1,
                    next_limit_mps=4.0,
                    distance_to_next_m=10.0,
                ),
            )
            gate.bus.publish(
                "dbw/car_state",
                CarState(
                    t=t,
                    mode=DriveMode.AUTOMATIC,
                    engaged=True,
                    watchdog_tripped=False,
                    setpoint_age_s=0.02,
                    v_command=0.0,
                    kappa_command=0.0,
                    speed_mps=0.0,
                    steering_wheel_deg=0.0,
                ),
            )
            gate.bus.publish(
                "mission/status",
                MissionStatus(
                    t=t,
                    goal_id=1,
                    state="DRIVING",
                    kind="tour",
                    poi=None,
                    action=None,
                    distance_m=None,
                    eta_s=None,
                    limit_mps=mission,
                    ready_to_move=True,
                ),
            )
            if doors is not None:
                gate.bus.publish("body/state", BodyState(t=t, doors=doors, ramp=ramp, entrance_clear=True))
                last = (doors, ramp, t)
            gate.bus.publish("awareness/state", AwarenessState(t=t, level=0))
            gate.node.step_once(t)
            command = gate.commands.latest
            age = None if last is None else t - last[2]
            if age is not None and age <= max_age - PERIOD and (last[0] != "closed" or last[1] != "stowed"):
                assert command.v == 0.0, (last, command)
            elif age is None or age > max_age + PERIOD:
                assert command.v <= before + 1e-9, (last, age, command)
            before = command.v
