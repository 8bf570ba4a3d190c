"""A realistic-size LiDAR frame for tests and timings: the shuttle's three LiDARs (a 64-ring
roof sensor, two 16-ring front-corner sensors) cast against a flat road between two buildings,
a car ahead, a pedestrian by the front bumper, a tree and the shuttle's own body. About 190,000
returns, 120,000 of them on the road, merged in the vehicle frame.

Boxes are (x_min, x_max, y_min, y_max, z_min, z_max). A ray hits the road (z = 0) or the first
box it enters from outside; rays that hit nothing within range give no return.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from perception.extrinsics import apply, pose_matrix

# sensor -> vehicle: the roof sensor, then the corner ones turned 45° out and tilted 15° down
MOUNTS = (
    pose_matrix(3.0, 0.0, 2.94, 0.0, 0.0, 0.0),
    pose_matrix(3.3, 0.95, 0.9, 0.0, math.radians(15), math.radians(45)),
    pose_matrix(3.3, -0.95, 0.9, 0.0, math.radians(15), math.radians(-45)),
)
ORIGINS = np.array([m[:3, 3] for m in MOUNTS])
BODY = (-0.565, 3.365, -0.995, 0.995, 0.0, 2.6)
# what the rays hit of the body: its front face just behind the corner sensors, which stick out,
# and a roof that slopes away from the roof sensor (a flat roof 0.34 m below it takes 29,000 of
# its 135,000 rays, this one 7,000)
BODY_HIT = (-0.565, 3.15, -0.90, 0.90, 0.0, 2.1)
SCENE = (
    (-60.0, 60.0, 30.0, 33.0, 0.0, 12.0),  # buildings on both sides
    (-60.0, 60.0, -33.0, -30.0, 0.0, 12.0),
    (60.0, 63.0, -33.0, 33.0, 0.0, 12.0),  # and across the street, far ahead and behind
    (-63.0, -60.0, -33.0, 33.0, 0.0, 12.0),
    (12.0, 16.5, -1.0, 0.9, 0.0, 1.5),  # a car ahead
    (5.0, 5.4, 1.8, 2.3, 0.0, 1.75),  # a pedestrian 1.6 m from the bumper
    (-3.0, -2.7, -5.2, -4.9, 0.0, 2.5),  # a tree: trunk,
    (-4.5, -1.2, -6.6, -3.5, 2.5, 5.0),  # crown
)


@dataclass
class Frame:
    points: np.ndarray  # (N, 3) float32, vehicle frame
    sensor: np.ndarray  # (N,) index into MOUNTS
    ground: np.ndarray  # (N,) True where the road was hit
    body: np.ndarray  # (N,) True where the shuttle itself was hit


def ray_pattern(elevations_deg: np.ndarray, azimuth_step_deg: float) -> np.ndarray:
    """Unit directions of a spinning sensor's rays, in its own frame."""
    el = np.radians(elevations_deg)[:, None]
    az = np.radians(np.arange(0.0, 360.0, azimuth_step_deg))[None, :]
    return np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el) + 0 * az], -1).reshape(-1, 3)


def box_entry(origin: np.ndarray, d: np.ndarray, box) -> np.ndarray:
    """Range at which each ray enters the box from outside (inf when it does not)."""
    lo, hi = np.array(box[0::2]), np.array(box[1::2])
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (lo - origin) / d, (hi - origin) / d
    near = np.nanmax(np.minimum(t1, t2), axis=1)
    far = np.nanmin(np.maximum(t1, t2), axis=1)
    return np.where((near <= far) & (near > 0), near, np.inf)


def cast(matrix: np.ndarray, directions: np.ndarray, max_range: float, rng):
    """(points in the vehicle frame, hit the road?, hit the body?) of one sensor's rays."""
    origin = matrix[:3, 3]
    d = directions @ matrix[:3, :3].T
    with np.errstate(divide="ignore"):
        road = np.where(d[:, 2] < 0, -origin[2] / d[:, 2], np.inf)
    hits = np.column_stack([road, box_entry(origin, d, BODY_HIT)] + [box_entry(origin, d, b) for b in SCENE])
    first = hits.argmin(axis=1)
    t = hits[np.arange(len(d)), first]
    seen = t < max_range
    t = t[seen] + rng.normal(0.0, 0.01, seen.sum())  # 1 cm range noise
    sensor_points = (directions[seen] * t[:, None]).astype(np.float32)
    return apply(matrix, sensor_points), first[seen] == 0, first[seen] == 1


def frame(seed: int = 0) -> Frame:
    rng = np.random.default_rng(seed)
    patterns = (ray_pattern(np.linspace(2.0, -24.9, 64), 0.17), ray_pattern(np.arange(-15.0, 16.0, 2.0), 0.2))
    parts = [cast(m, patterns[min(i, 1)], 100.0, rng) for i, m in enumerate(MOUNTS)]
    return Frame(
        np.concatenate([p[0] for p in parts]),
        np.concatenate([np.full(len(p[0]), i) for i, p in enumerate(parts)]),
        np.concatenate([p[1] for p in parts]),
        np.concatenate([p[2] for p in parts]),
    )
