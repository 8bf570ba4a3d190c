"""The Stanley lateral law (Hoffmann, Tomlin, Montemerlo, Thrun 2007; the controller ARES Fig. 15
sets the MPC beside), with the speed target of the path ahead.

The law steers the front wheels by the heading error plus a term that closes the front axle's
cross-track error:

    δ = ψ_e + atan(k · e_fa / (k_soft + v))

ψ_e the path's heading minus the vehicle's at the point of the path nearest the *front* axle,
e_fa that axle's offset from the path (+ when the path lies to its left), k the gain (1/s) and
k_soft a softening speed that keeps the term bounded when standing. The curvature the control
manager takes is κ = tan δ / L (L the wheelbase), within the vehicle's limits. The front axle is
the rear-axle pose moved one wheelbase ahead; the path is the path manager's poses ahead, which
start at the rear axle's match, so the front axle's nearest point lies on them.

As pure pursuit, it sends nothing without a fresh pose and path, and follows the path's own
curvature at creep speed while the heading is only the magnetometer's guess.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from ares.core.config import VehicleProfile, param
from ares.core.geometry import wrap_angle
from control.path_tracking import TrackerParams


class StanleyParams(TrackerParams):
    gain_per_s: float = param(
        1.5, "k: how hard the front axle's offset is closed (rad of steering per m at 1 m/s)", unit="1/s", gt=0
    )
    softening_mps: float = param(1.0, "k_soft: keeps the offset's term bounded at a standstill", unit="m/s", gt=0)


@dataclass
class StanleyCommand:
    v: float
    kappa: float
    front_offset_m: float  # e_fa: + when the path lies to the front axle's left
    heading_error_rad: float  # ψ_e at the front axle's nearest point
    finished: bool


def nearest_on_path(
    px: float, py: float, ahead_x: Sequence[float], ahead_y: Sequence[float]
) -> tuple[float, float] | None:
    """(the point's signed distance from the path, + when it lies left of the path's direction; the
    path's heading) at the foot of the perpendicular on the polyline's nearest segment; None when
    the polyline has no segment of any length."""
    best = None
    for k in range(1, len(ahead_x)):
        ax, ay = ahead_x[k - 1], ahead_y[k - 1]
        ex, ey = ahead_x[k] - ax, ahead_y[k] - ay
        seg2 = ex * ex + ey * ey
        if seg2 <= 0.0:
            continue
        t = min(max(((px - ax) * ex + (py - ay) * ey) / seg2, 0.0), 1.0)
        dx, dy = px - (ax + t * ex), py - (ay + t * ey)
        d2 = dx * dx + dy * dy
        if best is None or d2 < best[0]:
            side = (ex * dy - ey * dx) / math.sqrt(seg2)  # + when the point is left of the path
            best = d2, side, math.atan2(ey, ex)
    return None if best is None else (best[1], best[2])


class Stanley:
    """The law, free of the bus: a pose and the path ahead in, (v, kappa) out."""

    def __init__(self, params: StanleyParams, vehicle: VehicleProfile):
        self.gain = params.gain_per_s
        self.softening = params.softening_mps
        self.wheelbase = vehicle.wheelbase_m
        self.max_kappa = vehicle.max_curvature
        self.max_heading_sigma = params.max_heading_sigma_rad
        self.creep_speed = params.creep_speed_mps
        self.finish_distance = params.finish_distance_m

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
    ) -> StanleyCommand:
        finished = distance_to_end_m is not None and distance_to_end_m < self.finish_distance
        if finished or len(ahead_x) < 2:
            return StanleyCommand(0.0, 0.0, 0.0, 0.0, finished)
        if heading_sigma > self.max_heading_sigma:
            path_kappa = float(ahead_curvature[0]) if len(ahead_curvature) else 0.0
            return StanleyCommand(
                min(float(ahead_speed[0]), self.creep_speed), self._clamp(path_kappa), 0.0, 0.0, finished
            )
        fx, fy = x + self.wheelbase * math.cos(yaw), y + self.wheelbase * math.sin(yaw)
        found = nearest_on_path(fx, fy, ahead_x, ahead_y)
        if found is None:
            return StanleyCommand(0.0, 0.0, 0.0, 0.0, finished)
        side, path_yaw = found
        offset = -side  # the path's side of the axle: + when the path is to the axle's left
        heading_error = wrap_angle(path_yaw - yaw)
        delta = heading_error + math.atan(self.gain * offset / (self.softening + abs(v)))
        delta = max(-0.5 * math.pi + 1e-3, min(0.5 * math.pi - 1e-3, delta))
        kappa = self._clamp(math.tan(delta) / self.wheelbase)
        return StanleyCommand(float(ahead_speed[0]), kappa, offset, heading_error, finished)

    def _clamp(self, kappa: float) -> float:
        return max(-self.max_kappa, min(self.max_kappa, kappa))
