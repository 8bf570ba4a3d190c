"""LiDAR perception as a process: the three sweeps in, the occupancy grid, the road and the
sensors' health out (perception/lidar_perception.py does the work).

A frame is the newest sweep of each sensor that is fresh (lidar.max_age_s); a sensor without one
is missing from the frame and reported with rate 0. Each frame carries the time of its sweeps
(the pose they were taken from), so its outputs line up with the vehicle's state at that time.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from ares.core.config import LIDAR_NAMES, param
from ares.core.messages import (
    EventLevel,
    LidarHealth,
    LidarStatus,
    OccupancyGrid,
    PointCloud,
    RoadBoundary,
    RoadDetection,
)
from ares.core.node import Input, InputGroup, Node, Output
from perception.lidar_perception import FrameResult, LidarPipeline, LidarPipelineParams, SensorSweep

RATE_WINDOW_S = 1.0
USUAL_FRAMES = 50  # a sensor's usual point count: the median of its last this many sweeps
BLIND_SHARE = 0.05  # fewer points than this share of the usual: the sensor is blind (covered)
TRAVEL_GAP_S = 0.35  # the speed measured now stands for the drive since the last frame only this long


def boundary(coefficients, x_min: float, x_max: float, points: int = 0) -> RoadBoundary | None:
    if coefficients is None:
        return None
    return RoadBoundary(coefficients=[float(c) for c in coefficients], x_min=x_min, x_max=x_max, points=points)


def road_message(t: float, result: FrameResult, x_range: tuple[float, float]) -> RoadDetection:
    road = result.road
    if not road.found:
        return RoadDetection(t=t, found=False, confidence=0.0)
    model = road.model
    lo, hi = x_range
    return RoadDetection(
        t=t,
        found=True,
        confidence=float(road.confidence),
        left=boundary(model.left, lo, hi, int(road.left_fit.inliers.sum()) if road.left_fit else 0),
        right=boundary(model.right, lo, hi, int(road.right_fit.inliers.sum()) if road.right_fit else 0),
        centre=boundary(model.centre(), lo, hi),
        lateral_offset_m=float(road.lateral_offset_m),
        heading_rad=float(road.heading_rad),
        width_m=float(road.width_m) if np.isfinite(road.width_m) else None,
    )


class LidarPerceptionParams(LidarPipelineParams):
    car_timeout_s: float = param(0.5, "an older speed measurement is not used to move a lost road", unit="s", gt=0)


class LidarPerception(Node):
    """Self-hit and ghost filters, heightmap ground removal, the occupancy grid and road detection
    on the three LiDARs (ARES §3.4–3.5)."""

    name = "lidar_perception"
    Params = LidarPerceptionParams
    replay_ignores = ("perception/lidar_status.stage_ms",)  # the pipeline's own wall and CPU times
    stamps_outputs_with = "data"  # the grid and the road carry their sweep's stamp
    sweeps = InputGroup(
        {name: f"lidar/{name}/points" for name in LIDAR_NAMES},
        max_age="max_age_s",
        doc="each LiDAR's sweep, sensor frame",
    )
    grid = Output("perception/grid", rate="rate_hz", doc="20 x 20 m at 0.2 m around the vehicle")
    car = Input(
        "dbw/car_state",
        max_age="car_timeout_s",
        doc="the measured speed and steering: a lost road is moved by them to guide the next frames",
    )
    road = Output("perception/road", rate="rate_hz")
    status = Output("perception/lidar_status", rate="rate_hz", doc="per LiDAR: rate, points, road points")

    def setup(self) -> None:
        self.pipeline = LidarPipeline(self.vehicle, self.params)
        self.last_t: float | None = None
        self.seen = {name: None for name in LIDAR_NAMES}
        self.first_seen: dict[str, float | None] = {name: None for name in LIDAR_NAMES}
        self.counts = {name: deque(maxlen=USUAL_FRAMES) for name in LIDAR_NAMES}
        self.blind: set[str] = set()

    def step(self, now: float) -> None:
        fresh: dict[str, PointCloud] = {}
        for name, sub in self.sweeps.items():
            msg = sub.fresh(now)
            if msg is None or name not in self.pipeline.mounts:
                continue
            fresh[name] = msg
            if self.seen[name] != msg.t:
                self.seen[name] = msg.t
                if self.first_seen[name] is None:
                    self.first_seen[name] = msg.t
        if not fresh:
            return
        t = max(msg.t for msg in fresh.values())
        if t == self.last_t:
            return  # nothing new since the last frame
        travel = self._travel(self.last_t, t, now)
        self.last_t = t
        frame = [SensorSweep(name, np.stack([m.x, m.y, m.z], axis=1), m.ring) for name, m in fresh.items() if m.t == t]
        result = self.pipeline.process(frame, travel)
        self._watch_counts(result.raw_points)
        g = self.pipeline.mapper.grid
        self.grid.put(
            OccupancyGrid(
                t=t, frame="vehicle", resolution_m=g.cell_m, origin_x=g.origin_x, origin_y=g.origin_y, cells=result.grid
            )
        )
        road_params = self.params.road
        self.road.put(road_message(t, result, (road_params.x_min_m, road_params.x_max_m)))
        self.status.put(self._status(t, now, result, travel))

    def _travel(self, since: float | None, t: float, now: float) -> tuple[float, float] | None:
        """Distance and curvature driven from the frame at `since` to this one at t (at the speed and
        steering measured now: frames are 0.1 s apart), None without a fresh measurement or across a
        gap in the frames."""
        car = self.car.fresh(now)
        if car is None or since is None or t - since > TRAVEL_GAP_S:
            return None
        return car.speed_mps * (t - since), self.vehicle.curvature_of(car.steering_wheel_deg)

    def _watch_counts(self, counts: dict[str, int]) -> None:
        """A covered sensor's count falls to about zero (ARES §3.7): say so once, and once more
        when it sees again."""
        for name, n in counts.items():
            usual = float(np.median(self.counts[name])) if len(self.counts[name]) >= 5 else None
            blind = usual is not None and n < BLIND_SHARE * usual
            if blind and name not in self.blind:
                self.blind.add(name)
                self.event(
                    "lidar_blind",
                    f"{name} LiDAR returned {n} points, usually {usual:.0f}: covered or failed",
                    EventLevel.WARNING,
                    sensor=name,
                    points=n,
                    usual=round(usual),
                )
            elif not blind and name in self.blind and usual is not None:
                self.blind.discard(name)
                self.event("lidar_sees", f"{name} LiDAR sees again ({n} points)", sensor=name, points=n)
            if not blind:
                self.counts[name].append(n)

    def _status(self, t: float, now: float, result: FrameResult, travel: tuple[float, float] | None) -> LidarStatus:
        sensors = {}
        sweeps = self.sweeps
        for name in self.pipeline.names:
            seen = self.seen[name]
            sensors[name] = LidarHealth(
                # every sweep that arrived counts, also one a later sweep replaced before a step used
                # it (it came late, behind the clock's tick): the sensor's rate, not this loop's
                rate_hz=sweeps[name].rate_hz(RATE_WINDOW_S, now),
                points=result.raw_points.get(name, 0),
                road_points=result.road_points.get(name, 0),
                age_s=None if seen is None else round(now - seen, 3),
                blind=name in self.blind,
                counting_s=None if self.first_seen[name] is None else round(now - self.first_seen[name], 3),
            )
        moved_m, moved_curvature = travel if travel is not None else (None, None)
        return LidarStatus(
            t=t, sensors=sensors, stage_ms=result.stage_ms, moved_m=moved_m, moved_curvature=moved_curvature
        )
