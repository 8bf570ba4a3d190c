"""The experiment that chose where road reactive control reads the road at the vehicle
(control/rrc.py: view_from_m, view_to_m; docs/control.md).

    ares calibrate rrc-view [--seed S] [--json]

Road detection sees the boundaries from about 4 m ahead, so the offset and heading it gives at
x = 0 are its fit extrapolated backwards. The RRC can instead read them from frames seen a few
metres back, moved along by what was driven. Which frames?

1. Frames. Sequences along the built-in tour, a frame every 0.5 m (10 Hz at 5 m/s), the vehicle
   on a line parallel to the centre line (off it by `lateral`, not turned, so that the poses are
   ones a vehicle drives through): through each tight bend from 10 m before to 10 m after it, and
   along plain stretches away from them with a boundary on both sides (no crossing or square).
   The LiDARs at full resolution through the pipeline, as for `ares calibrate road`
   (ares/tools/harness/road_betas.py).
2. Reading. detect_road on each sequence in order (each frame's model the next one's previous;
   after a frame without a road, the last road found moved by the drive, as the pipeline does),
   and for every candidate range of distances back one RoadReactiveControl fed the detections,
   the distance driven between frames and its curvature, exactly (the route's, along the
   parallel line). Its command's e and heading are compared with the truth (lateral, 0).
3. Figures per group of sequences and range: the offset's error p50, p95 and max, the heading's
   p95, and the p95 of the error of b, the curvature fed forward, against the route's mean
   curvature over the look-ahead (frames where the road was found); and how many of those frames
   the RRC did not follow, as disagreeing with the road it remembered (`agree_m`).
"""

from __future__ import annotations

import math

import numpy as np

from ares.core.config import load_vehicle
from ares.core.route import Route
from ares.tools.bench.common import percentile
from ares.tools.harness.road_betas import make_frames, tight_bends
from control.rrc import RoadReactiveControl, RoadView, RrcParams
from perception.lidar_perception import LidarPipeline
from perception.road_detection import RoadDetectionParams, detect_road

RANGES = ((0.0, 0.0), (2.0, 5.0), (3.0, 6.0), (4.0, 6.0), (4.0, 8.0))  # (view_from_m, view_to_m); 0-0: at x = 0
STEP_M = 0.5
RUN_M = 10.0  # before and after a tight bend
PLAIN_M = 50.0  # a plain sequence's length
PLAIN_CLEAR_M = 30.0  # ... at least this far from a tight bend
SUBSTEPS = 10  # the drive between two frames, integrated along the route's curvature


def sequences(route: Route, plain: int = 3, laterals: tuple[float, ...] = (0.0, 0.3)) -> list[dict]:
    """(group, s0, lateral, frames) of every sequence: each tight bend at each lateral offset, and
    `plain` stretches spread along the tour clear of the bends and of open verges."""
    out = []
    bends = tight_bends(route)
    for a, b in bends:
        left, right = route.verge_at(a % route.length + (b - a) / 2)
        group = f"bend {a % route.length:.0f}-{b % route.length:.0f} m ({left}/{right})"
        for lateral in laterals:
            out.append(
                {"group": group, "s0": a - RUN_M, "lateral": lateral, "frames": int((b - a + 2 * RUN_M) / STEP_M) + 1}
            )
    clear = [
        s
        for s in np.arange(0.0, route.length - PLAIN_M, 5.0)
        if all(s + PLAIN_M < a - PLAIN_CLEAR_M or s > b + PLAIN_CLEAR_M for a, b in bends)
        and all("open" not in route.verge_at(float(v)) for v in np.arange(s, s + PLAIN_M + 12.0, 2.0))
    ]
    for s in np.array(clear)[np.linspace(0, len(clear) - 1, plain).astype(int)] if clear else []:
        out.append({"group": "plain", "s0": float(s), "lateral": 0.0, "frames": int(PLAIN_M / STEP_M) + 1})
    return out


def _driven(route: Route, s0: float, s1: float, lateral: float) -> list[tuple[float, float]]:
    """(distance, curvature) pieces of the line `lateral` off the centre line from s0 to s1."""
    pieces = []
    ds = (s1 - s0) / SUBSTEPS
    for k in range(SUBSTEPS):
        kappa = float(route.curvature[route.index_at((s0 + (k + 0.5) * ds) % route.length)])
        shrink = 1.0 - kappa * lateral  # a parallel line inside a bend is shorter
        pieces.append((ds * shrink, kappa / shrink))
    return pieces


def run(
    seed: int = 0,
    plain: int = 3,
    laterals: tuple[float, ...] = (0.0, 0.3),
    verbose: bool = False,
    ranges: tuple[tuple[float, float], ...] = RANGES,
    plan: list[dict] | None = None,
) -> dict:
    """The figures; `plan` (as `sequences` gives) instead of every tight bend and `plain` stretches."""
    route = Route.from_tour("default")
    plan = plan if plan is not None else sequences(route, plain, laterals)
    detection = RoadDetectionParams()
    shuttle = load_vehicle("ares_shuttle")
    errors: dict[str, dict[str, list]] = {}
    doubts: dict[str, dict[str, int]] = {}
    for n, seq in enumerate(plan):
        frames = make_frames(
            seed=seed, starts=[(seq["s0"], seq["lateral"], 0.0)], frames_per_sequence=seq["frames"], step_m=STEP_M
        )
        readers = {r: RoadReactiveControl(RrcParams(view_from_m=r[0], view_to_m=r[1])) for r in ranges}
        group = errors.setdefault(seq["group"], {f"{a:g}-{b:g} m": [] for a, b in ranges})
        doubted = doubts.setdefault(seq["group"], {f"{a:g}-{b:g} m": 0 for a, b in ranges})
        pipeline = LidarPipeline(shuttle)
        last_s, last_view = None, None
        for f in frames:
            pieces = _driven(route, last_s, f.s, seq["lateral"]) if last_s is not None else [(0.0, 0.0)]
            last_s = f.s
            driven = sum(d for d, _ in pieces)
            result = detect_road(
                f.lidar, detection, pipeline.guide((driven, sum(d * k for d, k in pieces) / driven if driven else 0.0))
            )
            pipeline.remember(result)
            view = None
            if result.found:
                view = RoadView(
                    result.lateral_offset_m,
                    result.heading_rad,
                    list(result.model.centre()),
                    result.confidence,
                    stamp=f.s,
                )
            for (a, b), rrc in readers.items():
                for distance, kappa in pieces[:-1]:  # the loop between frames sees the last one again
                    rrc.step(last_view, distance, kappa)
                cmd = rrc.step(view, *pieces[-1])
                if view is not None and cmd is not None:
                    doubted[f"{a:g}-{b:g} m"] += bool(rrc.doubted)
                    group[f"{a:g}-{b:g} m"].append(
                        (
                            cmd.error_m - f.lateral_m,
                            math.degrees(cmd.heading_rad) - f.yaw_deg,
                            cmd.feedforward - _mean_curvature(route, f.s, rrc.p.curvature_lookahead_m),
                        )
                    )
            last_view = view
        if verbose:
            print(
                f"  sequence {n + 1}/{len(plan)}: {seq['group']}, lateral {seq['lateral']:+.1f} m, "
                f"{len(frames)} frames",
                flush=True,
            )
    report = {"seed": seed, "sequences": len(plan), "step_m": STEP_M, "groups": {}}
    for name, by_range in errors.items():
        report["groups"][name] = {
            label: {**_figures(pairs), "not_followed": doubts[name][label]} for label, pairs in by_range.items()
        }
    return report


def _figures(errors: list[tuple[float, float, float]]) -> dict:
    """Frames, and |error| p50/p95/max of the offset, p95 of the heading and of b (None without frames)."""
    e = np.abs(np.array(errors)).reshape(-1, 3)
    return {
        "frames": len(e),
        "offset_p50_m": percentile(e[:, 0], 50),
        "offset_p95_m": percentile(e[:, 0], 95),
        "offset_max_m": percentile(e[:, 0], 100),
        "heading_p95_deg": percentile(e[:, 1], 95),
        "curvature_p95": percentile(e[:, 2], 95),
    }


def _mean_curvature(route: Route, s: float, length_m: float) -> float:
    """The route's turn over the next length_m, per metre (what the RRC's b stands for)."""
    return math.remainder(route.point_at(s + length_m)[3] - route.point_at(s)[3], 2.0 * math.pi) / length_m


def table(report: dict) -> str:
    lines = [
        f"{report['sequences']} sequences, a frame every {report['step_m']} m, seed {report['seed']}; "
        "errors of the offset and heading the RRC reads, by where it reads them"
    ]
    lines.append(
        f"{'':<34}{'read':<10}{'frames':>7}{'off p50':>9}{'off p95':>9}{'off max':>9}{'hdg p95':>9}"
        f"{'b p95':>9}{'doubted':>9}"
    )
    for group, by_range in report["groups"].items():
        for label, f in by_range.items():
            if not f["frames"]:
                continue
            lines.append(
                f"{group:<34}{label:<10}{f['frames']:>7}{f['offset_p50_m']:>8.3f}m{f['offset_p95_m']:>8.3f}m"
                f"{f['offset_max_m']:>8.3f}m{f['heading_p95_deg']:>8.1f}°{f['curvature_p95']:>7.3f}/m"
                f"{f['not_followed']:>9}"
            )
    return "\n".join(lines)
