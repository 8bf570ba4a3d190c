"""The Stanley controller (control/stanley.py): the law against its equation, its signs and
bounds (hypothesis), its convergence on a kinematic bicycle along straights and curves, the node on
the in-memory bus, and that it runs only when chosen (ares/app/processes.py).

Beside the MPC on the default tour, in the whole stack: `ares compare --controllers mpc,stanley`
(docs/control.md); a short drive of each on the in-process stack is the last test here."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ares.app import run_config as run_config_module
from ares.app.processes import for_config
from ares.core import config
from ares.core.clock import ManualClock
from ares.core.membus import MemoryNetwork
from ares.core.route import Route
from control.stanley import Stanley, StanleyParams, nearest_on_path
from control.stanley_node import StanleyNode
from managers.path import PathIndex, PathManagerParams
from managers.path_node import PathManager
from managers.speed import SpeedProfileParams, speed_limits
from tests.test_pure_pursuit import pose_at

VEHICLE = config.load_vehicle("ares_shuttle")
LAW = StanleyParams()
PATH = PathManagerParams()
STRAIGHT_X = np.arange(0.0, 30.0, 0.5)


def straight(y=0.0):
    return STRAIGHT_X + 0.0, np.full_like(STRAIGHT_X, y), np.full_like(STRAIGHT_X, 3.0)


def test_on_the_path_and_along_it_it_steers_straight():
    x, y, v = straight()
    cmd = Stanley(LAW, VEHICLE).command(0.0, 0.0, 0.0, 3.0, x, y, v)
    assert cmd.kappa == pytest.approx(0.0, abs=1e-12) and cmd.v == 3.0 and not cmd.finished


@pytest.mark.parametrize("lateral", [-1.0, -0.2, 0.2, 1.0])
def test_the_law_is_its_equation(lateral):
    """δ = ψ_e + atan(k e / (k_soft + v)), κ = tan δ / L, for a vehicle `lateral` m right of a
    straight path (+: the path on its left) heading 0.1 rad to the left of it."""
    law = Stanley(LAW, VEHICLE)
    x, y, speed = straight(lateral)
    yaw, v = 0.1, 2.5
    cmd = law.command(0.0, 0.0, yaw, v, x, y, speed)
    offset = lateral - VEHICLE.wheelbase_m * math.sin(yaw)  # the front axle sits that much further left
    delta = -yaw + math.atan(LAW.gain_per_s * offset / (LAW.softening_mps + v))
    assert cmd.front_offset_m == pytest.approx(offset, abs=1e-12)
    assert cmd.heading_error_rad == pytest.approx(-yaw, abs=1e-12)
    assert cmd.kappa == pytest.approx(
        max(-VEHICLE.max_curvature, min(VEHICLE.max_curvature, math.tan(delta) / VEHICLE.wheelbase_m))
    )


@settings(max_examples=300, deadline=None)
@given(
    lateral=st.floats(-5.0, 5.0),
    yaw=st.floats(-1.2, 1.2),
    v=st.floats(0.0, 6.0),
)
def test_the_curvature_is_within_the_vehicle_and_turns_towards_the_path(lateral, yaw, v):
    x, y, speed = straight(lateral)
    cmd = Stanley(LAW, VEHICLE).command(0.0, 0.0, yaw, v, x, y, speed)
    assert abs(cmd.kappa) <= VEHICLE.max_curvature + 1e-12
    # pointing along the path, the wheels turn towards it; on it, they take the heading error out
    if yaw == 0.0 and abs(lateral) > 1e-6:
        assert math.copysign(1.0, cmd.kappa) == math.copysign(1.0, lateral)
    if lateral == 0.0 and abs(yaw) > 1e-3:
        assert math.copysign(1.0, cmd.kappa) == -math.copysign(1.0, yaw)


def test_the_nearest_point_and_its_side():
    side, heading = nearest_on_path(10.2, 0.7, [0.0, 10.0, 20.0], [0.0, 0.0, 0.0])
    assert side == pytest.approx(0.7) and heading == pytest.approx(0.0)
    side, heading = nearest_on_path(10.0, -0.5, [0.0, 10.0, 10.0], [0.0, 0.0, 10.0])  # the corner's legs
    assert side == pytest.approx(-0.5) and heading == pytest.approx(0.0)
    assert nearest_on_path(1.0, 1.0, [0.0, 0.0], [0.0, 0.0]) is None  # no segment of any length


def test_an_uncertain_heading_creeps_along_the_paths_curvature_and_an_open_route_finishes():
    law = Stanley(LAW, VEHICLE)
    x, y, v = straight()
    creep = law.command(0.0, 0.5, 0.4, 0.0, x, y, v, heading_sigma=0.2, ahead_curvature=[0.05] * len(x))
    assert creep.v == LAW.creep_speed_mps and creep.kappa == pytest.approx(0.05)
    done = law.command(0.0, 0.0, 0.0, 1.0, x, y, v, distance_to_end_m=0.3)
    assert done.finished and done.v == 0.0 and done.kappa == 0.0


def bicycle_drive(route: Route, start_s: float, offset: float, seconds: float, dt: float = 0.05):
    """The law and the path manager's match in closed loop with a kinematic bicycle (the
    curvature applied at once): the cross-track errors along the drive."""
    index = PathIndex(route, PATH, speed_limits(route, SpeedProfileParams(), VEHICLE))
    law = Stanley(LAW, VEHICLE)
    px, py, _, yaw = route.point_at(start_s)
    x, y, v = px - math.sin(yaw) * offset, py + math.cos(yaw) * offset, 2.0
    hint, errors = None, []
    for _ in range(int(seconds / dt)):
        m = index.match(x, y, yaw, hint)
        hint = m.progress
        ahead = index.ahead(m.index, PATH.ahead_length_m, PATH.ahead_step_m, s=m.s)
        cmd = law.command(x, y, yaw, v, ahead.x, ahead.y, ahead.speed)
        v = cmd.v
        x, y, yaw = x + v * math.cos(yaw) * dt, y + v * math.sin(yaw) * dt, yaw + v * cmd.kappa * dt
        errors.append(m.xte)
    return np.array(errors)


@pytest.mark.parametrize("offset", [-1.5, 1.5])
def test_from_aside_it_joins_the_tour_and_holds_it_round_the_corners(offset):
    tour = Route.from_tour("default")
    errors = bicycle_drive(tour, 300.0, offset, 40.0)
    assert abs(errors[0]) == pytest.approx(1.5, abs=0.05)
    settled = errors[len(errors) // 4 :]  # after the first 10 s: round the corners of 300-400 m
    assert np.abs(settled).max() < 0.15 and np.sqrt(np.mean(settled**2)) < 0.05
    assert np.sign(errors[: len(errors) // 4]).min() * np.sign(offset) >= 0  # no overshoot to the other side


# ---- the node, and when it runs -----------------------------------------------------------------


def test_the_node_sends_a_candidate_while_its_inputs_are_fresh_and_nothing_after(run_config):
    tour = Route.from_tour("default")
    clock, network = ManualClock(), MemoryNetwork()
    path = PathManager(run_config, clock=clock, bus=network.bus("path_manager", clock))
    node = StanleyNode(run_config, clock=clock, bus=network.bus("stanley", clock))
    path.setup()
    node.setup()
    feeder = network.bus("test", clock)
    got = feeder.subscribe("control/candidate/stanley", queue=100)
    x, y, _, yaw = tour.point_at(400.0)
    for k in range(10):  # half a metre left of the path
        t = round(k * 0.05, 9)
        clock.set(t)
        feeder.publish("localization/pose", pose_at(x - math.sin(yaw) * 0.5, y + math.cos(yaw) * 0.5, yaw, t))
        path.step_once(t)
        node.step_once(t)
    candidates = [c for _, c in got.drain()]
    assert len(candidates) == 10 and all(c.controller == "stanley" and c.kappa < 0 and c.v > 0 for c in candidates)
    assert "front axle offset -0.50 m" in candidates[-1].note
    for k in range(1, 30):  # the poses stop: stale within input_timeout_s, then silence
        t = round(0.45 + k * 0.05, 9)
        clock.set(t)
        path.step_once(t)
        node.step_once(t)
    got.drain()
    t = round(0.45 + LAW.input_timeout_s + 0.5, 9)
    clock.set(t)
    node.step_once(t)
    assert got.drain() == []


@pytest.mark.parametrize(
    "control, runs",
    [
        ({}, False),
        ({"pinned": "stanley"}, True),
        ({"odometry_controller": "stanley"}, True),
        ({"pinned": "mpc"}, False),
    ],
)
def test_the_stanley_process_runs_only_when_chosen(control, runs):
    cfg = run_config_module.build(overrides={"control_manager": control} if control else None)
    assert ("stanley" in {p.name for p in for_config(cfg)}) == runs


def test_in_the_whole_stack_stanley_pinned_drives_the_tour_s_corners(tmp_path):
    """The in-process stack (every node on the in-memory bus, lockstep) with only Stanley driving,
    30 s round the corners after 300 m: the control manager forwards Stanley's candidates and the
    shuttle stays on its path (`ares compare --controllers mpc,stanley` sets it beside the MPC)."""
    from tests.test_in_process_stack import drive

    result = drive(tmp_path, seconds=30, control_manager={"pinned": "stanley"}, sim={"start_s_m": 300.0})
    assert result["ok"] and result["controller_time_share"].get("stanley", 0.0) >= 0.95, result
    assert result["distance_m"] > 50 and result["collisions"] == 0 and result["invariant_violations"] == 0
    assert result["xte_rmse_m"] <= 0.1 and result["xte_max_m"] <= 0.3
    print(f"\nstanley in the stack: xte rmse {result['xte_rmse_m']} m, max {result['xte_max_m']} m")
