"""The safety figures of a headless run (ares/app/evaluation/safety_eval.py) and the scenario's outside actions
(ares/app/scenario_driver.py): collisions and clearance from the footprints, each invariant violation
caught, the times of a fault's response, and faults and operator actions fired at their times."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ares.app.evaluation.safety_eval import SafetyTracker
from ares.app.scenario_driver import ScenarioDriver
from ares.core.clock import ManualClock
from ares.core.geometry import convex_gap, rectangle_corners
from ares.core.membus import MemoryNetwork
from ares.core.messages import (
    AwarenessState,
    BodyState,
    CarState,
    DriveMode,
    Event,
    MissionReply,
    MovementStatus,
    ObstacleBox,
    RearmReply,
    WorldTruth,
)
from simulator.scenario import Scenario

SHUTTLE = dict(length_m=3.93, width_m=1.99, front_bumper_m=3.365)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_far_obstacles_left_out_change_neither_the_clearance_nor_the_collisions(seed):
    """The tracker skips the exact gap of an obstacle too far to matter: the same figures as the gap
    to every obstacle at every step."""
    rng = np.random.default_rng(seed)

    def obstacle(i: int) -> ObstacleBox:
        x, y, yaw = rng.uniform(-25, 25), rng.uniform(-25, 25), rng.uniform(-3, 3)
        length, width = rng.uniform(0.3, 5), rng.uniform(0.3, 3)
        return ObstacleBox(name=f"o{i}", kind="parked", x=x, y=y, yaw=yaw, length_m=length, width_m=width, height_m=1.0)

    obstacles = [obstacle(i) for i in range(8)]
    tracker = SafetyTracker(**SHUTTLE)
    tracker.add_world(WorldTruth(t=0.0, obstacles=obstacles))
    smallest, hit = math.inf, set()
    front, length, width = SHUTTLE["front_bumper_m"], SHUTTLE["length_m"], SHUTTLE["width_m"]
    for k in range(30):
        x, y, yaw = rng.uniform(-20, 20), rng.uniform(-20, 20), rng.uniform(-3, 3)
        tracker.add_truth(float(k), x, y, yaw, 1.0)
        me = rectangle_corners(x, y, yaw, front, length - front, width / 2)
        for ob in obstacles:
            gap = convex_gap(
                me, rectangle_corners(ob.x, ob.y, ob.yaw, ob.length_m / 2, ob.length_m / 2, ob.width_m / 2)
            )
            smallest = min(smallest, gap)
            if gap <= 0.0:
                hit.add(ob.name)
    out = tracker.summary()
    assert out["min_clearance_m"] == round(smallest, 3)
    assert out["collisions"] == len(hit)


def status(t: float, v: float, limit: float | None, latched: bool = False, stopping: bool = False) -> MovementStatus:
    return MovementStatus(
        t=t, level=0, latched=latched, stopping=stopping, limit_mps=limit, limited_by="speed", v=v, kappa=0.0, reason=""
    )


def test_the_gap_between_rectangles():
    a = rectangle_corners(0.0, 0.0, 0.0, 2.0, 1.0, 0.5)
    assert convex_gap(a, rectangle_corners(4.0, 0.0, 0.0, 0.5, 0.5, 0.5)) == pytest.approx(1.5)
    assert convex_gap(a, rectangle_corners(2.2, 0.0, 0.7, 0.5, 0.5, 0.5)) == 0.0  # overlapping, turned
    assert convex_gap(a, rectangle_corners(3.0, 3.0, 0.0, 0.5, 0.5, 0.5)) == pytest.approx(math.hypot(0.5, 2.0))


def test_a_collision_counts_once_per_obstacle_and_the_clearance_is_the_smallest_gap():
    tracker = SafetyTracker(**SHUTTLE)
    walker = ObstacleBox(name="walker", kind="pedestrian", x=10.0, y=0.0, length_m=0.5, width_m=0.5, height_m=1.75)
    tracker.add_world(WorldTruth(t=0.0, obstacles=[walker]))
    for k, x in enumerate([0.0, 2.0, 4.0, 6.0, 6.6, 6.7]):
        tracker.add_truth(float(k), x, 0.0, 0.0, 1.0)
    out = tracker.summary()
    assert out["collisions"] == 1 and out["min_clearance_m"] == 0.0
    assert out["closest_approach"] == {"t": 4.0, "obstacle": "walker", "kind": "pedestrian", "v_mps": 1.0}
    assert out["invariant_violations"] == 1 and "collision with walker" in out["invariant_examples"][0]
    near = SafetyTracker(**SHUTTLE)
    near.add_world(WorldTruth(t=0.0, obstacles=[walker]))
    near.add_truth(0.0, 5.0, 0.0, 0.0, 0.0)  # bumper at 8.365, walker's back at 9.75
    assert near.summary()["min_clearance_m"] == pytest.approx(1.385) and near.summary()["collisions"] == 0
    assert near.summary()["closest_approach"]["t"] == 0.0 and near.summary()["closest_approach"]["v_mps"] == 0.0


@pytest.mark.parametrize(
    "doors, ramp, v, violated",
    [
        ("closed", "stowed", 2.0, False),
        ("open", "stowed", 0.0, False),
        ("open", "stowed", 0.3, True),
        ("closing", "stowed", 0.1, True),
        ("closed", "deploying", 0.2, True),
    ],
)
def test_moving_with_a_door_not_closed_or_the_ramp_out_is_a_violation(doors, ramp, v, violated):
    tracker = SafetyTracker(**SHUTTLE)
    tracker.add_body(BodyState(t=0.0, doors=doors, ramp=ramp, entrance_clear=True))
    tracker.add_truth(0.1, 0.0, 0.0, 0.0, v)
    assert (tracker.summary()["invariant_violations"] == 1) == violated


def test_a_command_above_the_limit_or_under_a_latch_is_a_violation():
    tracker = SafetyTracker(**SHUTTLE)
    tracker.add_status(status(1.0, 2.0, 2.0))
    tracker.add_status(status(1.1, 2.0, None))
    assert tracker.violations == 0
    tracker.add_status(status(1.2, 2.1, 2.0))
    tracker.add_status(status(1.3, 0.5, 0.0, latched=True))
    assert tracker.violations == 2 and "above the active limit" in tracker.examples[0]


def test_a_faults_response_is_timed_from_its_start():
    tracker = SafetyTracker(**SHUTTLE)
    tracker.add_status(status(5.0, 3.0, 3.0, stopping=True))  # a stop before the fault, over before it,
    tracker.add_status(status(6.0, 3.0, 3.0))  # is not its response
    tracker.add_fault(10.0, "kill_process", "mpc")
    tracker.add_truth(10.2, 0.0, 0.0, 0.0, 3.0)
    tracker.add_status(status(10.6, 2.9, 2.9, stopping=True))
    tracker.add_truth(14.0, 0.0, 0.0, 0.0, 0.0)
    tracker.add_status(status(17.0, 0.0, 3.0))  # the cause cleared: on again
    tracker.add_truth(18.0, 0.0, 0.0, 0.0, 0.2)
    tracker.add_truth(19.5, 0.0, 0.0, 0.0, 0.6)
    brief = SafetyTracker(**SHUTTLE)  # a cause that clears before a standstill
    brief.add_fault(1.0, "kill_process", "gnss")
    brief.add_status(status(1.2, 3.0, 3.0, stopping=True))
    brief.add_truth(1.25, 0.0, 0.0, 0.0, 2.9)
    brief.add_status(status(1.4, 2.8, 2.8))
    brief.add_truth(1.45, 0.0, 0.0, 0.0, 2.8)
    killed = SafetyTracker(**SHUTTLE)
    killed.add_fault(1.0, "kill_process", "dbw_bridge")
    killed.add_truth(1.55, 0.0, 0.0, 0.0, 3.0, failsafe=True)  # the board's own brake
    killed.add_car(
        CarState(
            t=2.0,
            mode=DriveMode.AUTOMATIC,
            engaged=True,
            watchdog_tripped=True,
            setpoint_age_s=None,
            v_command=0.0,
            kappa_command=0.0,
            speed_mps=2.0,
            steering_wheel_deg=0.0,
        )
    )
    assert tracker.summary()["faults"] == [
        {
            "kind": "kill_process",
            "target": "mpc",
            "at_s": 10.0,
            "time_to_safe_state_s": 0.6,
            "time_to_standstill_s": 4.0,
            "stop_ended_after_s": 7.0,
            "resumed_after_s": 9.5,
        }
    ]
    assert brief.summary()["faults"][0] == {
        "kind": "kill_process",
        "target": "gnss",
        "at_s": 1.0,
        "time_to_safe_state_s": 0.2,
        "time_to_standstill_s": None,
        "stop_ended_after_s": 0.4,
        "resumed_after_s": 0.45,
    }
    assert killed.summary()["faults"][0]["time_to_safe_state_s"] == 0.55


def test_levels_and_poi_actions_are_kept_in_order():
    tracker = SafetyTracker(**SHUTTLE)
    for t, level, causes in [
        (0.0, 0, []),
        (0.5, 0, []),
        (1.0, 2, ["imu: frozen"]),
        (1.5, 2, ["imu: frozen"]),
        (2.0, 0, []),
    ]:
        tracker.add_awareness(AwarenessState(t=t, level=level, causes=causes))
    for action in ("STOP", "OPENING_DOORS"):
        tracker.add_event(
            Event(
                t=3.0,
                source="mission_manager",
                kind="poi_action",
                message="",
                data={"poi": "Library", "action": action},
            )
        )
    tracker.add_event(Event(t=3.0, source="x", kind="awareness", message=""))
    out = tracker.summary()
    assert out["level_history"] == [[0.0, 0, ""], [1.0, 2, "imu: frozen"], [2.0, 0, ""]]
    assert out["poi_actions"] == [["Library", "STOP"], ["Library", "OPENING_DOORS"]]


def test_the_scenario_fires_faults_and_operator_actions_at_their_times():
    clock, network = ManualClock(), MemoryNetwork()
    vehicle = network.bus("vehicle", clock)
    calls = []
    vehicle.serve(
        "movement/rearm",
        lambda r: calls.append(("rearm", r.operator)) or RearmReply(t=0.0, accepted=True, reason="re-armed"),
    )
    vehicle.serve(
        "mission/pause",
        lambda r: (
            calls.append(("pause", r.operator)) or MissionReply(t=0.0, accepted=False, reason="nothing to pause (IDLE)")
        ),
    )
    scenario = Scenario.model_validate(
        {
            "name": "s",
            "faults": [
                {"kind": "kill_process", "process": "mpc", "at_t_s": 5},
                {"kind": "freeze_imu", "at_t_s": 2, "duration_s": 1},
            ],
            "operator": [{"at_t_s": 7, "action": "pause"}, {"at_t_s": 6, "action": "rearm"}],
        }
    )
    injected = []
    tracker = SafetyTracker(**SHUTTLE)
    driver = ScenarioDriver(
        scenario, network.bus("run", clock), lambda p, k: injected.append((p, k)) or f"{k} {p}", tracker, b"k" * 32
    )
    for t in (1.0, 2.0, 5.5, 6.5):
        driver.step(t)
        vehicle.poll_services()
    assert injected == [("mpc", "kill")] and calls == [("rearm", "scenario")]
    driver.step(9.0)
    assert calls[-1] == ("pause", "scenario")
    assert [a[1:3] for a in driver.summary()["scenario_actions"]] == [
        ["freeze_imu imu", True],
        ["kill_process mpc", True],
        ["rearm", True],
        ["pause", False],
    ]
    assert [(f.kind, f.target, f.at_s) for f in tracker.faults] == [
        ("freeze_imu", "imu", 2.0),
        ("kill_process", "mpc", 5.0),
    ]
