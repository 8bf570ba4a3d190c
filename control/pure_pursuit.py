"""Pure pursuit path tracking with a speed hold (the DBW paper's control module, after Coulter).

The controller does not search the route itself: the path manager matches the pose to the
route (KD-tree, reachable poses only) and sends the path ahead. The goal point lies one
lookahead distance along that path from the match; the arc from the rear axle through it has
curvature kappa = 2 sin(alpha) / L, where alpha is the goal's bearing relative to the heading
and L its distance. Pure pursuit cuts corners by roughly R - sqrt(R^2 - L^2) on a curve of
radius R, so the speed limits slow the vehicle in tight curves and the lookahead shrinks with
speed. The speed target is the limit at the match.

Without a fresh pose and a fresh path match no setpoint is sent at all, so the drive-by-wire
bridge's watchdog stops the vehicle rather than letting it steer from stale data.

At start-up the heading is only the magnetometer's guess, off by its calibration offset (the
ARES paper's reason for yaw from poses), until the vehicle has moved a few metres. Steering
towards the goal with that heading turns a phantom error into a real one, which the vehicle then
has to take out again at speed. So while the pose's heading is uncertain (sigma above
controller.max_heading_sigma_rad) the controller follows the path's own curvature at no more
than controller.creep_speed_mps, and pursues the goal point once the heading is known.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from ares.core.config import VehicleProfile, param
from control.path_tracking import TrackerParams


class ControllerParams(TrackerParams):
    lookahead_min_m: float = param(1.0, "shortest lookahead", unit="m", gt=0)
    lookahead_gain_s: float = param(
        1.1,
        "lookahead = min + gain * speed: short in slow, tight curves; long enough "
        "at speed that the rate-limited steering (350 deg/s at the steering wheel) "
        "keeps up",
        unit="s",
        ge=0,
    )
    lookahead_max_m: float = param(5.0, "longest lookahead", unit="m", gt=0)


@dataclass
class PursuitCommand:
    v: float
    kappa: float
    lookahead_m: float
    finished: bool


def goal_point(ahead_x: Sequence[float], ahead_y: Sequence[float], distance_m: float) -> tuple[float, float]:
    """The point `distance_m` along the polyline of the ahead poses from its first point
    (interpolated), or its last point when the polyline is shorter (the end of an open route)."""
    travelled = 0.0
    for k in range(1, len(ahead_x)):
        x0, y0, x1, y1 = ahead_x[k - 1], ahead_y[k - 1], ahead_x[k], ahead_y[k]
        seg = math.hypot(x1 - x0, y1 - y0)
        if travelled + seg >= distance_m and seg > 0.0:
            f = (distance_m - travelled) / seg
            return x0 + f * (x1 - x0), y0 + f * (y1 - y0)
        travelled += seg
    return ahead_x[-1], ahead_y[-1]


class PurePursuit:
    """The controller's geometry, free of the bus: a pose and the path ahead in, (v, kappa) out."""

    def __init__(self, params: ControllerParams, vehicle: VehicleProfile):
        self.lookahead_min = params.lookahead_min_m
        self.lookahead_gain = params.lookahead_gain_s
        self.lookahead_max = params.lookahead_max_m
        self.max_kappa = vehicle.max_curvature
        self.max_heading_sigma = params.max_heading_sigma_rad
        self.creep_speed = params.creep_speed_mps
        self.finish_distance = params.finish_distance_m

    def lookahead(self, v: float) -> float:
        return min(max(self.lookahead_min + self.lookahead_gain * abs(v), self.lookahead_min), self.lookahead_max)

    def command(
        self,
        x: float,
        y: float,
        yaw: float,
        v: float,
        ahead_x: Sequence[float],
        ahead_y: Sequence[float],
        ahead_speed: Sequence[float],
        distance_to_end_m: float | None = None,
        heading_sigma: float = 0.0,
        ahead_curvature: Sequence[float] = (),
    ) -> PursuitCommand:
        """Setpoint for a vehicle at (x, y, yaw) moving at v, following the ahead poses
        (the first one is the vehicle's match on the route)."""
        lookahead = self.lookahead(v)
        finished = distance_to_end_m is not None and distance_to_end_m < self.finish_distance
        if finished or len(ahead_x) == 0:
            return PursuitCommand(0.0, 0.0, lookahead, finished)
        if heading_sigma > self.max_heading_sigma:
            path_kappa = float(ahead_curvature[0]) if len(ahead_curvature) else 0.0
            return PursuitCommand(
                min(float(ahead_speed[0]), self.creep_speed),
                max(-self.max_kappa, min(self.max_kappa, path_kappa)),
                lookahead,
                finished,
            )
        gx, gy = goal_point(ahead_x, ahead_y, lookahead)
        dx, dy = gx - x, gy - y
        distance = math.hypot(dx, dy)
        if distance < 1e-3:
            return PursuitCommand(0.0, 0.0, lookahead, finished)
        alpha = math.atan2(dy, dx) - yaw
        kappa = 2.0 * math.sin(alpha) / distance
        kappa = max(-self.max_kappa, min(self.max_kappa, kappa))
        return PursuitCommand(float(ahead_speed[0]), kappa, lookahead, finished)
