"""Times of the LiDAR pipeline's steps on a realistic frame (tests/lidar_scene.py: ~190,000
returns, ~120,000 of them road), in this process. Measured and printed, never asserted:

    python -m tests.time_perception [repeats]
"""

from __future__ import annotations

import statistics
import sys
import time

import numpy as np

from perception.cloud_filters import BodyBox, CloudFilterParams, ghost_mask, keep_mask, self_hit_mask
from perception.extrinsics import apply, inverse
from perception.heightmap import ground_mask
from perception.occupancy import OccupancyMapper, OccupancyParams
from tests.helpers import lidar_scene


def timed(repeats: int, fn) -> tuple[float, float]:
    """(median, 90th percentile) in milliseconds."""
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append((time.perf_counter() - start) * 1e3)
    times.sort()
    return statistics.median(times), times[int(0.9 * (len(times) - 1))]


def main(repeats: int = 50) -> None:
    frame = lidar_scene.frame()
    body, origins, params = BodyBox(*lidar_scene.BODY), lidar_scene.ORIGINS, CloudFilterParams()
    roof = frame.sensor == 0
    roof_in_sensor_frame = apply(inverse(lidar_scene.MOUNTS[0]), frame.points[roof])
    keep = keep_mask(frame.points, frame.sensor, origins, body, params)
    kept, sensor = frame.points[keep], frame.sensor[keep]
    not_self = ~self_hit_mask(frame.points, body, params.self_hit.margin_m)
    centre = np.array([1.4, 0.0, 0.0], np.float32)  # the heightmap's grid around the body
    ground = ground_mask(kept - centre)
    setup_start = time.perf_counter()
    mapper = OccupancyMapper(OccupancyParams(), origins)
    setup_ms = (time.perf_counter() - setup_start) * 1e3
    print(
        f"frame: {len(frame.points)} returns ({frame.ground.sum()} road, {frame.body.sum()} on the body); "
        f"after the filters {len(kept)}; occupancy set-up {setup_ms:.0f} ms, "
        f"{len(mapper.tracer.pair_cell)} (bin, cell) pairs"
    )
    steps = {
        f"extrinsics.apply ({roof.sum()} roof points)": lambda: apply(lidar_scene.MOUNTS[0], roof_in_sensor_frame),
        "cloud_filters.self_hit_mask": lambda: self_hit_mask(frame.points, body, params.self_hit.margin_m),
        "cloud_filters.ghost_mask (after self hits)": lambda: ghost_mask(
            frame.points[not_self], frame.sensor[not_self], origins, body
        ),
        "cloud_filters.keep_mask (both)": lambda: keep_mask(frame.points, frame.sensor, origins, body, params),
        "heightmap.ground_mask": lambda: ground_mask(kept - centre),
        "occupancy OccupancyMapper.cells": lambda: mapper.cells(kept, ground, sensor),
        f"  the same, all {len(frame.points)} returns": lambda: mapper.cells(frame.points, frame.ground, frame.sensor),
        "  of which FreeSpaceTracer.free": lambda: mapper.tracer.free(
            kept[:, 0], kept[:, 1], sensor, np.ones(len(kept), bool), np.zeros(mapper.grid.size, bool)
        ),
    }
    for name, fn in steps.items():
        p50, p90 = timed(repeats, fn)
        print(f"{name:48s} p50 {p50:6.2f} ms   p90 {p90:6.2f} ms")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 50)
