"""`ares bench perception --reference`: our ground stage beside a published ground segmenter,
Patchwork++ (Lee, Lim, Myung: "Patchwork++: Fast and robust ground segmentation solving partial
under-segmentation using 3D point cloud", IROS 2022; the `pypatchworkpp` package), on the same
scans, point for point.

The scans:

- simulated, at places spread evenly along the built-in tour: the ARES shuttle's roof HDL-64E
  alone (3.09 m above the road, the tour as it is), and the dense street scan of `ares bench
  perception` (a techs4agecar roof HDL-64E 1.73 m up, as on KITTI's car, façades either side);
- real: every file given with `--scan` (KITTI .bin, .pcd, .ply), read and placed as `ares
  perception scan` does (on the techs4agecar's roof, KITTI's 1.73 m for a .bin).

Each goes through the pipeline's filters (LidarPipeline.road_frame: vehicle frame, self hits and
ghosts removed); then the same points are labelled three ways: our floor ground stage
(GroundParams.mask, method floor: the stack's default), Algorithm 2 as published (method
cell_span), and
Patchwork++ on the points moved back into the sensor's frame, its
sensor_height set to the mount's height above the road (its other parameters its defaults; its
reflected-noise removal off, as a scan without intensities has it anyway). Per scan: the share of
points each calls ground, over the whole scan and inside the 20 × 20 m occupancy grid; the IoU of
each one's ground labels with Patchwork++'s; the occupied cells each leaves in the grid
(OccupancyMapper.cells on that mask); and the time of each, medians of `repeats` runs, wall and
the calling thread's CPU time.
"""

from __future__ import annotations

import contextlib
import os
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TextIO

import numpy as np

from ares.tools.bench.common import BenchError, Goal, judge, percentile

SIM_IOU_GOAL = 0.85  # ours against Patchwork++, every simulated scan
REAL_SHARE_GOAL = 0.10  # |our ground share - Patchwork++'s|, every real scan
LABELLERS = ("ours", "algorithm2", "patchworkpp")


@dataclass
class ScanCase:
    name: str
    kind: str  # "simulated" or "real"
    pipeline: object  # LidarPipeline of the scan's one sensor
    sweep: object  # SensorSweep, sensor frame
    sensor_height_m: float


@contextlib.contextmanager
def _stdout_silenced() -> Iterator[None]:
    """Patchwork++'s C++ writes to the process's stdout (fd 1) whatever `verbose` says; this
    command's stdout carries its result."""
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 1)
        yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)


def patchwork(sensor_height_m: float):
    """A Patchwork++ segmenter for a sensor this high above the road."""
    try:
        import pypatchworkpp
    except ImportError as exc:
        raise BenchError(f"the reference needs the pypatchworkpp package: {exc}") from None
    params = pypatchworkpp.Parameters()
    params.sensor_height = float(sensor_height_m)
    params.enable_RNR = False  # needs intensities: our simulated scans carry none to it
    params.verbose = False
    with _stdout_silenced():
        return pypatchworkpp.patchworkpp(params)


def patchwork_ground(segmenter, sensor_points: np.ndarray) -> np.ndarray:
    """Patchwork++'s ground mask of an (N, 3) cloud in the sensor's frame."""
    with _stdout_silenced():
        segmenter.estimateGround(np.ascontiguousarray(sensor_points, dtype=np.float64))
    ground = np.zeros(len(sensor_points), dtype=bool)
    ground[np.asarray(segmenter.getGroundIndices(), dtype=np.int64)] = True
    return ground


def _timed(run: Callable[[], np.ndarray], repeats: int) -> tuple[np.ndarray, float, float]:
    """(the last result, median wall ms, median CPU ms of this thread)."""
    wall, cpu = [], []
    for _ in range(repeats):
        started, thread = time.perf_counter(), time.thread_time()
        out = run()
        cpu.append((time.thread_time() - thread) * 1e3)
        wall.append((time.perf_counter() - started) * 1e3)
    return out, float(np.median(wall)), float(np.median(cpu))


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    union = int((a | b).sum())
    return round(int((a & b).sum()) / union, 4) if union else 1.0


def compare(case: ScanCase, repeats: int = 5) -> dict:
    """One scan labelled by each labeller: the row of the table."""
    from perception.extrinsics import apply
    from perception.occupancy import OCCUPIED

    pipeline = case.pipeline
    frame, _, _ = pipeline.road_frame([case.sweep])
    points, sensor_index = frame.points, frame.sensor_index
    grid = pipeline.params.grid
    ours_params = pipeline.params.ground.model_copy(update={"method": "floor"})
    paper_params = ours_params.model_copy(update={"method": "cell_span"})
    sensor_points = apply(np.linalg.inv(pipeline.extrinsics[case.sweep.name]), points)
    segmenter = patchwork(case.sensor_height_m)
    runs = {
        "ours": lambda: ours_params.mask(points, grid),
        "algorithm2": lambda: paper_params.mask(points, grid),
        "patchworkpp": lambda: patchwork_ground(segmenter, sensor_points),
    }
    masks, wall, cpu = {}, {}, {}
    for name, run in runs.items():
        masks[name], wall[name], cpu[name] = _timed(run, repeats)
    inside = pipeline.mapper.grid.cell_index(points[:, 0], points[:, 1])[1]
    occupied = {
        name: pipeline.mapper.cells(points, mask, sensor_index).ravel() == OCCUPIED for name, mask in masks.items()
    }
    reference = masks["patchworkpp"]
    return {
        "scan": case.name,
        "kind": case.kind,
        "points": len(points),
        "points_in_grid": int(inside.sum()),
        "sensor_height_m": round(case.sensor_height_m, 3),
        "share": {name: round(float(mask.mean()), 4) for name, mask in masks.items()},
        "share_in_grid": {name: round(float(mask[inside].mean()), 4) for name, mask in masks.items()},
        "iou": {name: _iou(masks[name], reference) for name in ("ours", "algorithm2")},
        "iou_in_grid": {name: _iou(masks[name][inside], reference[inside]) for name in ("ours", "algorithm2")},
        "occupied": {name: int(cells.sum()) for name, cells in occupied.items()},
        "occupied_not_by_patchworkpp": {
            name: int((occupied[name] & ~occupied["patchworkpp"]).sum()) for name in ("ours", "algorithm2")
        },
        "occupied_only_by_patchworkpp": {
            name: int((occupied["patchworkpp"] & ~occupied[name]).sum()) for name in ("ours", "algorithm2")
        },
        "ms": {name: round(value, 3) for name, value in wall.items()},
        "cpu_ms": {name: round(value, 3) for name, value in cpu.items()},
    }


def simulated_cases(frames: int, seed: int, progress: Callable[[str], None]) -> list[ScanCase]:
    """Two simulated HDL-64E scans at each of `frames` places along the tour (the module's docstring)."""
    from ares.core.config import load_vehicle
    from ares.tools.bench.perception import TourScene, street_roof_scan
    from perception.lidar_perception import LidarPipeline, SensorSweep
    from simulator.lidar import LidarSimParams, SimulatedLidar

    shuttle = load_vehicle("ares_shuttle")
    roof = shuttle.lidars["roof"]
    sensor = SimulatedLidar("roof", roof, shuttle, LidarSimParams(), np.random.default_rng([seed, 0]))
    scene = TourScene(shuttle.wheelbase_m)
    tour_pipeline = LidarPipeline(shuttle, mounts={"roof": roof})
    cases = []
    for k in range(frames):
        s = (k + 0.5) * scene.route.length / frames
        progress(f"simulating place {k + 1}/{frames}: s = {s:.0f} m, verges {'/'.join(scene.route.verge_at(s))}")
        sweep = scene.sweep(sensor, s)
        points = np.column_stack([sweep.x, sweep.y, sweep.z])
        cases.append(
            ScanCase(
                f"tour s={s:.0f} m", "simulated", tour_pipeline, SensorSweep("roof", points, sweep.ring), roof.xyz_m[2]
            )
        )
        dense, car, mount = street_roof_scan(scene, s, seed + k)
        points = np.column_stack([dense.x, dense.y, dense.z])
        cases.append(
            ScanCase(
                f"street s={s:.0f} m",
                "simulated",
                LidarPipeline(car, mounts={"roof": mount}),
                SensorSweep("roof", points, dense.ring),
                mount.xyz_m[2],
            )
        )
    return cases


def real_case(path: str | Path, vehicle_name: str = "techs4agecar") -> ScanCase:
    """A scan file placed as `ares perception scan` places it: on the vehicle's roof mount, at
    KITTI's height for a .bin and the mount's own for the others; rings recovered if it has none."""
    from ares.core.config import LIDAR_MODELS, LidarMount, load_vehicle
    from perception.lidar_perception import LidarPipeline, SensorSweep
    from perception.rings import recover_rings
    from perception.scan_file import KITTI_SENSOR_HEIGHT_M, read_scan

    path = Path(path)
    scan = read_scan(path)
    vehicle = load_vehicle(vehicle_name)
    roof = vehicle.lidars["roof"]
    height = KITTI_SENSOR_HEIGHT_M if path.suffix.lower() == ".bin" else roof.xyz_m[2]
    mount = LidarMount(model="hdl64e", xyz_m=(roof.xyz_m[0], roof.xyz_m[1], height), rpy_deg=roof.rpy_deg)
    ring = scan.ring if scan.ring is not None else recover_rings(scan.points, LIDAR_MODELS["hdl64e"])[0]
    pipeline = LidarPipeline(vehicle, mounts={"roof": mount})
    return ScanCase(path.name, "real", pipeline, SensorSweep("roof", scan.points, ring), height)


def _summary(simulated: list[dict], real_rows: list[dict]) -> dict:
    """Per kind of scan (simulated, real): the worst and median IoU, the largest ground share gap,
    the median times of each labeller."""
    summary = {}
    for name, part in (("simulated", simulated), ("real", real_rows)):
        if not part:
            continue
        summary[name] = {
            "scans": len(part),
            "iou_min": {who: min(r["iou"][who] for r in part) for who in ("ours", "algorithm2")},
            "iou_p50": {who: percentile([r["iou"][who] for r in part], 50, 4) for who in ("ours", "algorithm2")},
            "share_gap_max": {
                who: round(max(abs(r["share"][who] - r["share"]["patchworkpp"]) for r in part), 4)
                for who in ("ours", "algorithm2")
            },
            "cpu_ms_p50": {who: percentile([r["cpu_ms"][who] for r in part], 50, 3) for who in LABELLERS},
            "ms_p50": {who: percentile([r["ms"][who] for r in part], 50, 3) for who in LABELLERS},
        }
    return summary


def run_reference_bench(
    frames: int = 8,
    repeats: int = 5,
    seed: int = 1,
    scans: list[str] | tuple[str, ...] = (),
    progress: Callable[[str], None] | None = None,
) -> dict:
    from ares.core.config import ConfigError
    from perception.scan_file import ScanFileError

    say = progress or (lambda _msg: None)
    load_before = os.getloadavg()
    try:
        real = [real_case(path) for path in scans]
    except (ScanFileError, ConfigError) as exc:
        raise BenchError(str(exc)) from None
    cases = simulated_cases(frames, seed, say) + real
    if not cases:
        raise BenchError("no scans: simulate some places (--frames) or give files (--scan)")
    rows = []
    for k, case in enumerate(cases):
        say(f"labelling {k + 1}/{len(cases)}: {case.name}")
        rows.append(compare(case, repeats))

    simulated = [r for r in rows if r["kind"] == "simulated"]
    real_rows = [r for r in rows if r["kind"] == "real"]
    result: dict = {
        "bench": "perception_reference",
        "frames": frames,
        "repeats": repeats,
        "scans": rows,
        "cpus": os.cpu_count(),
        "load_avg_1m": [round(load_before[0], 2), round(os.getloadavg()[0], 2)],
        "numpy": np.__version__,
        "pypatchworkpp": _version("pypatchworkpp"),
        "method": (
            "same filtered points (LidarPipeline.road_frame) labelled by GroundParams.mask, method floor (ours), "
            "method cell_span (Algorithm 2 as published) and Patchwork++ in the sensor frame at the "
            "mount's height; IoU of ground labels against Patchwork++'s; occupied cells from "
            "OccupancyMapper.cells on each mask; medians of repeats, wall and thread CPU time"
        ),
    }
    result["summary"] = _summary(simulated, real_rows)
    result["scans_ours_not_faster"] = sum(r["cpu_ms"]["ours"] >= r["cpu_ms"]["patchworkpp"] for r in rows)
    goals = {"scans_ours_not_faster": Goal(0)}  # ours faster than Patchwork++ on every scan
    if simulated:
        goals["summary.simulated.iou_min.ours"] = Goal(SIM_IOU_GOAL, at_least=True)
    if real_rows:
        goals["summary.real.share_gap_max.ours"] = Goal(REAL_SHARE_GOAL)
    return judge(result, goals)


def _version(distribution: str) -> str | None:
    from importlib import metadata

    try:
        return metadata.version(distribution)
    except metadata.PackageNotFoundError:
        return None


def format_reference_result(result: dict, out: TextIO) -> None:
    out.write(
        f"ground stage beside Patchwork++ {result['pypatchworkpp']}: {len(result['scans'])} scans, "
        f"{result['repeats']} repeats, {result['cpus']} CPUs, load {result['load_avg_1m'][0]} -> "
        f"{result['load_avg_1m'][1]}\n"
        "  ours = GroundParams' floor method, alg2 = Algorithm 2 as published, P++ = Patchwork++; "
        "IoU of ground labels with P++'s; CPU ms (thread), medians\n"
    )
    out.write(
        f"  {'scan':18} {'points':>7} {'ground share ours/alg2/P++':>27} {'in grid':>17} "
        f"{'IoU ours/alg2':>14} {'occupied ours/alg2/P++':>23} {'CPU ms ours/alg2/P++':>22}\n"
    )
    for r in result["scans"]:
        s, g, i, o, c = r["share"], r["share_in_grid"], r["iou"], r["occupied"], r["cpu_ms"]
        out.write(
            f"  {r['scan'][:18]:18} {r['points']:7d} "
            f"{s['ours']:9.3f}{s['algorithm2']:9.3f}{s['patchworkpp']:9.3f} "
            f"{g['ours']:6.3f}{g['algorithm2']:6.3f}{g['patchworkpp']:6.3f} "
            f"{i['ours']:7.3f}{i['algorithm2']:7.3f} "
            f"{o['ours']:8d}{o['algorithm2']:8d}{o['patchworkpp']:7d} "
            f"{c['ours']:8.1f}{c['algorithm2']:7.1f}{c['patchworkpp']:7.1f}\n"
        )
    for name, part in result["summary"].items():
        out.write(
            f"  {name}: {part['scans']} scans, IoU ours min {part['iou_min']['ours']:.3f} "
            f"(alg2 {part['iou_min']['algorithm2']:.3f}), share gap max ours {part['share_gap_max']['ours']:.3f} "
            f"(alg2 {part['share_gap_max']['algorithm2']:.3f}), CPU ms p50 ours {part['cpu_ms_p50']['ours']:.1f} "
            f"alg2 {part['cpu_ms_p50']['algorithm2']:.1f} P++ {part['cpu_ms_p50']['patchworkpp']:.1f}\n"
        )
    for path, met in result["goals_met"].items():
        bound = ", ".join(f"{side.replace('_', ' ')} {limit:g}" for side, limit in result["goals"][path].items())
        out.write(f"  goal {path} {bound}: {'ok' if met else 'MISSED'}\n")
