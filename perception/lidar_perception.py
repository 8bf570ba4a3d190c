"""One frame of the three LiDARs through perception (ARES §3.4–3.5), in order:

    each sensor's points → vehicle frame (its extrinsics)
    → merged → self-hit filter (the shape of the vehicle) → near-field ghost filter
    → heightmap ground removal (Algorithm 2) → local occupancy grid (ray traced)
    → road detection per ring (eqs. 7–10, Algorithm 1, two-step least squares)

The same pipeline serves the perception process, `ares perception scan FILE` and
`ares bench perception`; it keeps the last road model (eq. 10 measures against it, and its
centre line guides the next frame's scan).

Where a frame finds no road (a grass verge hides an edge now and then), the next frames are
guided by the last road found, moved by what the vehicle has driven since (the measured speed and
steering the caller passes; the paper's "taking into account the displacement"), for
`lost_guide_m` of travel. Without it they start again from the near field, which does not find a
tight bend: standing in the promenade's 12 m bend, 8 of 9 frames found nothing and the ninth a
road 48° wrong, while guided by the road seen 3.5 m back all 9 found it, within 8 cm from 4 m
ahead (guided by the one seen 8 m back, a road 0.95 m off: docs/road_detection.md). Without a
measured motion the lost road cannot be moved, and the next frame starts from the near field as
before.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from ares.core.config import LidarMount, Params, VehicleProfile, param
from ares.core.geometry import arc_step
from perception.cloud_filters import BodyBox, CloudFilterParams, ghost_mask, self_hit_mask
from perception.extrinsics import apply, pose_matrix
from perception.heightmap import floor_ground_mask, ground_mask
from perception.occupancy import OccupancyMapper, OccupancyParams
from perception.road_detection import LidarFrame, RoadDetectionParams, RoadModel, RoadResult, detect_road

RINGS_PER_SENSOR = 64  # ring ids are sensor index × 64 + laser: unique across the sensors
GUIDE_FROM_M = 4.0  # a lost road is moved from where its fit had points (from ~4 m ahead), not the
# stretch before them, which the fit extrapolates (metres off before a tight bend)


class GroundParams(Params):
    """Heightmap ground removal (Algorithm 2 and where it departs from it: perception/heightmap.py)."""

    method: Literal["floor", "cell_span"] = param(
        "floor",
        "floor: a point near its cell's lowest, which is near the floor around it, is ground "
        "(agrees with Patchwork++ on real scans: docs/performance.md); cell_span: Algorithm 2 as "
        "published, a cell spanning less than threshold_m is ground, within the occupancy grid only",
    )
    threshold_m: float = param(
        0.15,
        "Algorithm 2's Th: a point less than this above its cell's lowest return is ground "
        "(cell_span: a cell spanning less than this)",
        unit="m",
        gt=0,
    )
    extent_m: float = param(
        100.0,
        "floor: the heightmap is this wide, square around the occupancy grid's centre (it labels the "
        "scan, not only the grid; a point beyond it is not ground)",
        unit="m",
        gt=0,
    )
    floor_window_m: float = param(
        0.4, "floor: the near floor is the lowest return of the cells this close (square window)", unit="m", ge=0
    )
    near_extent_m: float = param(
        30.0,
        "floor: the near floor is kept on a square this wide around the grid's centre, where the "
        "occupancy grid reads the labels (beyond it the far floor and the plane judge alone)",
        unit="m",
        gt=0,
    )
    step_m: float = param(
        0.2,
        "floor: a point standing this much above the near floor is not ground (a 0.3 m box's top; "
        "a kerb's, a slope's stand lower); the occupancy grid's min_height_m",
        unit="m",
        gt=0,
    )
    block_m: float = param(1.0, "floor: cells are grouped in blocks this wide for the far floor", unit="m", gt=0)
    floor_rank: int = param(
        3,
        "floor: a block's floor is the lowest return of its n-th lowest cell, so a few stray returns "
        "below the road sink no floor (fewer cells with returns: no floor)",
        ge=1,
    )
    far_blocks: int = param(3, "floor: the far floor is the lowest block floor this many blocks around", ge=0)
    rise_m: float = param(
        0.5,
        "floor: a cell whose lowest return stands this much above the far floor is not ground "
        "(a car's roof, a wall whose foot was hidden; a road's grade rises less)",
        unit="m",
        gt=0,
    )
    plane_m: float = param(
        0.3,
        "floor: a cell whose lowest return lies this plus max_grade × its distance from the grid's "
        "centre above or below the plane the wheels stand on (z = 0) is not ground (a ledge, a "
        "canopy over road that the body hides from the sensors)",
        unit="m",
        gt=0,
    )
    max_grade: float = param(
        0.12, "floor: how steeply the ground may climb or fall away from the vehicle (plane_m)", ge=0
    )

    def mask(self, points: np.ndarray, grid: OccupancyParams) -> np.ndarray:
        """The ground points of an (N, ≥3) cloud in the vehicle frame; the heightmap is laid on the
        occupancy grid's cells, around its centre."""
        shifted = points - np.array([grid.centre_x_m, grid.centre_y_m, 0.0], dtype=np.float32)
        if self.method == "cell_span":
            return ground_mask(shifted, grid.width_m, grid.height_m, grid.cell_m, self.threshold_m)
        return floor_ground_mask(
            shifted,
            self.extent_m,
            grid.cell_m,
            self.threshold_m,
            self.floor_window_m,
            self.step_m,
            self.block_m,
            self.floor_rank,
            self.far_blocks,
            self.rise_m,
            self.max_grade,
            self.plane_m,
            self.near_extent_m,
        )


class LidarPipelineParams(Params):
    """Perception of the three LiDARs (ARES §3.4–3.5)."""

    rate_hz: float = param(10.0, "frames per second (the LiDARs' rate)", unit="Hz", gt=0)
    max_age_s: float = param(0.25, "a sensor's sweep older than this is missing from the frame", unit="s", gt=0)
    filters: CloudFilterParams = param(doc="self-hit and ghost filters (§3.5.1)", factory=CloudFilterParams)
    ground: GroundParams = param(
        doc="heightmap ground removal (Algorithm 2), on the grid's cells", factory=GroundParams
    )
    grid: OccupancyParams = param(doc="the local occupancy grid (§3.5.2)", factory=OccupancyParams)
    road: RoadDetectionParams = param(doc="road detection (§3.4.2)", factory=RoadDetectionParams)
    lost_guide_m: float = param(
        5.0,
        "after the road is lost, the last road found, moved by what "
        "was driven, guides the frames for this distance travelled "
        "(then, or without a measured motion, they start from the near "
        "field; 0: never)",
        unit="m",
        ge=0,
    )


@dataclass
class SensorSweep:
    """One sensor's sweep as it arrives: points in its own frame and their ring."""

    name: str
    points: np.ndarray  # (n, 3) float32, sensor frame
    ring: np.ndarray  # (n,) laser index, 0 = lowest


@dataclass
class FrameResult:
    points: np.ndarray  # (N, 3) the merged cloud, vehicle frame, after the filters
    sensor_index: np.ndarray  # (N,) which sensor each point came from
    ground: np.ndarray  # (N,) the heightmap's ground mask
    grid: np.ndarray  # (rows, cols) 0 free, 100 occupied, 255 unknown
    road: RoadResult
    raw_points: dict[str, int]  # per sensor, before the filters
    road_points: dict[str, int]  # per sensor, points scored as road
    removed: dict[str, int]  # self hits and ghosts
    stage_ms: dict[str, float] = field(default_factory=dict)


class LidarPipeline:
    def __init__(
        self,
        vehicle: VehicleProfile,
        params: LidarPipelineParams | None = None,
        mounts: dict[str, LidarMount] | None = None,
    ):
        self.params = params or LidarPipelineParams()
        self.mounts = dict(mounts if mounts is not None else vehicle.lidars)
        self.names = list(self.mounts)
        self.extrinsics = {
            n: pose_matrix(*m.xyz_m, *(math.radians(a) for a in m.rpy_deg)) for n, m in self.mounts.items()
        }
        self.origins = np.array([m.xyz_m for m in self.mounts.values()], dtype=np.float64).reshape(-1, 3)
        self.min_range = np.array([m.datasheet().min_range_m for m in self.mounts.values()], dtype=np.float32)
        self.body = BodyBox.of(vehicle, vehicle.height_m or self.params.filters.self_hit.body_height_m)
        self.mapper = OccupancyMapper(self.params.grid, self.origins)
        self.previous: RoadModel | None = None  # the last frame's road model (None: it found none)
        self.last_found: RoadModel | None = None
        self.since_found: tuple[float, float, float, float] | None = None  # x, y, yaw, travelled in its frame

    def road_frame(self, sweeps: list[SensorSweep], lap=None) -> tuple[LidarFrame, dict[str, int], dict[str, int]]:
        """The sweeps in the vehicle frame, merged, self hits and ghosts filtered: the frame road
        detection reads (also what `ares calibrate road` caches). Also the raw point counts per
        sensor and the counts removed. lap(stage), if given, is called after each stage."""
        p = self.params
        parts, index, rings, azimuths = [], [], [], []
        raw = {s.name: len(s.points) for s in sweeps}
        for sweep in sweeps:
            k = self.names.index(sweep.name)
            pts = np.asarray(sweep.points, dtype=np.float32)
            parts.append(apply(self.extrinsics[sweep.name], pts))
            index.append(np.full(len(pts), k, dtype=np.int16))
            rings.append(k * RINGS_PER_SENSOR + np.asarray(sweep.ring, dtype=np.int32))
            azimuths.append(np.arctan2(pts[:, 1], pts[:, 0]))
        points = np.concatenate(parts) if parts else np.zeros((0, 3), np.float32)
        sensor_index = np.concatenate(index) if index else np.zeros(0, np.int16)
        ring_id = np.concatenate(rings) if rings else np.zeros(0, np.int32)
        azimuth = np.concatenate(azimuths) if azimuths else np.zeros(0, np.float32)
        if lap:
            lap("transform")

        keep = ~self_hit_mask(points, self.body, p.filters.self_hit.margin_m)
        removed = {"self_hits": int(len(keep) - keep.sum())}
        index = np.flatnonzero(keep)
        ghost = p.filters.ghost
        ghosts = ghost_mask(
            np.take(points, index, axis=0),  # take: 4x faster than points[index] on (N, 3)
            sensor_index[index],
            self.origins,
            self.body,
            ghost.near_field_m,
            ghost.radius_m,
            ghost.min_neighbours,
            np.maximum(self.min_range, ghost.min_range_m),
        )
        keep[index[ghosts]] = False  # ghosts are judged once the self hits are gone (keep_mask)
        removed["ghosts"] = int(ghosts.sum())
        index = np.flatnonzero(keep)
        frame = LidarFrame(
            np.take(points, index, axis=0),
            ring_id[index],
            azimuth[index],
            sensor_index[index].astype(np.int64),
            self.origins,
        )
        if lap:
            lap("filters")
        return frame, raw, removed

    def process(self, sweeps: list[SensorSweep], travel: tuple[float, float] | None = None) -> FrameResult:
        """One frame; `travel`: the distance (m, signed) and curvature (1/m) the vehicle drove since
        the previous frame, None where not measured."""
        p = self.params
        ms: dict[str, float] = {}
        clock = time.perf_counter()
        cpu = time.thread_time()  # beside the wall time: on a busy machine the two part

        def lap(stage: str) -> None:
            nonlocal clock
            now = time.perf_counter()
            ms[stage] = round((now - clock) * 1e3, 3)
            clock = now

        frame, raw, removed = self.road_frame(sweeps, lap)
        points, sensor_index = frame.points, frame.sensor_index

        g = p.grid
        ground = p.ground.mask(points, g)
        lap("ground")

        cells = self.mapper.cells(points, ground, sensor_index)
        lap("grid")

        road = detect_road(frame, p.road, self.guide(travel))
        self.remember(road)
        lap("road")
        ms["total"] = round(sum(ms.values()), 3)
        ms["cpu"] = round((time.thread_time() - cpu) * 1e3, 3)
        road_points = {
            name: int(road.road_points_per_sensor[k]) if k < len(road.road_points_per_sensor) else 0
            for k, name in enumerate(self.names)
        }
        return FrameResult(points, sensor_index.astype(np.int16), ground, cells, road, raw, road_points, removed, ms)

    def guide(self, travel: tuple[float, float] | None) -> RoadModel | None:
        """The model guiding this frame: the last frame's, or after a loss the last road found,
        moved to where the vehicle now is. Once per frame: `travel` is what was driven since the
        last one."""
        if self.since_found is not None:
            if travel is None:
                self.since_found = None  # the lost road can no longer be placed
            else:
                x, y, yaw, travelled = self.since_found
                ds, kappa = travel
                self.since_found = (*arc_step(x, y, yaw, ds, kappa), travelled + abs(ds))
        if self.previous is None and self.since_found is not None and self.since_found[3] < self.params.lost_guide_m:
            x, y, yaw, _ = self.since_found
            return self.last_found.seen_from(x, y, yaw, (GUIDE_FROM_M, self.params.road.fit_x_max_m))
        return self.previous

    def remember(self, road: RoadResult) -> None:
        if road.found:
            self.previous = self.last_found = road.model
            self.since_found = (0.0, 0.0, 0.0, 0.0)
        else:
            self.previous = None
