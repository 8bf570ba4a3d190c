"""`ares bench path`: the path manager's KD-tree and match, and one UKF step, in this process.

No bus is involved. The route is a long wiggly closed path (a ~50 km loop whose radius swings
with two harmonics, curves down to ~100 m radius) of exactly `poses` poses. Queries replay
drives along it at 4 m/s sampled at 20 Hz, with a slowly wandering cross-track offset and yaw
noise; each match's hint is the previous match's progress, as in the path manager. The figure
that matters is PathIndex.match (tracked: the nearest reachable pose in the hint's window +
perpendicular refinement); the match without a hint (start-up, a rematch: a ball query of the
{X, Y, Z, Ψ} KD-tree) and the raw KD queries are given beside it.
"""

from __future__ import annotations

import math
import os
import platform
import time
from collections.abc import Callable
from importlib import metadata
from typing import TextIO

from ares.tools.bench.common import Goal, judge, percentile

PATH_GOALS = {"kdtree_build_ms": Goal(100.0), "query_p50_us": Goal(30.0)}


def bench_route(poses: int = 100_000, spacing_m: float = 0.5):
    """A closed wiggly loop of exactly `poses` poses, `spacing_m` apart."""
    import numpy as np

    from ares.core.route import Route

    length = poses * spacing_m
    theta = np.linspace(0.0, 2 * math.pi, 20 * poses, endpoint=False)
    big = length / (2 * math.pi)
    waves = max(round(length / 300.0), 1)  # ~300 m between bends, and tighter ones between;
    # whole numbers of waves round the loop, so that it closes without a kink
    radius = big + 20.0 * np.sin(waves * theta) + 6.0 * np.sin(3 * waves * theta + 1.0)
    x, y = radius * np.cos(theta), radius * np.sin(theta)
    seg = np.hypot(np.diff(x, append=x[:1]), np.diff(y, append=y[:1]))
    s = np.concatenate([[0.0], np.cumsum(seg)])
    scale = length / s[-1]  # make the loop exactly `length` long
    s_new = np.arange(poses) * spacing_m / scale
    xs = np.interp(s_new, s, np.append(x, x[0])) * scale
    ys = np.interp(s_new, s, np.append(y, y[0])) * scale
    return Route("bench", xs, ys, np.zeros(poses), True, np.full(poses, 6.0))


def _drive_poses(route, queries: int, drives: int, seed: int):
    """(x, y, z, yaw, true progress, true offset) of `drives` drives at 0.2 m per query, random starts."""
    import numpy as np

    rng = np.random.default_rng(seed)
    per = max(queries // drives, 1)
    out = []
    for _ in range(drives):
        s0 = rng.uniform(0.0, route.length)
        s = s0 + 0.2 * np.arange(per)
        phase = rng.uniform(0, 2 * math.pi)
        offset = 0.8 * np.sin(0.013 * np.arange(per) + phase) + rng.normal(0.0, 0.05, per)
        for k in range(per):
            px, py, pz, yaw = route.point_at(float(s[k]))
            out.append(
                (
                    px - math.sin(yaw) * offset[k],
                    py + math.cos(yaw) * offset[k],
                    pz,
                    yaw + float(rng.normal(0.0, 0.05)),
                    float(s[k]),
                    float(offset[k]),
                )
            )
    return out


def _ukf_step_p50_ms(n: int) -> float:
    """p50 of one UKF step (predict + update), perception.ukf.ukf_step_benchmark's n steps."""
    from perception.ukf import ukf_step_benchmark

    return percentile(ukf_step_benchmark(n), 50) * 1e3


def _build_times(route, builds: int) -> tuple[list[float], list[float], object]:
    """(ms of each KD-tree build, ms of each PathIndex build, the last PathIndex)."""
    from scipy.spatial import cKDTree

    from managers.path import PathIndex

    index_ms = []
    for _ in range(3):
        started = time.perf_counter()
        index = PathIndex(route)
        index_ms.append((time.perf_counter() - started) * 1e3)
    build_ms = []
    for _ in range(builds):  # the tree over {X, Y, Z, Ψ} alone
        started = time.perf_counter()
        cKDTree(index.points)
        build_ms.append((time.perf_counter() - started) * 1e3)
    return build_ms, index_ms, index


def _match_times(index, drives: list, per: int) -> tuple[list[float], int, float]:
    """(µs of each match, the matches not tracked, the worst |match xte - true offset|): each
    drive's matches hinted by the one before, as the path manager does."""
    match_us, not_tracked, worst_xte_error = [], 0, 0.0
    perf = time.perf_counter_ns
    hint = None
    for k, (x, y, z, yaw, s_true, offset) in enumerate(drives):
        if k % per == 0:
            hint = s_true - 0.2  # a drive starts tracked, as the path manager would be
        started = perf()
        m = index.match(x, y, yaw, hint, z=z)
        match_us.append((perf() - started) / 1e3)
        if m is None or m.search != "tracked":
            not_tracked += 1
            hint = None if m is None else m.progress
            continue
        hint = m.progress
        worst_xte_error = max(worst_xte_error, abs(m.xte - offset))
    return match_us, not_tracked, worst_xte_error


def _kd_query_times(index, drives: list) -> tuple[list[float], list[float], list[float]]:
    """(µs of each raw ball query, of each nearest query, of each match without a hint) at the
    drives' poses (every tenth for the last)."""
    perf = time.perf_counter_ns
    tree = index.tree
    ball_us, nearest_us, unhinted_us = [], [], []
    for k, (x, y, z, yaw, *_) in enumerate(drives):
        query = index.query_point(x, y, z, yaw)
        started = perf()
        tree.query_ball_point(query, index.radius_m)
        ball_us.append((perf() - started) / 1e3)
        started = perf()
        tree.query(query)
        nearest_us.append((perf() - started) / 1e3)
        if k % 10 == 0:
            started = perf()
            index.match(x, y, yaw, None, z=z)
            unhinted_us.append((perf() - started) / 1e3)
    return ball_us, nearest_us, unhinted_us


def run_path_bench(
    poses: int = 100_000,
    queries: int = 10_000,
    builds: int = 7,
    ukf_steps: int = 1000,
    seed: int = 1,
    progress: Callable[[str], None] | None = None,
) -> dict:
    import numpy as np

    say = progress or (lambda _msg: None)
    say(f"building a {poses}-pose route")
    route = bench_route(poses)
    build_ms, index_ms, index = _build_times(route, builds)
    n_drives = max(queries // 1000, 1)
    say(f"{queries} matches along {n_drives} drives")
    drives = _drive_poses(route, queries, n_drives, seed)
    match_us, not_tracked, worst_xte_error = _match_times(index, drives, max(queries // n_drives, 1))
    ball_us, nearest_us, unhinted_us = _kd_query_times(index, drives)
    say("UKF step")
    ukf_p50 = _ukf_step_p50_ms(ukf_steps)
    result = {
        "bench": "path",
        "poses": poses,
        "route_length_m": round(route.length, 1),
        "spacing_m": round(route.length / poses, 3),
        "kdtree_build_ms": percentile(build_ms, 50, 3),
        "kdtree_builds": builds,
        "path_index_build_ms": percentile(index_ms, 50, 3),
        "queries": len(match_us),
        "query_p50_us": percentile(match_us, 50, 2),
        "query_p90_us": percentile(match_us, 90, 2),
        "query_p99_us": percentile(match_us, 99, 2),
        "query_method": (
            "PathIndex.match: nearest pose within radius_m, heading agreeing, in the hint's window "
            "(read from the route), refined to the perpendicular foot; hint = previous match"
        ),
        "radius_m": index.radius_m,
        "unhinted_match_p50_us": percentile(unhinted_us, 50, 2),
        "kd_ball_query_p50_us": percentile(ball_us, 50, 2),
        "kd_nearest_query_p50_us": percentile(nearest_us, 50, 2),
        "matches_not_tracked": not_tracked,
        "max_xte_error_m": round(worst_xte_error, 4),  # |match xte - the drive's true offset|
        "ukf_step_p50_ms": round(ukf_p50, 4),
        "ukf_step_method": f"perception.ukf.ukf_step_benchmark({ukf_steps}): one predict + update",
        "cpus": os.cpu_count(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "scipy": metadata.version("scipy"),
    }
    return judge(result, PATH_GOALS)


def format_path_result(result: dict, out: TextIO) -> None:
    met = result["goals_met"]
    mark = lambda k: "ok" if met[k] else "MISSED"  # noqa: E731
    out.write(
        f"path bench ({result['poses']} poses, {result['route_length_m'] / 1000:.1f} km closed route, "
        f"python {result['python']}, scipy {result['scipy']})\n"
    )
    out.write(
        f"  KD-tree build {result['kdtree_build_ms']:.1f} ms (median of {result['kdtree_builds']})  "
        f"[goal <= {PATH_GOALS['kdtree_build_ms'].limit:g} ms: {mark('kdtree_build_ms')}]; "
        f"PathIndex {result['path_index_build_ms']:.1f} ms\n"
    )
    out.write(
        f"  match p50 {result['query_p50_us']:.1f} us  [goal <= {PATH_GOALS['query_p50_us'].limit:g} us: "
        f"{mark('query_p50_us')}], p90 {result['query_p90_us']:.1f} us, p99 {result['query_p99_us']:.1f} us, "
        f"{result['queries']} matches, {result['matches_not_tracked']} not tracked, "
        f"max xte error {result['max_xte_error_m']:.4f} m\n"
    )
    out.write(
        f"  raw KD: ball query (r = {result['radius_m']:g} m) p50 {result['kd_ball_query_p50_us']:.1f} us, "
        f"nearest p50 {result['kd_nearest_query_p50_us']:.1f} us; a match without a hint p50 "
        f"{result['unhinted_match_p50_us']:.1f} us\n"
    )
    ukf = result["ukf_step_p50_ms"]
    out.write(f"  UKF step p50 {ukf:.3f} ms  ({result['ukf_step_method']})\n")
