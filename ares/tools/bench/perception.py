"""`ares bench perception`: the LiDAR pipeline's stages and the simulated LiDARs' ray casting, at
places spread evenly along the built-in tour (so over its different verges); medians over all.

At each place:

- the stack's frame: the three LiDARs of the ARES shuttle (a roof HDL-64E, two front VLP-16s,
  full resolution) simulated on the tour's World (simulator), then LidarPipeline.process on it.
  Two frames 1 m apart (100 ms at 10 m/s): the first gives the road model the second is
  measured against, as in a drive; the second is processed `repeats` times from that same model.
  Wall times, and beside them the pipeline thread's CPU time (pipeline_cpu_ms_*), which other
  processes on a busy machine do not inflate (they do the wall times, several-fold).
- the ray casting: SimulatedLidar.sweep × 3 for one frame (both frames of each place), twice:
  single-threaded, in a child process whose BLAS runs one thread (OPENBLAS_NUM_THREADS=1) and
  whose scenes cast with nthreads=1 (sweep takes no thread count, so the scenes are handed to it
  wrapped); raycast_core_share_at_10hz = that median / the 100 ms between frames. And as the
  simulator runs it, in this process: open3d's default threads (every core), numpy's BLAS as
  configured; wall and process CPU time. The two differ by more than threads: sweep's
  (n × 3) @ (3 × 3) products go to OpenBLAS, whose threads wait for a busy core (the trap
  perception/extrinsics.py's docstring describes).
- a dense 64-layer scan: the tour's roof sweep has ~78,000 returns (the upper lasers see sky,
  asphalt returns end at ~50 m), a city street's ~120,000 (KITTI's). So the roof HDL-64E of the
  techs4agecar profile, 1.73 m above the road as on KITTI's car, sweeps the tour with a street
  canyon added: 15 m façades along both sides, 7 m beyond the road's edges, 120 m long (cast as
  sweep's obstacle scene, so they return as metal). That
  gives ~120,000-130,000 returns; heightmap.ground_mask is timed on them (vehicle frame, around
  the grid's centre, as the pipeline calls it), and the whole pipeline on that one sensor, as
  `ares perception scan` runs a KITTI file.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, TextIO

import numpy as np

from ares.tools.bench.common import BenchError, Goal, judge, percentile
from perception.scan_file import KITTI_SENSOR_HEIGHT_M

if TYPE_CHECKING:
    from perception.lidar_perception import FrameResult, LidarPipeline
    from simulator.lidar import Sweep

GOALS = {
    "raycast_core_share_at_10hz": Goal(0.30),  # of one core at 10 Hz
    "ground_ms_p50": Goal(5.0),  # heightmap.ground_mask on the dense 64-layer scan
}
FRAME_PERIOD_MS = 100.0
STEP_M = 1.0  # between the two frames of a place: 100 ms at 10 m/s
STREET_SETBACK_M = 7.0  # façades this far beyond the road's edges
FACADE_HEIGHT_M = 15.0
FACADE_LENGTH_M = 120.0
STAGES = ("transform", "filters", "ground", "grid", "road")
METHOD = (
    "stack frame: ares_shuttle's 3 LiDARs simulated at full resolution on the built-in tour, "
    "LidarPipeline.process stage_ms on the second of two frames 1 m apart; ground: "
    "heightmap.ground_mask on a techs4agecar roof HDL-64E sweep 1.73 m up in a street canyon "
    f"(façades {STREET_SETBACK_M:g} m beyond the road's edges); raycast: SimulatedLidar.sweep x 3 "
    "in a child process, open3d nthreads=1, OPENBLAS_NUM_THREADS=1; as_run: in this process, "
    "open3d's and numpy's default threads"
)


class TourScene:
    """The built-in tour's World and poses on it."""

    def __init__(self, wheelbase_m: float):
        from ares.core.route import Route
        from simulator.params import SimParams
        from simulator.road import roughness_for
        from simulator.world import World

        self.route = Route.from_tour("default")
        self.world = World(self.route, roughness_for(self.route, SimParams(), wheelbase_m))

    def pose(self, s: float):
        """(rotation, position) of the vehicle on the road's centre line at s, pitched with the grade."""
        from simulator.lidar import vehicle_pose
        from simulator.road import grade_at

        x, y, _, yaw = self.route.point_at(s)
        return vehicle_pose(x, y, float(self.world.centre_height(s)), yaw, -math.atan(grade_at(self.route, s)))

    def facades(self, s: float):
        """A raycasting scene of a street canyon around s: two façades along the heading there."""
        import open3d as o3d

        from simulator.world import Mesh, box_mesh

        x, y, _, yaw = self.route.point_at(s)
        half = float(self.route.width[self.route.index_at(s)]) / 2
        base = float(self.world.centre_height(s)) - 3.0  # below any verge the tour has
        parts = []
        for side in (1.0, -1.0):
            offset = side * (half + STREET_SETBACK_M)
            parts.append(
                box_mesh(
                    (x - math.sin(yaw) * offset, y + math.cos(yaw) * offset, base),
                    (FACADE_LENGTH_M, 1.0, FACADE_HEIGHT_M + 3.0),
                    yaw,
                    "concrete",
                )
            )
        mesh = Mesh.join(parts)
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(o3d.core.Tensor(mesh.vertices), o3d.core.Tensor(mesh.triangles))
        return scene

    def sweep(self, sensor, s: float, obstacles=None):
        rotation, position = self.pose(s)
        return sensor.sweep(self.world.scene, rotation, position, obstacles, self.world.material_of)


def street_roof_scan(scene: TourScene, s: float, seed: int = 0, height_m: float = KITTI_SENSOR_HEIGHT_M):
    """(sweep in the sensor frame, the car, its roof mount): the dense 64-layer scan of the module's
    docstring at s."""
    from ares.core.config import load_vehicle
    from simulator.lidar import LidarSimParams, SimulatedLidar

    car = load_vehicle("techs4agecar")
    roof = car.lidars["roof"]
    mount = roof.model_copy(update={"xyz_m": (roof.xyz_m[0], roof.xyz_m[1], height_m)})
    sensor = SimulatedLidar("roof", mount, car, LidarSimParams(), np.random.default_rng([seed, 64]))
    return scene.sweep(sensor, s, scene.facades(s)), car, mount


class _Threads:
    """A raycasting scene whose cast_rays uses n threads (0: open3d's default, every core) and
    adds the wall time it takes to `spent` (ms): how much of a sweep is open3d's."""

    def __init__(self, scene, n: int, spent: list[float]):
        self.scene, self.n, self.spent = scene, n, spent

    def cast_rays(self, rays, nthreads: int = 0):  # the sensor's own count is overridden by n
        started = time.perf_counter()
        hit = self.scene.cast_rays(rays, nthreads=self.n)
        self.spent[0] += (time.perf_counter() - started) * 1e3
        return hit


def _sweeps(scene: TourScene, sensors: dict, s: float, threads: int) -> tuple[list, dict]:
    """(sweeps of every sensor, {wall, cpu, cast_rays: ms}) of one simulated frame; threads:
    open3d's cast_rays nthreads."""
    rotation, position = scene.pose(s)
    spent = [0.0]
    world = _Threads(scene.world.scene, threads, spent)  # (each sensor's body hits are cast once, at start)
    wall, cpu = time.perf_counter(), time.process_time()
    out = [
        (name, sensor.sweep(world, rotation, position, None, scene.world.material_of))
        for name, sensor in sensors.items()
    ]
    return out, {
        "wall": (time.perf_counter() - wall) * 1e3,
        "cpu": (time.process_time() - cpu) * 1e3,
        "cast_rays": spent[0],
    }


def _places(route_length: float, frames: int) -> list[float]:
    return [(k + 0.5) * route_length / frames for k in range(frames)]


def _shuttle_lidars(seed: int):
    from ares.core.config import load_vehicle
    from simulator.lidar import LidarSimParams, SimulatedLidar

    shuttle = load_vehicle("ares_shuttle")
    return shuttle, {
        name: SimulatedLidar(name, mount, shuttle, LidarSimParams(), np.random.default_rng([seed, i]))
        for i, (name, mount) in enumerate(shuttle.lidars.items())
    }


def raycast_times(frames: int, seed: int, threads: int) -> dict:
    """{wall, cpu, cast_rays: [ms of each simulated frame]} (two frames per place), in this
    process, open3d `threads`."""
    shuttle, sensors = _shuttle_lidars(seed)
    scene = TourScene(shuttle.wheelbase_m)
    times: dict[str, list[float]] = {"wall": [], "cpu": [], "cast_rays": []}
    for s in _places(scene.route.length, frames):
        for at in (s, s + STEP_M):
            for key, value in _sweeps(scene, sensors, at, threads)[1].items():
                times[key].append(value)
    return times


def _single_threaded_raycast(frames: int, seed: int) -> dict:
    """raycast_times in a child process whose BLAS and OpenMP run one thread (they read it at start)."""
    import ares

    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    root = str(Path(ares.__file__).resolve().parents[1])  # this same code, wherever it runs from
    env["PYTHONPATH"] = os.pathsep.join(p for p in (root, env.get("PYTHONPATH")) if p)
    child = subprocess.run(
        [sys.executable, "-m", "ares.tools.bench.perception", str(frames), str(seed)],
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
        stdin=subprocess.DEVNULL,
    )
    if child.returncode != 0:
        raise BenchError(f"the single-threaded ray casting failed: {child.stderr.strip()[-1500:]}")
    return json.loads(child.stdout.strip().splitlines()[-1])


def _as_input(sweeps: list):
    from perception.lidar_perception import SensorSweep

    return [SensorSweep(name, np.column_stack([sw.x, sw.y, sw.z]), sw.ring) for name, sw in sweeps]


@dataclass
class _Place:
    """A place's simulated input: the stack frame's two frames and the dense 64-layer scan."""

    s: float
    first: list
    second: list
    dense: Sweep


def _simulate_places(scene: TourScene, sensors: dict, places: list[float], seed: int, say) -> tuple[list, dict, tuple]:
    """(every place's input, the as-run ray casting times, the dense scan's (car, roof mount)).
    All the frames first: open3d's worker threads, busy right after a cast, would otherwise
    share the cores with the pipeline measured next."""
    simulated, as_run = [], {"wall": [], "cpu": [], "cast_rays": []}
    dense_sensor: tuple = ()
    for k, s in enumerate(places):
        say(f"simulating place {k + 1}/{len(places)}: s = {s:.0f} m, verges {'/'.join(scene.route.verge_at(s))}")
        pair = []
        for at in (s, s + STEP_M):
            sweeps, times = _sweeps(scene, sensors, at, threads=0)
            pair.append(_as_input(sweeps))
            for key, value in times.items():
                as_run[key].append(value)
        dense, car, mount = street_roof_scan(scene, s, seed + k)
        dense_sensor = (car, mount)
        simulated.append(_Place(s, pair[0], pair[1], dense))
    return simulated, as_run, dense_sensor


def _time_stack_frame(pipeline: LidarPipeline, place: _Place, repeats: int, ms: dict) -> FrameResult:
    """The second frame of a place, `repeats` times against the first's road; its last result."""
    pipeline.previous = None
    pipeline.process(place.first)
    model = pipeline.previous
    for _ in range(repeats):
        pipeline.previous = model
        frame = pipeline.process(place.second)
        ms["pipeline"].append(frame.stage_ms["total"])
        ms["pipeline_cpu"].append(frame.stage_ms["cpu"])
        for stage in STAGES:
            ms[f"stack_{stage}"].append(frame.stage_ms[stage])
    return frame


def _time_dense_scan(
    pipeline: LidarPipeline, single: LidarPipeline, place: _Place, repeats: int, ms: dict
) -> FrameResult:
    """heightmap.ground_mask on the dense scan `repeats` times, then the whole one-sensor pipeline
    on it once, as a file's first frame; that pipeline's result."""
    from perception.extrinsics import apply
    from perception.heightmap import ground_mask
    from perception.lidar_perception import SensorSweep

    grid = pipeline.params.grid
    centre = np.array([grid.centre_x_m, grid.centre_y_m, 0.0], dtype=np.float32)
    dense = place.dense
    cloud = np.column_stack([dense.x, dense.y, dense.z])
    shifted = apply(single.extrinsics["roof"], cloud) - centre
    for _ in range(repeats):
        started = time.perf_counter()
        ground_mask(shifted, grid.width_m, grid.height_m, grid.cell_m, pipeline.params.ground.threshold_m)
        ms["ground_mask"].append((time.perf_counter() - started) * 1e3)
    single.previous = None
    scan = single.process([SensorSweep("roof", cloud, dense.ring)])
    ms["scan"].append(scan.stage_ms["total"])
    ms["scan_cpu"].append(scan.stage_ms["cpu"])
    for stage in STAGES:
        ms[f"scan_{stage}"].append(scan.stage_ms[stage])
    return scan


def _time_pipeline(shuttle, dense_sensor: tuple, simulated: list[_Place], scene: TourScene, repeats: int):
    """(every timing's ms by name, a summary of each place)."""
    from perception.lidar_perception import LidarPipeline

    pipeline = LidarPipeline(shuttle)
    car, mount = dense_sensor
    single = LidarPipeline(car, mounts={"roof": mount})  # the dense scan's one sensor
    keys: tuple[str, ...] = ("ground_mask", "pipeline", "pipeline_cpu", "scan", "scan_cpu")
    keys += tuple(f"stack_{st}" for st in STAGES) + tuple(f"scan_{st}" for st in STAGES)
    ms: dict[str, list[float]] = {key: [] for key in keys}
    where = []
    for place in simulated:
        here = len(ms["pipeline"])
        frame = _time_stack_frame(pipeline, place, repeats, ms)
        scan = _time_dense_scan(pipeline, single, place, repeats, ms)
        where.append(
            {
                "s_m": round(place.s, 1),
                "verges": list(scene.route.verge_at(place.s)),
                "frame_points": sum(len(sweep.points) for sweep in place.second),
                "scan_points": place.dense.size,
                "pipeline_ms_p50": percentile(ms["pipeline"][here:], 50, 3),
                "filters_ms_p50": percentile(ms["stack_filters"][here:], 50, 3),
                "road_found": bool(frame.road.found),
                "scan_road_found": bool(scan.road.found),
            }
        )
    return ms, where


def _pipeline_figures(ms: dict, where: list[dict]) -> dict:
    return {
        "ground_ms_p50": percentile(ms["ground_mask"], 50, 3),
        "ground_scan_points_p50": int(percentile([p["scan_points"] for p in where], 50)),
        "grid_ms_p50": percentile(ms["stack_grid"], 50, 3),
        "road_ms_p50": percentile(ms["stack_road"], 50, 3),
        "filters_ms_p50": percentile(ms["stack_filters"], 50, 3),
        "transform_ms_p50": percentile(ms["stack_transform"], 50, 3),
        "pipeline_ground_ms_p50": percentile(ms["stack_ground"], 50, 3),
        "pipeline_ms_p50": percentile(ms["pipeline"], 50, 3),
        "pipeline_ms_max": round(max(ms["pipeline"]), 3),
        "pipeline_cpu_ms_p50": percentile(ms["pipeline_cpu"], 50, 3),
        "pipeline_cpu_ms_max": round(max(ms["pipeline_cpu"]), 3),
        "frame_points_p50": int(percentile([p["frame_points"] for p in where], 50)),
        "scan_pipeline_ms_p50": percentile(ms["scan"], 50, 3),
        "scan_pipeline_cpu_ms_p50": percentile(ms["scan_cpu"], 50, 3),
        "scan_stage_ms_p50": {stage: percentile(ms[f"scan_{stage}"], 50, 3) for stage in STAGES},
        "places": where,
    }


def _raycast_figures(single_threaded: dict, as_run: dict) -> dict:
    raycast = percentile(single_threaded["wall"], 50, 3)
    return {
        "raycast_ms_p50": raycast,
        "raycast_core_share_at_10hz": round(raycast / FRAME_PERIOD_MS, 3),
        "raycast_cpu_ms_p50": percentile(single_threaded["cpu"], 50, 3),
        "raycast_cast_rays_ms_p50": percentile(single_threaded["cast_rays"], 50, 3),
        "raycast_as_run_ms_p50": percentile(as_run["wall"], 50, 3),
        "raycast_as_run_cpu_ms_p50": percentile(as_run["cpu"], 50, 3),
        "raycast_as_run_cast_rays_ms_p50": percentile(as_run["cast_rays"], 50, 3),
    }


def run_perception_bench(
    frames: int = 8, repeats: int = 3, seed: int = 1, progress: Callable[[str], None] | None = None
) -> dict:
    import open3d
    import scipy

    say = progress or (lambda _msg: None)
    load_before = os.getloadavg()
    say("ray casting single-threaded, in a child process")
    single_threaded = _single_threaded_raycast(frames, seed)
    say("building the built-in tour's world")
    shuttle, sensors = _shuttle_lidars(seed)
    scene = TourScene(shuttle.wheelbase_m)
    places = _places(scene.route.length, frames)
    simulated, as_run, dense_sensor = _simulate_places(scene, sensors, places, seed, say)
    say("timing the pipeline")
    ms, where = _time_pipeline(shuttle, dense_sensor, simulated, scene, repeats)
    result = {
        "bench": "perception",
        "frames": frames,
        "repeats": repeats,
        **_pipeline_figures(ms, where),
        **_raycast_figures(single_threaded, as_run),
        "method": METHOD,
        "cpus": os.cpu_count(),
        "load_avg_1m": [round(load_before[0], 2), round(os.getloadavg()[0], 2)],
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "open3d": open3d.__version__,
    }
    return judge(result, GOALS)


def format_perception_result(result: dict, out: TextIO) -> None:
    met = {key: "ok" if ok else "MISSED" for key, ok in result["goals_met"].items()}
    out.write(
        f"perception bench: {result['frames']} places along the built-in tour x {result['repeats']} repeats, "
        f"{result['cpus']} CPUs, load {result['load_avg_1m'][0]} -> {result['load_avg_1m'][1]} "
        f"(numpy {result['numpy']}, scipy {result['scipy']}, open3d {result['open3d']})\n"
    )
    out.write(f"  stack frame (3 LiDARs, {result['frame_points_p50']} points)     medians, ms\n")
    for key in ("transform", "filters", "pipeline_ground", "grid", "road"):
        out.write(f"    {key.replace('pipeline_', ''):28} {result[key + '_ms_p50']:8.2f}\n")
    out.write(
        f"    {'whole LidarPipeline.process':28} {result['pipeline_ms_p50']:8.2f}   "
        f"(max {result['pipeline_ms_max']:.1f}; its thread's CPU {result['pipeline_cpu_ms_p50']:.1f}, "
        f"max {result['pipeline_cpu_ms_max']:.1f}: the figure a loaded machine does not inflate)\n"
    )
    out.write(f"  dense 64-layer scan ({result['ground_scan_points_p50']} points)\n")
    out.write(
        f"    {'heightmap.ground_mask':28} {result['ground_ms_p50']:8.2f}   "
        f"[goal <= {GOALS['ground_ms_p50'].limit:g}: {met['ground_ms_p50']}]\n"
    )
    stages = ", ".join(f"{k} {v:.1f}" for k, v in result["scan_stage_ms_p50"].items())
    out.write(f"    {'whole pipeline, 1 sensor':28} {result['scan_pipeline_ms_p50']:8.2f}   ({stages})\n")
    out.write("  ray casting, 3 sensors, 1 frame\n")
    share = result["raycast_core_share_at_10hz"]
    out.write(
        f"    {'single-threaded':28} {result['raycast_ms_p50']:8.2f}   = {share:.2f} "
        f"of a core at 10 Hz [goal <= {GOALS['raycast_core_share_at_10hz'].limit:g}: "
        f"{met['raycast_core_share_at_10hz']}]; "
        f"{result['raycast_cast_rays_ms_p50']:.1f} of it in open3d's cast_rays; "
        f"CPU {result['raycast_cpu_ms_p50']:.1f} ms\n"
    )
    out.write(
        f"    {'as the simulator runs it':28} {result['raycast_as_run_ms_p50']:8.2f}   "
        f"(CPU {result['raycast_as_run_cpu_ms_p50']:.1f} ms; {result['raycast_as_run_cast_rays_ms_p50']:.1f} "
        f"in cast_rays)\n"
    )
    for place in result["places"]:
        out.write(
            f"  s = {place['s_m']:7.1f} m  {'/'.join(place['verges']):20} "
            f"frame {place['frame_points']:6d} points {place['pipeline_ms_p50']:5.1f} ms "
            f"(filters {place['filters_ms_p50']:4.1f}), "
            f"road {'found' if place['road_found'] else 'NOT found'}; dense scan {place['scan_points']:6d}, "
            f"road {'found' if place['scan_road_found'] else 'NOT found'}\n"
        )


if __name__ == "__main__":  # the child of _single_threaded_raycast: FRAMES SEED
    print(json.dumps(raycast_times(int(sys.argv[1]), int(sys.argv[2]), threads=1)))
