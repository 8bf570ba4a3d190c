"""Road Reactive Control (ARES paper §3.6.2, eqs. 14-15): keep to the middle of the road the
LiDARs see, with no trust in the odometry.

    cmd(t) = Kp e(t) + (1/τi) ∫ e dt + τd de/dt + b          (14)
    e(t)   = (lb(t) + rb(t)) / 2 − lb(t)                     (15)

e is the vehicle's distance from the road's centre line (lb, rb: the left and right boundaries
across the road at the vehicle), which road detection publishes as the lateral offset (+ when
the vehicle is left of the centre). The command is a curvature. Its terms are written per metre
travelled rather than per second, so that one set of gains behaves alike at walking pace and at
the cap speed (the lateral error grows with distance, d²e/ds² ≈ −κ for small angles):

    κ = −(kp·e + ki·∫e ds + kd·de/ds) + b
    de/ds = sin(heading relative to the road)   (road detection's heading: no differencing of
                                                 frames, which would amplify their scatter)
    b     = the centre line's own curvature ahead (the road's bend, fed forward)

kp = λ², kd = 2ζλ put the lateral error's response at a spatial frequency λ with damping ζ
(critically damped at ζ = 1). The integral, bounded, takes out a steady offset such as a road's
cross-fall pulling the vehicle aside. The speed is the RRC's own cap (the road is seen only so far
ahead), lowered in proportion as the detection's confidence falls towards min_confidence.

When the detection is lost (grass verges hide an edge now and then), the road last seen is
remembered for `memory_m` of travel: its centre line, in the frame of the vehicle when it was
seen, and the vehicle moved along it by the distance and the curvature actually driven (dead
reckoning over a few metres is good to centimetres). The same law then steers along that centre
line, and the command's speed is 0: the remembered road is good enough to steer a controlled stop
by, not to drive on (`remembered`; the control manager only steers its stop with it). Beyond
`memory_m` there is no candidate, and the integral starts again from zero.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from numpy.polynomial import polynomial as poly

from ares.config import Params, param


class RrcParams(Params):
    """Road Reactive Control (ARES §3.6.2)."""
    kp: float = param(0.0625, "per metre of offset from the centre (λ², λ = 0.25 /m: a lateral error settles "
                              "in ~20 m)", unit="1/m^2", ge=0)
    ki: float = param(0.002, "per metre·metre of offset travelled", unit="1/m^3", ge=0)
    kd: float = param(0.45, "per unit of de/ds = sin(heading to the road) (2ζλ, ζ = 0.9)", unit="1/m", ge=0)
    integral_limit_m2: float = param(5.0, "bound on ∫e ds (anti-windup)", unit="m^2", gt=0)
    curvature_lookahead_m: float = param(4.0, "the road's curvature fed forward is the centre line's at this "
                                              "distance ahead", unit="m", ge=0)
    max_speed_mps: float = param(2.5, "the RRC's own speed cap", unit="m/s", gt=0)
    min_confidence: float = param(0.03, "below this the detection is not followed (docs/control_manager.md: grass "
                                        "verges give right detections at 0.1-0.3)", ge=0, le=1)
    full_speed_confidence: float = param(0.25, "from this confidence the RRC drives at its cap; below, slower in "
                                               "proportion down to 0 at min_confidence", ge=0, le=1)
    max_kappa: float = param(0.25, "largest curvature commanded", unit="1/m", gt=0)
    memory_m: float = param(8.0, "a lost road is steered along, remembered, for this distance travelled (a "
                                 "controlled stop from the cap speed takes ~4 m)", unit="m", ge=0)


@dataclass(frozen=True)
class RoadView:
    """What road detection says of one frame (perception/road), in the vehicle frame."""
    lateral_offset_m: float         # + when the vehicle is left of the centre line
    heading_rad: float              # + when the vehicle points left of the road
    centre: list[float]             # centre line y = c0 + c1 x + c2 x² ..., lowest order first
    confidence: float


@dataclass(frozen=True)
class RrcCommand:
    v: float
    kappa: float
    error_m: float                  # eq. 15
    feedforward: float              # b
    remembered: bool = False        # steering along the road last seen: for a controlled stop only (v = 0)


@dataclass
class RememberedRoad:
    """The last road seen (its centre line in the vehicle frame of then) and the vehicle's pose in
    that frame since, moved by what was driven."""
    centre: list[float]
    x: float = 0.0
    y: float = 0.0
    yaw: float = 0.0
    travelled_m: float = 0.0

    def advance(self, ds: float, kappa: float) -> None:
        """Move the vehicle ds metres along an arc of curvature kappa (exact for a constant kappa)."""
        dyaw = kappa * ds
        chord = ds if abs(dyaw) < 1e-9 else 2.0 * math.sin(dyaw / 2.0) / kappa
        self.x += chord * math.cos(self.yaw + dyaw / 2.0)
        self.y += chord * math.sin(self.yaw + dyaw / 2.0)
        self.yaw += dyaw
        self.travelled_m += ds

    def view(self, confidence: float) -> RoadView:
        """What road detection would say from here of the remembered centre line y = f(x): the offset
        across the line at the vehicle's x, the heading relative to the line's direction there."""
        f = poly.polyval(self.x, self.centre)
        road_yaw = math.atan(poly.polyval(self.x, poly.polyder(self.centre)))
        heading = math.remainder(self.yaw - road_yaw, 2.0 * math.pi)
        offset = (self.y - f) * math.cos(road_yaw)
        return RoadView(offset, heading, self.centre, confidence)


class RoadReactiveControl:
    def __init__(self, params: RrcParams | None = None):
        self.p = params or RrcParams()
        self.integral = 0.0         # ∫ e ds, m²
        self.memory: RememberedRoad | None = None

    def reset(self) -> None:
        self.integral = 0.0
        self.memory = None

    def step(self, road: RoadView | None, travelled_m: float, driven_kappa: float = 0.0) -> RrcCommand | None:
        """One cycle: `travelled_m` since the last one, at the measured curvature `driven_kappa`.
        None: nothing to follow, not even a road remembered."""
        p = self.p
        travelled_m = max(travelled_m, 0.0)
        if road is None or road.confidence < p.min_confidence or not all(
                math.isfinite(v) for v in (road.lateral_offset_m, road.heading_rad)):
            return self._remembered(travelled_m, driven_kappa)
        self.memory = RememberedRoad(list(road.centre)) if p.memory_m > 0 else None
        e = road.lateral_offset_m
        self.integral = max(-p.integral_limit_m2, min(p.integral_limit_m2, self.integral + e * travelled_m))
        kappa, b = self._law(road)
        share = min(1.0, (road.confidence - p.min_confidence) / max(p.full_speed_confidence - p.min_confidence, 1e-9))
        return RrcCommand(p.max_speed_mps * max(share, 0.0), kappa, e, b)

    def _remembered(self, travelled_m: float, driven_kappa: float) -> RrcCommand | None:
        memory = self.memory
        if memory is None:
            self.reset()
            return None
        memory.advance(travelled_m, driven_kappa)
        if memory.travelled_m > self.p.memory_m:
            self.reset()
            return None
        view = memory.view(confidence=0.0)
        kappa, b = self._law(view, ahead_m=memory.x)
        return RrcCommand(0.0, kappa, view.lateral_offset_m, b, remembered=True)

    def _law(self, road: RoadView, ahead_m: float = 0.0) -> tuple[float, float]:
        """Eq. 14 per metre: the curvature commanded and the road's own curvature fed forward."""
        p = self.p
        b = _curvature(road.centre, ahead_m + p.curvature_lookahead_m)
        kappa = -(p.kp * road.lateral_offset_m + p.ki * self.integral + p.kd * math.sin(road.heading_rad)) + b
        return max(-p.max_kappa, min(p.max_kappa, kappa)), b


def _curvature(coefficients: list[float], x: float) -> float:
    """Signed curvature of y = f(x) at x: f'' / (1 + f'²)^1.5 (+ bending left)."""
    d1 = sum(i * c * x ** (i - 1) for i, c in enumerate(coefficients) if i >= 1)
    d2 = sum(i * (i - 1) * c * x ** (i - 2) for i, c in enumerate(coefficients) if i >= 2)
    return d2 / (1.0 + d1 * d1) ** 1.5
