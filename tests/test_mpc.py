"""The MPC (control/mpc.py, ARES eqs. 11-13) on its own: in closed loop with a kinematic vehicle
whose steering has the profile's dead time and rate limit, on hand-made paths."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ares.core.config import load_vehicle
from control.mpc import Mpc, MpcParams, VehicleState, _Polyline, predict

VEHICLE = load_vehicle("ares_shuttle")
PLANT_DT = 0.01
# the solver's time budget is a benchmark's business: here a slow, busy machine must not turn a
# late solve into a failed one
UNTIMED = {"max_solve_ms": 10_000.0}


def arc_path(radius: float, straight_m: float = 15.0, turn_deg: float = 90.0, after_m: float = 40.0, ds: float = 0.5):
    """A straight, a left arc of `radius` through `turn_deg` (inf: straight on), a straight; poses
    every ds, as the path manager sends them."""
    if math.isinf(radius):
        s = np.arange(0.0, straight_m + after_m + 60.0, ds)
        return s, np.zeros_like(s)
    a = np.radians(turn_deg)
    arc = np.arange(0.0, radius * a, ds) / radius
    end = np.array([straight_m + radius * math.sin(a), radius - radius * math.cos(a)])
    tail = np.arange(ds, after_m, ds)
    return (
        np.r_[np.arange(0.0, straight_m, ds), straight_m + radius * np.sin(arc), end[0] + tail * math.cos(a)],
        np.r_[np.zeros(int(math.ceil(straight_m / ds))), radius - radius * np.cos(arc), end[1] + tail * math.sin(a)],
    )


def distance_to(path, x: float, y: float) -> float:
    """From (x, y) to the polyline through the path's poses."""
    return abs(offset_from(path, x, y))


def offset_from(path, x: float, y: float) -> float:
    """From the polyline through the path's poses to (x, y): + left of it."""
    px, py = path
    ax, ay, bx, by = px[:-1], py[:-1], px[1:], py[1:]
    dx, dy = bx - ax, by - ay
    t = np.clip(((x - ax) * dx + (y - ay) * dy) / np.maximum(dx * dx + dy * dy, 1e-12), 0.0, 1.0)
    gaps = np.hypot(ax + t * dx - x, ay + t * dy - y)
    i = int(np.argmin(gaps))
    return float(gaps[i]) * (1.0 if dx[i] * (y - ay[i]) - dy[i] * (x - ax[i]) >= 0 else -1.0)


def closed_loop(
    mpc: Mpc,
    path,
    offset_m: float,
    speed: float = 3.0,
    seconds: float = 12.0,
    v0: float | None = None,
    yaw0: float = 0.0,
    signed: bool = False,
):
    """Drive the path from `offset_m` left of its start, headed `yaw0`; the wheels follow each
    command after the steering's dead time at its rate. Returns the distance from the path at each
    plant step (`signed`: + left of it) and the commands."""
    px, py = path
    steering = VEHICLE.actuators.steering
    rate = math.radians(steering.max_rate_deg_s) / VEHICLE.steering_ratio * PLANT_DT
    x, y, yaw, v, delta, accel = 0.0, offset_m, yaw0, speed if v0 is None else v0, 0.0, 0.0
    pending, target, errors, commands = [], 0.0, [], []
    every = round(1.0 / mpc.params.rate_hz / PLANT_DT)
    for k in range(round(seconds / PLANT_DT)):
        if k % every == 0:
            i = int(np.argmin(np.hypot(px - x, py - y)))
            near = slice(max(i - 2, 0), i + 80)
            cmd = mpc.solve(VehicleState(x, y, yaw, v, delta, accel), px[near], py[near], np.full(len(px[near]), speed))
            commands.append(cmd)
            pending.append((k * PLANT_DT + steering.dead_time_s, cmd.delta))
            accel = cmd.accel
        while pending and pending[0][0] <= k * PLANT_DT + 1e-9:
            target = pending.pop(0)[1]
        delta += float(np.clip(target - delta, -rate, rate))
        v = max(0.0, v + accel * PLANT_DT)
        x, y, yaw, _ = predict(x, y, yaw, v, delta, 0.0, PLANT_DT, VEHICLE.wheelbase_m)
        errors.append(offset_from(path, x, y) if signed else distance_to(path, x, y))
    return np.array(errors), commands


def test_an_offset_on_a_straight_is_taken_out():
    errors, commands = closed_loop(Mpc(VEHICLE, MpcParams(**UNTIMED)), arc_path(math.inf), offset_m=0.5)
    assert commands[0].delta < 0  # left of the path: steer right
    assert commands[0].cte == pytest.approx(-0.5, abs=0.05)
    assert errors[-300:].max() < 0.03  # settled within 9 s
    assert all(c.ok for c in commands)


@pytest.mark.parametrize("radius", [12.0, 20.0, 40.0])
def test_arcs_are_followed_closely(radius):
    errors, commands = closed_loop(
        Mpc(VEHICLE, MpcParams(**UNTIMED)), arc_path(radius), offset_m=0.0, speed=min(3.0, math.sqrt(0.5 * radius))
    )
    # measured: RMSE 1.0-2.1 cm, max 1.6-3.9 cm
    assert errors.max() < 0.08 and np.sqrt(np.mean(errors**2)) < 0.04, (errors.max(), np.sqrt(np.mean(errors**2)))
    steady = [c.delta for c in commands[-20:]]
    assert np.mean(steady) == pytest.approx(math.atan(VEHICLE.wheelbase_m / radius), rel=0.15)


def test_a_long_arc_is_held_on_the_line_not_inside_it():
    """Steps along the heading halfway through them: with the paper's form (the heading at the
    step's start) the plan believes the vehicle wider than it goes and holds it inside the arc
    (measured: 2.3 cm inside a 30 m arc at 3 m/s, against 0.3 mm)."""
    errors, _ = closed_loop(
        Mpc(VEHICLE, MpcParams(**UNTIMED)), arc_path(30.0, turn_deg=120.0), 0.0, speed=3.0, seconds=20.0
    )
    assert errors[1200:].max() < 0.005


def test_the_dead_time_compensation_pays():
    """The same bend with the steering's dead time: solved from the state the dead time ahead,
    the MPC holds the arc closer than solved from the state now (measured over the last 3 s:
    largest error 0.048 against 0.062 m)."""
    path = arc_path(15.0)
    with_it, _ = closed_loop(Mpc(VEHICLE, MpcParams(compensate_dead_time=True, **UNTIMED)), path, 0.3)
    without, _ = closed_loop(Mpc(VEHICLE, MpcParams(compensate_dead_time=False, **UNTIMED)), path, 0.3)
    assert with_it[-300:].max() <= 0.85 * without[-300:].max()


def test_inputs_stay_within_eq_12_and_the_steering_rate():
    mpc = Mpc(VEHICLE, MpcParams(**UNTIMED))
    _, commands = closed_loop(mpc, arc_path(12.0, straight_m=3.0), offset_m=2.0, speed=2.5, seconds=6.0, v0=0.0)
    step = math.radians(VEHICLE.actuators.steering.max_rate_deg_s) / VEHICLE.steering_ratio * mpc.params.step_s
    deltas = np.array([c.delta for c in commands])
    assert np.abs(deltas).max() <= VEHICLE.max_wheel_angle_rad + 1e-6
    assert all(-VEHICLE.max_decel_mps2 - 1e-6 <= c.accel <= VEHICLE.max_accel_mps2 + 1e-6 for c in commands)
    assert np.abs(np.diff(deltas)).max() <= step + 1e-6  # commands 0.1 s apart: within one step's reach
    assert commands[0].accel > 0  # from standstill: away


def test_speed_follows_the_limit():
    errors, commands = closed_loop(
        Mpc(VEHICLE, MpcParams(**UNTIMED)), arc_path(math.inf), offset_m=0.0, speed=2.0, seconds=10.0, v0=0.0
    )
    assert commands[-1].v == pytest.approx(2.0, abs=0.1)


def test_a_failed_solve_reuses_the_previous_solution_then_hands_over():
    mpc = Mpc(VEHICLE, MpcParams(max_reused=2, **UNTIMED))
    px, py = arc_path(20.0)
    state = VehicleState(0.0, 0.2, 0.0, 3.0)
    good = mpc.solve(state, px[:120], py[:120], np.full(120, 3.0))
    assert good.ok and not good.handover and len(good.predicted_x) == mpc.params.horizon_steps + 1
    nowhere = mpc.solve(state, px[:2], py[:2], np.full(2, 3.0))  # no path to fit: a failure
    assert not nowhere.ok and not nowhere.handover and nowhere.reused == 1
    assert nowhere.delta == pytest.approx(second_input_of_previous(mpc))
    assert not mpc.solve(state, px[:2], py[:2], np.full(2, 3.0)).handover
    third = mpc.solve(state, px[:2], py[:2], np.full(2, 3.0))
    assert third.handover and third.accel < 0  # stop asking, slow down
    assert mpc.failures == 3
    again = mpc.solve(state, px[:120], py[:120], np.full(120, 3.0))
    assert again.ok and again.reused == 0


def second_input_of_previous(mpc):
    """The previous solution's second step (its first, shifted by one)."""
    _, U, _ = mpc._previous
    return float(U[0, 1])


def test_the_predicted_trajectory_is_in_the_callers_frame():
    mpc = Mpc(VEHICLE, MpcParams(compensate_dead_time=False, **UNTIMED))
    # the same straight path, the vehicle at (100, 50) heading 90°: the prediction runs up y
    s = np.arange(0.0, 40.0, 0.25)
    cmd = mpc.solve(VehicleState(100.0, 50.0, math.pi / 2, 3.0), np.full_like(s, 100.0), 50.0 + s, np.full(len(s), 3.0))
    assert cmd.ok
    assert np.allclose(cmd.predicted_x, 100.0, atol=0.05) and cmd.predicted_y[-1] > 55.0


def test_the_bench_reports_solve_times_and_the_loops_tracking():
    from ares.tools.bench.mpc import run_mpc_bench

    # a solve is never "late" here: how fast the machine is is the bench's figure, not this test's
    result = run_mpc_bench(solves=60, params=MpcParams(max_solve_ms=60_000.0))
    assert result["solves"] == 60 and result["horizon"] == MpcParams().horizon_steps
    assert 0 < result["solve_p50_ms"] <= result["solve_p99_ms"] <= result["solve_max_ms"]
    assert result["failed_solves"] == 0 and result["xte_max_m"] < 0.2  # it drove the tour's start


def test_one_iteration_per_cycle_tracks_as_well_as_a_converged_solve():
    """The real-time iteration: one Gauss-Newton step per cycle from the shifted previous solution
    drives the bend as a solver iterating to convergence every cycle does."""
    path = arc_path(15.0)
    rti, rti_cmds = closed_loop(Mpc(VEHICLE, MpcParams(**UNTIMED)), path, 0.3)
    full, _ = closed_loop(Mpc(VEHICLE, MpcParams(sqp_iterations=20, **UNTIMED)), path, 0.3)
    rmse = lambda e: float(np.sqrt(np.mean(e**2)))  # noqa: E731
    assert rmse(rti) == pytest.approx(rmse(full), rel=0.1) and rti.max() <= full.max() * 1.1 + 0.01
    assert all(c.ok for c in rti_cmds)


@pytest.mark.parametrize(
    "v_command, v_now, v_path, stalls",
    [
        (0.0, 0.0, 2.0, True),  # standing, the plan stays, the path asks to move: stalled
        (0.3, 0.0, 2.0, False),  # the plan starts the shuttle
        (0.0, 1.5, 2.0, False),  # a plan to stop from speed is not a stall
        (0.0, 0.0, 0.2, False),  # the path asks for nothing (its end, a stop)
    ],
)
def test_a_plan_that_keeps_the_shuttle_standing_hands_over_after_a_while(v_command, v_now, v_path, stalls):
    from control.mpc_node import StallGuard

    guard = StallGuard(after_s=2.0)
    answers = [guard.stalled(t / 10, v_command, v_now, v_path) for t in range(31)]
    assert answers[19] is False and answers[-1] is stalls  # never before 2 s
    assert guard.stalled(3.1, 0.5, 0.0, v_path) is False and guard.since is None  # moving again: reset


# ---- the way back (docs/control.md, "The MPC from half a metre aside: the way back") ----------------------
# From a default-tour soak: a controlled stop left the shuttle standing 0.55 m aside, turned 9.5°
# further away. With the path itself as the reference every start first adds to the offset, so the
# plan stood; pure pursuit started it (the stall guard), and the MPC, moving, turned lock to lock.


def right_bend():
    px, py = arc_path(20.0, straight_m=3.0)
    return px, -py


@pytest.mark.parametrize(
    "path, offset_m, yaw0, speed",
    [
        (arc_path(math.inf), 0.55, 0.165, 3.0),  # the soak's stop
        (arc_path(math.inf), 1.0, 0.3, 3.0),
        (right_bend(), 1.5, 0.3, 2.4),  # outside a 20 m bend, turned further out
        (arc_path(12.0, straight_m=3.0), 0.55, 0.0, 2.4),  # inside a 12 m bend
    ],
)
def test_from_aside_and_turned_away_a_standing_shuttle_sets_off_and_rejoins_the_path(path, offset_m, yaw0, speed):
    errors, commands = closed_loop(
        Mpc(VEHICLE, MpcParams(**UNTIMED)), path, offset_m, speed, seconds=20.0, v0=0.0, yaw0=yaw0, signed=True
    )
    setting_off = next(i for i, c in enumerate(commands) if c.v > 0.3)
    assert setting_off <= 10  # within a second
    assert np.abs(errors[-500:]).max() < 0.05  # back on the path: measured within 5.8-11.8 s
    assert -errors.min() < 0.3  # crossing it by little (measured 0.04-0.24 m)
    # beyond a quarter lock, the wheel swings over at most once (in the soak: lock to lock every 12 s)
    quarter = 0.25 * VEHICLE.max_wheel_angle_rad
    steering = np.sign([c.delta for c in commands if abs(c.delta) > quarter])
    assert np.count_nonzero(np.diff(steering)) <= 1
    assert all(c.ok for c in commands)


def test_with_the_path_itself_as_the_reference_the_soaks_stop_stood_for_good():
    """Why the way back: without it, the same start is a plan to stand."""
    errors, commands = closed_loop(
        Mpc(VEHICLE, MpcParams(rejoin_band_m=100.0, **UNTIMED)),
        arc_path(math.inf),
        0.55,
        3.0,
        seconds=10.0,
        v0=0.0,
        yaw0=0.165,
    )
    assert max(c.v for c in commands) < 0.05 and errors[-1] == pytest.approx(0.55, abs=0.01)


def way_back(left_m: float, heading: float, band_m: float = 0.15, length_m: float = 4.0):
    """The references of a straight path (world x axis) seen from a vehicle `left_m` left of it,
    headed `heading` to it: the lateral offset (world y) of the references at world x = 0..8 m."""
    s = np.arange(-2.0, 40.0, 0.25)
    c, si = math.cos(heading), math.sin(heading)
    dx, dy = s - 0.0, -left_m  # the path's poses from the vehicle, turned into its frame
    path = _Polyline(c * dx + si * dy, -si * dx + c * dy, np.full(len(s), 3.0))
    path.rejoin(band_m, length_m, max_kappa=10.0, speed_mps=2.0)  # a curvature never reached: L stays
    ahead = np.arange(0.0, 8.0, 0.5)
    x = c * ahead - si * left_m
    y = -si * ahead - c * left_m  # the path's points at x = ahead, in the vehicle's frame ...
    n = len(ahead)
    refs = path.references(x, y)
    rx, ry = refs[:n], refs[n : 2 * n]  # ... and their references, back in the world
    return ahead, si * rx + c * ry + left_m, path


def test_within_the_band_the_references_are_the_path_itself():
    _, offsets, path = way_back(0.12, 0.1)
    assert np.allclose(offsets, 0.0, atol=1e-9) and path.rejoin_speed == math.inf


def test_the_way_back_is_the_same_curve_from_any_point_on_it():
    """e(d) = (e0 + (e0 / L + θ0) d) exp(-d / L), starting the band nearer the path than the
    vehicle: a vehicle the band beside it, headed along it, is asked for the same curve again."""
    band, length, e0, theta0 = 0.15, 4.0, 0.65, 0.12
    curve = lambda d: (e0 + (e0 / length + theta0) * d) * np.exp(-d / length)  # noqa: E731
    slope = lambda d: (theta0 - (e0 / length + theta0) * d / length) * np.exp(-d / length)  # noqa: E731
    ahead, offsets, _ = way_back(band + e0, math.atan(theta0), band, length)
    assert np.allclose(offsets, curve(ahead), atol=0.01)
    d1 = 2.0  # 2 m on: the vehicle the band beside the curve, headed along it
    later_ahead, later, _ = way_back(band + float(curve(d1)), math.atan(float(slope(d1))), band, length)
    assert np.allclose(later, curve(d1 + later_ahead), atol=0.02)
