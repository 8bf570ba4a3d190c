"""Point-cloud filters applied before ground removal (ARES paper §3.5.1).

Self hits: the lower rings of the roof LiDAR hit the roof and the corner LiDARs hit the body and
each other. "A filter with the shape of the platform" drops every point inside the body's box,
grown by a margin for the sensors' range noise and whatever sticks out of the box.

Ghosts: interference, fog or a sensor's systematic errors put false points in the air in front
of a sensor, where the obstacle manager would stop the shuttle for them. They are isolated;
real near obstacles (a pedestrian 1.5 m from the bumper) return dense patches. The rule:

    a point inside the near field (the body's box grown by `near_field_m` on every side, below
    too: a road going down ahead lies under the wheels' plane) is a ghost unless at least
    `min_neighbours` other points lie within `radius_m` of it (3-D); any point closer to its
    own sensor than `min_range_m` is a ghost too (below its minimum range a LiDAR's return is
    its window's dirt or its own echo, not a measurement).

Neighbours are counted among all the points kept so far, also those just outside the near field
(within `radius_m` of it), so a real point at its edge is not judged on half its neighbourhood.
Points outside the near field are never ghosts: far away a lone return is often a real thin
thing (a pole, a wire) and the occupancy grid's cells are far coarser than the ghost problem.

Counting the neighbours of every near-field point with a k-d tree costs 5-20 ms a frame (the tree
over 40,000-140,000 points of the near field, built every frame), so the points are settled in
three steps, each exact:

1. Voxels of side radius_m/√3, a hair less: two points in one voxel are within radius_m of each
   other, so a point sharing its voxel with `min_neighbours` others is no ghost. That settles
   85-90 % of them, the dense patches of road.
2. The points next to it in the cloud's order: a LiDAR's cloud comes ring by ring in firing
   order (the simulator's, a driver's, KITTI's), so a point's neighbours along its ring are next
   to it in the array. A point with `min_neighbours` of the `min_neighbours` on each side of it
   within radius_m (computed a hair short, so that none is counted that the tree would not count)
   is no ghost. That leaves 1-5 % of the rest, whatever the order was (a shuffled cloud just
   leaves more).
3. The few left get the exact count from a cKDTree of only the points that can be within
   radius_m of one of them: those within two voxels of theirs along each axis (radius_m is 1.73
   voxels).
The result is the rule above, exactly.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from ares.core.config import Params, VehicleProfile, param


class BodyBox(NamedTuple):
    """The vehicle's shape as an axis-aligned box in the vehicle frame, metres."""

    x_min: float
    x_max: float
    y_min: float
    y_max: float
    z_min: float
    z_max: float

    @classmethod
    def of(cls, profile: VehicleProfile, height_m: float) -> BodyBox:
        """The body around the rear-axle centre: the overhangs are equal, (length - wheelbase)/2."""
        rear = (profile.length_m - profile.wheelbase_m) / 2.0
        half_width = profile.width_m / 2.0
        return cls(-rear, profile.length_m - rear, -half_width, half_width, 0.0, height_m)

    def grown(self, margin_m: float) -> BodyBox:
        m = margin_m
        return BodyBox(self.x_min - m, self.x_max + m, self.y_min - m, self.y_max + m, self.z_min - m, self.z_max + m)

    def contains(self, points: np.ndarray) -> np.ndarray:
        x, y, z = points[:, 0], points[:, 1], points[:, 2]
        return (
            (x >= self.x_min)
            & (x <= self.x_max)
            & (y >= self.y_min)
            & (y <= self.y_max)
            & (z >= self.z_min)
            & (z <= self.z_max)
        )


class SelfHitParams(Params):
    body_height_m: float = param(2.6, "top of the body's box (the roof; the roof LiDAR sits above it)", unit="m", gt=0)
    margin_m: float = param(
        0.15,
        "the box is grown by this on every side but the road's: range noise, mirrors, the corner sensors' housings",
        unit="m",
        ge=0,
    )


class GhostParams(Params):
    near_field_m: float = param(4.0, "points this close to the body's box (on any side) are checked", unit="m", ge=0)
    radius_m: float = param(
        0.15,
        "neighbours are counted within this distance (0.3 let a ghost 0.2-0.3 m above a "
        "dense patch of road count the road as its neighbours, and the obstacle manager "
        "stopped for it in half the frames)",
        unit="m",
        gt=0,
    )
    min_neighbours: int = param(3, "a near-field point with fewer neighbours than this is a ghost", ge=1)
    min_range_m: float = param(0.5, "returns closer to their own sensor than this are dropped", unit="m", ge=0)


class CloudFilterParams(Params):
    """The filters of ARES §3.5.1, run on the merged cloud in the vehicle frame."""

    self_hit: SelfHitParams = param(doc="the filter with the shape of the platform", factory=SelfHitParams)
    ghost: GhostParams = param(doc="the near-field filter of isolated false points", factory=GhostParams)


def self_hit_mask(points: np.ndarray, body: BodyBox, margin_m: float) -> np.ndarray:
    """True for the points of an (N, ≥3) vehicle-frame cloud that hit the vehicle itself. The
    box is grown on every side but the road's: below the body there is only road."""
    hits = np.zeros(len(points), dtype=bool)
    hits[_inside(points, body.grown(margin_m)._replace(z_min=body.z_min))] = True
    return hits


def ghost_mask(
    points: np.ndarray,
    sensor_index: np.ndarray,
    sensor_origins: np.ndarray,
    body: BodyBox,
    near_field_m: float = 4.0,
    radius_m: float = 0.3,
    min_neighbours: int = 3,
    min_range_m: float | np.ndarray = 0.5,
) -> np.ndarray:
    """True for the ghost points of an (N, ≥3) vehicle-frame cloud (the rule in the module's
    docstring); sensor_index[i] is the row of sensor_origins (S × 3) that point i came from;
    min_range_m is one for all sensors or one per sensor (their datasheets differ)."""
    xyz = np.asarray(points)[:, :3]
    origins = np.asarray(sensor_origins, dtype=np.float32)
    squared = np.zeros(len(xyz), dtype=np.float32)
    for axis in range(3):  # column by column: no (N, 3) temporaries
        d = xyz[:, axis] - np.take(origins[:, axis], sensor_index)
        squared += d * d
    limit = np.broadcast_to(np.asarray(min_range_m, dtype=np.float32), (len(origins),))
    ghost = squared < np.take(limit * limit, sensor_index)
    pool = _inside(xyz, body.grown(near_field_m + radius_m))
    pool = pool[~ghost[pool]]
    near = np.take(xyz, pool, axis=0)  # take: 4x faster than xyz[pool] on (N, 3)
    judged = body.grown(near_field_m).contains(near)
    if judged.any():
        isolated = _isolated(
            near.astype(np.float64), judged, body.grown(near_field_m + radius_m), radius_m, min_neighbours
        )
        ghost[pool[isolated]] = True
    return ghost


def _inside(points: np.ndarray, box: BodyBox) -> np.ndarray:
    """Indices of the points in the box (BodyBox.contains), x tested first on all, y and z only on
    the few that pass: most of a cloud lies far ahead or behind."""
    x = points[:, 0]
    index = np.flatnonzero((x >= box.x_min) & (x <= box.x_max))
    y, z = points[index, 1], points[index, 2]
    return index[(y >= box.y_min) & (y <= box.y_max) & (z >= box.z_min) & (z <= box.z_max)]


def _isolated(pool: np.ndarray, judged: np.ndarray, box: BodyBox, radius_m: float, k: int) -> np.ndarray:
    """Which of the `judged` pool points have fewer than k others within radius_m in the pool
    (the three steps of the module's docstring)."""
    side = radius_m / math.sqrt(3.0) * (1.0 - 1e-9)  # under rounding too, a voxel's diagonal < r
    # one spare voxel on each side: a point the float32 box test let in by a rounding error
    # still gets a voxel of its own (clipping it into the edge voxel could bring a mate > r away)
    lower = np.array([box.x_min, box.y_min, box.z_min]) - side
    dims = np.floor((np.array([box.x_max, box.y_max, box.z_max]) - lower) / side).astype(np.int64) + 2
    ijk = np.floor((pool - lower) / side).astype(np.int64)
    voxel = (ijk[:, 0] * dims[1] + ijk[:, 1]) * dims[2] + ijk[:, 2]
    sharing = np.bincount(voxel, minlength=int(dims.prod()))[voxel]
    candidates = np.flatnonzero(judged & (sharing <= k))
    candidates = candidates[_order_neighbours(pool, candidates, radius_m, k) < k]
    isolated = np.zeros(len(pool), dtype=bool)
    if len(candidates):
        # only the pool points within 2 voxels (r < 2 sides) of a candidate's along each axis can be its neighbours
        step = np.arange(-2, 3)
        around = ((step[:, None, None] * dims[1] + step[None, :, None]) * dims[2] + step).ravel()
        near = np.zeros(int(dims.prod()) + 2 * around[-1] + 1, dtype=bool)  # room past both ends for the offsets
        near[(voxel[candidates, None] + around).ravel() + around[-1]] = True
        mates = np.flatnonzero(near[voxel + around[-1]])
        # k + 1 nearest (the candidate itself among them) up to just past r: "within" includes r
        tree = cKDTree(pool[mates], balanced_tree=False, compact_nodes=False)  # built 2x faster, same answers
        distances, _ = tree.query(pool[candidates], k=k + 1, distance_upper_bound=np.nextafter(radius_m, np.inf))
        isolated[candidates] = ~np.isfinite(distances[:, k])
    return isolated


def _order_neighbours(pool: np.ndarray, candidates: np.ndarray, radius_m: float, k: int) -> np.ndarray:
    """How many of the k points before and the k after each candidate in the pool's order lie
    within radius_m of it; a hair short of radius_m, so never more than the tree would count."""
    within = radius_m * radius_m * (1.0 - 1e-9)
    count = np.zeros(len(candidates), dtype=np.int64)
    centre = pool[candidates]
    last = len(pool) - 1
    for offset in (*range(-k, 0), *range(1, k + 1)):
        other = candidates + offset
        squared = np.zeros(len(candidates))
        for axis in range(3):
            d = pool[np.clip(other, 0, last), axis] - centre[:, axis]
            squared += d * d
        count += (squared <= within) & (other >= 0) & (other <= last)
    return count


def keep_mask(
    points: np.ndarray, sensor_index: np.ndarray, sensor_origins: np.ndarray, body: BodyBox, params: CloudFilterParams
) -> np.ndarray:
    """True for the points that survive both filters. Ghosts are judged after the self hits are
    gone, so that the dense patch of a bumper does not vouch for a ghost beside it."""
    keep = ~self_hit_mask(points, body, params.self_hit.margin_m)
    index = np.flatnonzero(keep)
    g = params.ghost
    ghost = ghost_mask(
        points[index],
        sensor_index[index],
        sensor_origins,
        body,
        g.near_field_m,
        g.radius_m,
        g.min_neighbours,
        g.min_range_m,
    )
    keep[index[ghost]] = False
    return keep
