"""The soak's fault plan (ares.tools.soak.plan), the measurements it is judged by
(ares.tools.soak.measure) and the obstacles that appear ahead of the shuttle (simulator.obstacles):
pure functions; and the simulator's run-time sensor faults, on the whole stack in one process."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ares.core.messages import ProcessState
from ares.core.route import Route
from ares.tools.soak.measure import FaultOutcome, SoakTracker, summarise
from ares.tools.soak.plan import KINDS, MIN_SLOT_S, PlannedFault, fault_plan, kinds_for
from ares.tools.soak.runner import obstacle_scenario
from simulator.obstacles import ObstacleField
from simulator.scenario import Scenario, ScenarioObstacle

PROCESSES = ["mpc", "movement_manager", "blackbox", "gnss"]
LIDARS = ["front_left", "front_right", "roof"]

plans = st.fixed_dictionaries(
    {
        "seed": st.integers(0, 2**32 - 1),
        "count": st.integers(1, 400),
        "lidars": st.booleans(),
    }
).flatmap(
    lambda d: st.fixed_dictionaries(
        {
            **{k: st.just(v) for k, v in d.items()},
            # at least MIN_SLOT_S per fault, at most a day
            "hours": st.floats(d["count"] * MIN_SLOT_S * 1.001 / 3600.0, 24.0, allow_nan=False),
        }
    )
)


def make(p: dict) -> list[PlannedFault]:
    return fault_plan(p["seed"], p["hours"], p["count"], kinds_for(p["lidars"]), PROCESSES, LIDARS)


@settings(max_examples=60, deadline=None)
@given(plans)
def test_a_plan_is_the_seeds_alone_and_every_fault_has_its_slot(p):
    plan = make(p)
    assert plan == make(p), "the same arguments, the same plan"
    assert len(plan) == p["count"] and [f.index for f in plan] == list(range(p["count"]))
    slot = p["hours"] * 3600.0 / p["count"]
    for f, later in zip(plan, plan[1:]):
        # each ends while a quarter of its slot is still left to handle it, recover and move on
        assert later.at_s - f.ends_s >= slot / 4 - 0.02
    for f in plan:
        kind = KINDS[f.kind]
        assert 0.0 <= f.at_s <= p["hours"] * 3600.0
        assert 0.0 <= f.duration_s <= max(kind.duration_s[1], 0.0) + 0.01
        assert (f.target in PROCESSES) if kind.target == "process" else True
        assert (f.target in LIDARS) if kind.target == "lidar" else True
        assert (f.requests >= 20) == (f.kind == "bad_api_burst")
    assert p["lidars"] or not any(KINDS[f.kind].needs_lidars for f in plan)


@settings(max_examples=40, deadline=None)
@given(plans)
def test_every_kind_comes_about_as_often_as_the_others(p):
    plan = make(p)
    kinds = kinds_for(p["lidars"])
    counts = [sum(f.kind == k for f in plan) for k in kinds]
    assert max(counts) - min(counts) <= 1  # each round of len(kinds) faults is every kind once
    if p["count"] >= len(kinds):
        assert min(counts) >= 1


def test_a_plan_that_does_not_fit_is_refused():
    with pytest.raises(ValueError, match="at least"):
        fault_plan(1, 0.01, 1000, kinds_for(False), PROCESSES)
    with pytest.raises(ValueError, match="unknown"):
        fault_plan(1, 1.0, 10, ["meteor_strike"], PROCESSES)
    with pytest.raises(ValueError, match="LiDARs"):
        fault_plan(1, 1.0, 10, ["lidar_covered"], PROCESSES, [])
    assert fault_plan(1, 1.0, 10, kinds_for(False), PROCESSES) != fault_plan(2, 1.0, 10, kinds_for(False), PROCESSES)


def test_the_long_soak_of_the_issue_is_a_valid_plan_of_every_kind():
    plan = fault_plan(1, 10.0, 1000, kinds_for(True), PROCESSES, LIDARS)
    assert len(plan) == 1000 and {f.kind for f in plan} == set(KINDS)


def test_obstacles_appear_ahead_of_the_shuttle_at_their_time_and_leave():
    x = np.arange(0.0, 201.0, 2.0)
    route = Route("straight", x, np.zeros_like(x), np.zeros_like(x), False, np.full(len(x), 6.0))
    plan = [
        PlannedFault(0, 10.0, "parked_object_in_path", 5.0, ahead_m=20.0),
        PlannedFault(1, 30.0, "pedestrian_in_path", 8.0, ahead_m=25.0),
    ]
    scenario = Scenario.model_validate(obstacle_scenario(plan, lead_s=100.0, seed=1))
    field = ObstacleField(scenario, route, lambda s: 0.0)
    assert field.boxes(0.0) == [] and field.update(109.9, 40.0) == []
    assert field.update(110.0, 40.0) == ["parked_object_in_path_0"]
    (cart,) = field.boxes(110.0)
    assert cart.x == pytest.approx(60.0) and cart.y == pytest.approx(0.0)  # 20 m ahead, on the path
    field.update(115.0, 40.0)
    assert field.boxes(115.0) == []  # driven away after its 5 s
    field.update(130.0, 50.0)
    (walker,) = field.boxes(130.0)
    assert walker.x == pytest.approx(75.0) and walker.y == pytest.approx(-2.0)  # at the road's edge, 25 m ahead
    field.update(134.0, 50.0)
    assert abs(field.boxes(134.0)[0].y) < 0.1  # standing in the middle of the path
    # a LiDAR simulator restarted after they came and went does not bring them back
    again = ObstacleField(scenario, route, lambda s: 0.0)
    again.update(200.0, 80.0)
    assert again.boxes(200.0) == []


def test_obstacles_that_appear_need_a_time():
    with pytest.raises(ValueError, match="start_t_s"):
        ScenarioObstacle.model_validate({"name": "x", "kind": "box", "path": [{"s": 0.0}], "appear_ahead_m": 10.0})


def outcome(index: int, at: float, kind: str = "kill_process", duration: float = 0.0) -> FaultOutcome:
    process = "mpc" if kind == "kill_process" else None
    return FaultOutcome(PlannedFault(index, at, kind, duration, target=process), at, True, True, "done", process)


def test_the_time_to_the_safe_state_and_to_recover_are_taken_from_the_messages():
    tracker = SoakTracker(t_start=0.0)
    tracker.add_processes([("mpc", ProcessState.RUNNING, 0)])
    tracker.add_awareness(0)
    tracker.add_gate(0.0, latched=False, stopping=False, limit_mps=3.0)
    for t in (0.0, 0.1, 0.2):
        tracker.add_truth(t, 3.0, False)
    first = outcome(0, 0.25)
    tracker.injected(first)
    assert not first.overlapped
    tracker.add_processes([("mpc", ProcessState.RESTARTING, 1)])
    tracker.add_awareness(2)
    tracker.add_truth(0.3, 3.0, False)
    tracker.add_gate(0.55, latched=False, stopping=True, limit_mps=None)
    for i in range(1, 31):
        tracker.add_truth(0.5 + i * 0.1, max(3.0 - i * 0.15, 0.0), False)
    assert first.safe_at == pytest.approx(0.55) and first.standstill_at is not None
    second = outcome(1, 4.0, "imu_frozen", 0.5)
    tracker.injected(second)  # while the first is not yet over: overlapped, already in its safe state
    assert second.overlapped and second.safe_at == 4.0
    tracker.add_awareness(0)
    tracker.add_gate(4.5, latched=False, stopping=False, limit_mps=3.0)
    tracker.add_truth(4.6, 0.2, False)
    assert first.recovered_at is None  # not moving yet
    tracker.add_truth(5.0, 0.6, False)
    assert first.recovered_at is None and second.recovered_at is None, "the killed process is not back yet"
    tracker.add_processes([("mpc", ProcessState.RUNNING, 1)])
    tracker.add_truth(5.1, 0.7, False)
    assert first.recovered_at == 5.1 and second.recovered_at == 5.1 and not tracker.open
    figures = summarise([first.as_dict(), second.as_dict()])
    assert figures["all"]["injected"] == 2 and figures["all"]["overlapped"] == 1
    assert figures["all"]["time_to_safe_state_max_s"] == pytest.approx(0.3)  # the overlapped one left out
    assert figures["per_kind"]["kill_process"]["time_to_recover_max_s"] == pytest.approx(4.85)
    # moving or standing at a POI is available time; standing for a fault is the last fault's loss
    assert 0.0 < tracker.availability() < 1.0
    assert first.lost_s + second.lost_s == pytest.approx(tracker.total_s - tracker.available_s)


def test_a_frozen_imu_injected_at_run_time_stops_the_shuttle_until_it_is_back(tmp_path):
    """`sim/sensor_fault` on the whole stack in one process (the in-memory bus, a manual clock): the
    IMU frozen for 3 s from now is awareness level 2, a controlled stop by the movement gate, and
    then nominal again; a GNSS outage silences the receiver for its duration."""
    from ares.app.stack import prepare
    from ares.core.messages import SensorFault
    from tests.helpers.in_process_stack import InProcessStack
    from tests.helpers.stack import NO_LIDARS, REPO

    cfg = prepare(
        (str(NO_LIDARS), str(REPO / "tests" / "in_process.yaml")),
        {"blackbox_store": {"uri": str(tmp_path / "blackbox.sqlite")}},
        1.0,
    )
    with InProcessStack(cfg, run_dir=tmp_path / "run", exclude=("blackbox", "api")) as stack:
        awareness, gate = stack.bus.subscribe("awareness/state"), stack.bus.subscribe("movement/status")
        fixes = stack.bus.subscribe("gnss/fix", queue=256)
        stack.engage()
        stack.advance(stack.clock.now() + 2.0)
        assert awareness.latest.level == 0 and not gate.latest.stopping
        reply = stack.bus.call("sim/sensor_fault", SensorFault(t=stack.clock.now(), kind="freeze_imu", duration_s=3.0))
        assert reply.ok, reply.detail
        stack.advance(stack.clock.now() + 1.5)
        assert awareness.latest.level == 2 and any("imu" in c for c in awareness.latest.causes)
        assert gate.latest.stopping
        stack.advance(stack.clock.now() + 3.0)
        assert awareness.latest.level == 0 and not gate.latest.stopping
        stack.bus.call("sim/sensor_fault", SensorFault(t=stack.clock.now(), kind="gnss_outage", duration_s=2.0))
        fixes.drain()
        stack.advance(stack.clock.now() + 1.5)
        assert fixes.drain() == [], "no fix while the receiver is out"
        stack.advance(stack.clock.now() + 2.0)
        assert fixes.drain(), "fixes again once the outage is over"
