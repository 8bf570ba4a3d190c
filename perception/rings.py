"""The ring (laser) of each point of a spinning LiDAR's scan whose file does not say it (KITTI's
.bin has x, y, z and intensity only). Road detection walks each ring on its own, so two
lasers mixed under one ring id interleave points metres apart in range, and the ring is lost.

Two ways, tried in this order (`recover_rings`):

1. The point order. KITTI stores a revolution laser by laser: all of one laser's points in
   azimuth order, then the next laser's, each revolution cut facing forward (azimuth 0, where
   the cameras look). So a new ring starts where the azimuth, taken in the direction of the
   spin, falls back across that cut (from nearly a full turn to nearly nothing). This is exact
   whatever the lasers' calibration, but for the few points of a laser that lie past the cut
   (each laser has its own azimuth correction), which go to the ring next to it.
   It is accepted only if it looks like that order: between half and all of the lasers as
   segments, and the segments' median elevations stepping one way (the lasers one after the
   other, top to bottom in KITTI). Ring ids are the segments ranked by median elevation,
   0 the lowest. Files in firing order (all lasers at one azimuth, then the next: a driver's
   organised cloud), shuffled or voxel-filtered clouds fail the check.
2. The elevation, atan2(z, hypot(x, y)), binned to the nearest laser of the datasheet
   (config.LIDAR_MODELS). Works in any order, but only as well as the datasheet matches the
   sensor: each HDL-64E laser has its own calibrated angle and a vertical offset on the head
   (Velodyne's per-laser corrections, of the order of a decimetre or two), so seen from one
   origin a real scan's elevations drift with range by ~offset/range (half a degree to a
   degree at 10 m: two or three upper-block ring spacings) and near rings get mixed. Exact
   for the simulator's sensors, which fire from one point at the datasheet's angles.

A scan whose file carries a ring field (a driver's .pcd or .ply) needs neither.
"""

from __future__ import annotations

import math

import numpy as np

from ares.core.config import LidarModel

MONOTONIC_SHARE = 0.9  # of the steps between adjacent segments' median elevations
MIN_RUN = 8  # fewer points after a cut join the segment before: jitter, not a laser


def elevation(points: np.ndarray) -> np.ndarray:
    """Elevation of each point seen from the sensor's origin, radians."""
    x, y, z = (points[:, i].astype(np.float64) for i in range(3))
    return np.arctan2(z, np.hypot(x, y))


def rings_from_elevation(points: np.ndarray, model: LidarModel) -> np.ndarray:
    """Index of the datasheet laser nearest in elevation to each point (0 the lowest)."""
    lasers = np.radians(model.elevations_deg())
    between = (lasers[1:] + lasers[:-1]) / 2
    return np.searchsorted(between, elevation(points)).astype(np.int64)


def rings_from_order(points: np.ndarray, lasers: int) -> np.ndarray | None:
    """Ring ids from a ring-by-ring point order cut facing forward (KITTI's), or None when the
    order does not look like that (see the module's docstring)."""
    if len(points) < 2 * lasers:
        return None
    azimuth = np.arctan2(points[:, 1].astype(np.float64), points[:, 0].astype(np.float64))
    step = np.diff(azimuth)
    step = (step + math.pi) % (2 * math.pi) - math.pi  # wrapped to [−π, π)
    spin = np.sign(np.median(step))
    if spin == 0:
        return None
    turned = (spin * azimuth) % (2 * math.pi)  # how far round from the forward cut
    cuts = np.flatnonzero(np.diff(turned) < -math.pi) + 1
    cuts = cuts[np.diff(np.r_[cuts, len(points)]) >= MIN_RUN]  # a few points jittering across the cut
    count = len(cuts) + 1
    if not lasers // 2 <= count <= lasers:
        return None
    segment = np.zeros(len(points), dtype=np.int64)
    segment[cuts] = 1
    segment = np.cumsum(segment)  # segments are runs of the file's order
    medians = np.array([np.median(run) for run in np.split(elevation(points), cuts)])
    steps = np.diff(medians)
    if max((steps > 0).mean(), (steps < 0).mean()) < MONOTONIC_SHARE:
        return None
    rank = np.empty(count, dtype=np.int64)
    rank[np.argsort(medians, kind="stable")] = np.arange(count)
    return rank[segment]


def recover_rings(points: np.ndarray, model: LidarModel) -> tuple[np.ndarray, str]:
    """(ring of each point, "order" or "elevation": how it was found)."""
    lasers = len(model.elevations_deg())
    ring = rings_from_order(points, lasers)
    if ring is not None:
        return ring, "order"
    return rings_from_elevation(points, model), "elevation"
