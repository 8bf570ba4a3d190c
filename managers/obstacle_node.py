"""Obstacle manager: a speed limit from what stands in the vehicle's way (ARES §3.5.3).

Each cycle it lays the search area (managers/obstacle.py) along the trajectory the shuttle
will drive: the path ahead (the path manager's, into the vehicle's frame by the fused pose) while
the control manager forwards a controller that follows it (odometry mode: MPC, pure pursuit) and
the pose's heading is sure; otherwise the arc the wheels are turned to (the CAN steering angle through the bridge's car
state). It is sized for the larger of the speed now and the speed manager's limit, and it looks
for occupied cells of the occupancy grid in it. Along the arc, where a lane's curvature changes
the arc meets the wall 7-10 m ahead (`ares bench obstacle-zone`); the path ahead bends with the lane.
The nearest one sets the limit (ready, slow in proportion, stop) that the movement manager applies;
the score and the area's outline go out for the black box and the pages. Without a fresh grid or
car state the area is unknown: the limit is 0.

One grid alone never slows the shuttle: the limit is the higher of the last two grids' (a tenth of
a second later for a real obstacle, which stays). The simulated LiDARs' clusters of false cells a
metre or two past the bumper last one frame: without this the shuttle braked for them every few
seconds.
"""

from __future__ import annotations

import math

import numpy as np

from ares.core.messages import (
    CarState,
    ControllerStatus,
    EventLevel,
    ObstacleState,
    OccupancyGrid,
    PathMatch,
    Pose,
    SpeedLimits,
)
from ares.core.node import Input, Node, Output
from managers.obstacle import ObstacleParams, judge, occupied_cells, zone_for


class ObstacleManager(Node):
    """The trapezoid along the predicted trajectory: ready, slow or stop for what is in it."""

    name = "obstacle_manager"
    Params = ObstacleParams
    grid = Input("perception/grid", max_age="grid_timeout_s", doc="occupied cells around the vehicle")
    car = Input("dbw/car_state", max_age="grid_timeout_s", doc="speed and steering-wheel angle now")
    limits = Input("speed/limits", max_age="grid_timeout_s", doc="the speed the shuttle is allowed here")
    match = Input("path/match", max_age="grid_timeout_s", doc="the path ahead")
    pose = Input("localization/pose", max_age="grid_timeout_s", doc="to turn the path ahead into the vehicle's frame")
    control = Input("control/status", max_age="grid_timeout_s", doc="who drives: a path follower, or not")
    state = Output("obstacle/state", rate="rate_hz", doc="score, nearest obstacle, speed limit, the area")

    def setup(self) -> None:
        self.bumper_m = self.vehicle.front_bumper_m
        self._band = "clear"
        self._grid_t: float | None = None
        self._limits: tuple[float, float] | None = None  # the limits from the last two grids

    def step(self, now: float) -> None:
        grid: OccupancyGrid | None = self.grid.fresh(now)
        car: CarState | None = self.car.fresh(now)
        limits: SpeedLimits | None = self.limits.fresh(now)
        v = self.vehicle
        allowed = limits.limit_mps if limits is not None else v.max_speed_mps
        speed = 0.0 if car is None else car.speed_mps
        kappa = 0.0 if car is None else v.curvature_of(car.steering_wheel_deg)
        zone = zone_for(self.params, max(speed, allowed), kappa, v.width_m, self.bumper_m, centre=self._path_ahead(now))
        outline = zone.outline()
        xs, ys = [round(p[0], 3) for p in outline], [round(p[1], 3) for p in outline]
        if grid is None or car is None:
            missing = "grid" if grid is None else "car state"
            self._report("unknown", f"no fresh {missing}: the area is unknown")
            self.state.put(
                ObstacleState(
                    t=now,
                    score=0.0,
                    band="unknown",
                    nearest_m=None,
                    limit_mps=0.0,
                    length_m=zone.length_m,
                    cells=0,
                    area_x=xs,
                    area_y=ys,
                    reason=f"no fresh {missing}",
                )
            )
            return
        ox, oy = occupied_cells(grid.cells, grid.origin_x, grid.origin_y, grid.resolution_m)
        verdict = judge(self.params, zone, ox, oy, max(speed, allowed))
        if self._limits is None:
            self._limits = (verdict.limit_mps, verdict.limit_mps)
        elif grid.t != self._grid_t:  # a new grid: the last two grids' limits
            self._limits = (self._limits[1], verdict.limit_mps)
        else:  # the same grid judged again (a new speed or angle)
            self._limits = (self._limits[0], verdict.limit_mps)
        self._grid_t = grid.t
        limit, band = max(self._limits), verdict.band
        if limit > verdict.limit_mps:
            band = "ready"  # seen in one grid only: be ready, do not brake yet
        reason = (
            "" if verdict.nearest_m is None else f"obstacle {verdict.nearest_m:.1f} m ahead ({verdict.cells} cells)"
        )
        self._report(band, reason)
        self.state.put(
            ObstacleState(
                t=now,
                score=verdict.share,
                band=band,
                nearest_m=verdict.nearest_m,
                limit_mps=limit,
                length_m=zone.length_m,
                cells=verdict.cells,
                area_x=xs,
                area_y=ys,
                reason=reason,
            )
        )

    def _path_ahead(self, now: float) -> np.ndarray | None:
        """The path ahead in the vehicle's frame, while a path follower drives (None: the arc)."""
        status: ControllerStatus | None = self.control.fresh(now)
        match: PathMatch | None = self.match.fresh(now)
        pose: Pose | None = self.pose.fresh(now)
        if status is None or status.mode != "odometry" or match is None or pose is None or len(match.ahead_x) < 2:
            return None
        if pose.var_yaw > self.params.path_max_yaw_std_rad**2:
            return None  # the heading is not known well enough to turn the path
        c, s = math.cos(pose.yaw), math.sin(pose.yaw)
        dx, dy = np.asarray(match.ahead_x) - pose.x, np.asarray(match.ahead_y) - pose.y
        # from a metre behind the axle, so that the bumper's foot is always on it
        back = np.array([[-1.0, 0.0]])
        ahead = np.column_stack([dx * c + dy * s, -dx * s + dy * c])
        return np.vstack([back, ahead[ahead[:, 0] > -1.0]]) if (ahead[:, 0] > -1.0).sum() >= 2 else None

    def _report(self, band: str, reason: str) -> None:
        """An event when the shuttle starts or stops stopping for something."""
        if (band in ("stop", "unknown")) != (self._band in ("stop", "unknown")):
            if band in ("stop", "unknown"):
                self.event("obstacle_stop", f"stopping: {reason}", EventLevel.WARNING)
            else:
                self.event("obstacle_stop", "the way is clear", EventLevel.INFO)
        self._band = band
