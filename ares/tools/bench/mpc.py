"""`ares bench mpc`: the MPC's solve times in closed loop, in this process.

The MPC (control/mpc.py) drives a kinematic bicycle round the built-in tour at its speed
profile, the steering with the vehicle profile's dead time and rate (as tests/test_mpc.py's
loop), solving at mpc.rate_hz from the true state. Each solve is timed as the MPC node times
it (the path taken in, the Gauss-Newton steps, the command out). A solve longer than the period
(100 ms at 10 Hz) would miss its deadline. The loop's cross-track error is given beside the
times, so that a faster solver that tracks worse shows.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from ares.tools.bench.common import Goal, judge, percentile, versions

MPC_GOALS = {"solve_p50_ms": Goal(1.0), "solve_p99_ms": Goal(3.0), "deadline_misses": Goal(0)}
PLANT_DT = 0.01


def _closed_loop(mpc, vehicle, route, speed, solves: int, progress: Callable[[str], None]):
    """(ms of each solve, the cross-track error at each, the distance driven, the failed solves):
    the MPC solving at its rate from the true state of a kinematic bicycle whose steering has the
    vehicle's dead time and rate."""
    from control.mpc import VehicleState, predict

    params = mpc.params
    steering = vehicle.actuators.steering
    rate = vehicle.max_wheel_rate_rad_s * PLANT_DT
    every = round(1.0 / params.rate_hz / PLANT_DT)
    x, y, yaw, v, delta, accel = float(route.x[0]), float(route.y[0]), float(route.yaw[0]), 0.0, 0.0, 0.0
    pending: list[tuple[float, float]] = []
    target, times, xte, s_hint, failures = 0.0, [], [], 0.0, 0
    n = len(route.x)
    k = 0
    while len(times) < solves:
        t = k * PLANT_DT
        if k % every == 0:
            s, err, _ = route.project(x, y, s_hint)
            s_hint = s
            xte.append(err)
            i = int(np.searchsorted(route.s, s % route.length))
            near = np.arange(i - 2, i + 80) % n
            started = time.perf_counter()
            cmd = mpc.solve(VehicleState(x, y, yaw, v, delta, accel), route.x[near], route.y[near], speed[near])
            times.append((time.perf_counter() - started) * 1e3)
            failures += not cmd.ok
            pending.append((t + steering.dead_time_s, cmd.delta))
            accel = cmd.accel
            if len(times) % 500 == 0:
                progress(f"{len(times)} solves")
        while pending and pending[0][0] <= t + 1e-9:
            target = pending.pop(0)[1]
        delta += float(np.clip(target - delta, -rate, rate))
        v = max(0.0, v + accel * PLANT_DT)
        x, y, yaw, _ = predict(x, y, yaw, v, delta, 0.0, PLANT_DT, vehicle.wheelbase_m)
        k += 1
    return times, xte, s_hint, failures


def run_mpc_bench(
    solves: int = 2000,
    vehicle_name: str = "ares_shuttle",
    tour: str = "default",
    progress: Callable[[str], None] = lambda _msg: None,
    params=None,
) -> dict:
    """`params` (MpcParams) replaces the configured MPC's: a test gives a late solve all the time
    it takes, so that a busy machine does not count as a failing solver."""
    from ares.core.config import load_vehicle
    from ares.core.route import Route
    from control.mpc import Mpc, MpcParams
    from managers.speed import SpeedProfileParams, speed_limits

    vehicle = load_vehicle(vehicle_name)
    route = Route.from_tour(tour)
    speed = speed_limits(route, SpeedProfileParams(), vehicle)
    params = params or MpcParams()
    progress(f"{solves} solves of horizon {params.horizon_steps} x {params.step_s} s round the '{tour}' tour")
    times, xte, distance, failures = _closed_loop(Mpc(vehicle, params), vehicle, route, speed, solves, progress)
    period_ms = 1e3 / params.rate_hz
    err = np.abs(np.array(xte[20:]))  # after the start from standstill
    result = {
        "bench": "mpc",
        "solve_p50_ms": percentile(times, 50, 3),
        "solve_p99_ms": percentile(times, 99, 3),
        "solve_max_ms": round(max(times), 3),
        "solves": len(times),
        "horizon": params.horizon_steps,
        "step_s": params.step_s,
        "rate_hz": params.rate_hz,
        "deadline_misses": int(sum(t > period_ms for t in times)),
        "failed_solves": failures,
        "xte_rmse_m": round(float(np.sqrt(np.mean(err**2))), 4),
        "xte_max_m": round(float(err.max()), 4),
        "distance_m": round(float(distance), 1),
        "vehicle": vehicle_name,
        "tour": tour,
        **versions("casadi", "numpy"),
    }
    return judge(result, MPC_GOALS)
