"""`ares bench obstacle-zone`: false stops of the obstacle manager's trapezoid beside those of a
rectangle of the same length, in the built-in tour's narrow lane between rock walls (s 60-200 m,
3.2 m wide, a 30 m bend in it), where nothing stands in the way.

Every `step_m` along the lane the three simulated LiDARs of the ARES shuttle (full resolution) cast
one frame from the vehicle on the lane's centre line with its wheels at the path's curvature there,
and LidarPipeline.process makes the occupancy grid. Both areas are sized for `speed_mps`: the
trapezoid narrows from half the body + near_margin_m at the bumper to half the body +
far_margin_m at its end; the rectangle keeps the near width all along. Each is laid two ways, as
the obstacle manager may: along the path ahead (`path`: while localization is trusted) and along
the arc of the wheels' curvature (`arc`: otherwise). A frame whose verdict is `slow` or `stop` is a
false one (there is no obstacle in the lane).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np


def run_obstacle_zone_bench(
    step_m: float = 2.0, speed_mps: float = 4.0, progress: Callable[[str], None] = lambda _m: None
) -> dict:
    from ares.core.config import load_vehicle
    from ares.tools.bench.perception import TourScene
    from managers.obstacle import ObstacleParams, judge, occupied_cells, zone_for
    from perception.lidar_perception import LidarPipeline, SensorSweep
    from simulator.lidar import LidarSimParams, SimulatedLidar

    vehicle = load_vehicle("ares_shuttle")
    scene = TourScene(vehicle.wheelbase_m)
    route = scene.route
    stretches = [(z.s_start, z.s_end) for z in route.zones if z.kind == "narrow"]
    params = ObstacleParams()
    bumper = vehicle.front_bumper_m
    pipeline = LidarPipeline(vehicle)
    sensors = {
        name: SimulatedLidar(name, mount, vehicle, LidarSimParams(), np.random.default_rng([7, k]))
        for k, (name, mount) in enumerate(sorted(vehicle.lidars.items()))
    }
    shapes = {"trapezoid": params.far_margin_m, "rectangle": params.near_margin_m}
    layouts = ("path", "arc")
    counts = {(shape, layout): {"clear": 0, "ready": 0, "slow": 0, "stop": 0} for shape in shapes for layout in layouts}
    frames = 0
    for start, end in stretches:
        places = np.arange(start, end, step_m)
        for i, s in enumerate(places):
            sweeps = [
                SensorSweep(name, np.stack([sw.x, sw.y, sw.z], axis=1).astype(np.float32), sw.ring)
                for name, sw in ((name, scene.sweep(sensor, float(s))) for name, sensor in sensors.items())
            ]
            result = pipeline.process(sweeps)
            grid = pipeline.mapper.grid
            ox, oy = occupied_cells(result.grid, grid.origin_x, grid.origin_y, grid.cell_m)
            kappa = float(route.curvature[route.index_at(float(s))])
            centre = path_ahead(route, float(s), bumper + params.headway_s * speed_mps + 5.0)
            for (shape, layout), bands in counts.items():
                zone = zone_for(
                    params,
                    speed_mps,
                    kappa,
                    vehicle.width_m,
                    bumper,
                    far_margin_m=shapes[shape],
                    centre=centre if layout == "path" else None,
                )
                bands[judge(params, zone, ox, oy, speed_mps).band] += 1
            frames += 1
            if i % 10 == 0:
                progress(f"s {s:.0f} m: {frames} frames")
    out: dict = {
        "frames": frames,
        "speed_mps": speed_mps,
        "area_length_m": max(params.min_length_m, params.headway_s * speed_mps),
        "stretches_m": [[round(a, 1), round(b, 1)] for a, b in stretches],
    }
    for (shape, layout), bands in counts.items():
        name = shape if layout == "path" else f"{shape}_{layout}"
        out[f"{name}_false_stops"] = bands["stop"]
        out[f"{name}_false_slows"] = bands["slow"]
        out[f"{name}_bands"] = bands
    return out


def path_ahead(route, s: float, reach_m: float, step_m: float = 0.5) -> np.ndarray:
    """The route's centre line from 1 m behind s to reach_m ahead, in the frame of a vehicle whose
    rear axle stands on it at s facing along it (as the path manager's path ahead, turned into the
    vehicle's frame by the obstacle manager)."""
    x0, y0, _, yaw0 = route.point_at(s)
    c, si = np.cos(yaw0), np.sin(yaw0)
    points = [route.point_at(s + d)[:2] for d in np.arange(-1.0, reach_m, step_m)]
    return np.array([((x - x0) * c + (y - y0) * si, -(x - x0) * si + (y - y0) * c) for x, y in points])
