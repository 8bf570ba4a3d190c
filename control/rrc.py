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
    b     = the road's mean curvature over the next curvature_lookahead_m (its bend, fed forward)

kp = λ², kd = 2ζλ put the lateral error's response at a spatial frequency λ with damping ζ
(critically damped at ζ = 1). The integral, bounded, takes out a steady offset such as a road's
cross-fall pulling the vehicle aside. It runs only while the RRC's candidate drives (`driving`):
the RRC computes all the time, and a reading a centimetre off for the hundreds of metres the MPC
drives would fill it to its bound, then steer the shuttle aside at the hand-over. The speed is
the RRC's own cap (the road is seen only so far ahead), lowered in proportion as the detection's
confidence falls towards min_confidence.

The road at the wheels is read from frames seen a few metres back. Road detection sees the
boundaries from about 4 m ahead, so its offset and heading at the vehicle (x = 0) are its fit
extrapolated backwards; where a tight bend begins ahead, the fit bends towards it and the
extrapolation is off by up to 1.5 m and 35° (the promenade's 12 m bend), while within its points
(4-6 m ahead) the same fit is good to ~15 cm. So each confident frame's centre line is remembered,
in the vehicle frame of the moment it was seen, with the vehicle moved along it since by the
distance and the curvature actually driven (dead reckoning over a few metres is good to
centimetres), and e and the heading are the mean of what the frames seen `view_from_m` to
`view_to_m` back say of the road where the vehicle now is (without any that far back yet, after
a start, the frame seen nearest to that range).

b is not a fit's curvature either: a quadratic's curvature is one figure for all of 4-12 m ahead,
so it reads a bend up to 8 m early and, inside a bend turning through 90°, off by a factor of two
or three. It is the turn of the road's direction from where the vehicle is (the heading just
read) to curvature_lookahead_m ahead (the newest frame's direction there, near its first points),
over that distance.

A new frame is checked against the road remembered: where both saw the same stretch (its centre
line 4-8 m ahead, the remembered frame's within its points), it must lie within `agree_m` of the
newest remembered frame's, on the mean, across the road. One that does not is not followed (it
is treated as a lost road): a detection grown from the near field inside a tight bend can point
the road 48° wrong with some confidence, and it once steered the shuttle 1.3 m aside. Should
`doubt_frames` frames in a row (no cycle without a followable road between them) agree with one
another but not with the memory, the memory was the wrong one and they replace it, the integral
starting again (`replaced`). Without that, a wrong memory would hold a standing shuttle for good:
standing, the remembered frames never age.

When the detection is lost (grass verges hide an edge now and then), the remembered frames keep
being read the same way for `memory_m` of travel past the last one. The command's speed is then
0: the remembered road is good enough to steer a controlled stop by, not to drive on
(`remembered`; the control manager only steers its stop with it). Beyond `memory_m` there is no
candidate, and the integral starts again from zero.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.polynomial import polynomial as poly
from pydantic import model_validator

from ares.core.config import Params, param
from ares.core.geometry import arc_step, local_to_vehicle, vehicle_to_local

SPACING_M = 0.1  # remembered frames lie at least this far apart (but the newest): bounded at standstill
CHECK_AHEAD_M = (4.0, 5.0, 6.0, 7.0, 8.0)  # a new frame's centre line is checked here (within its points) ...
SEEN_M = (4.0, 12.0)  # ... against a remembered frame's, where that one had points (the fit reaches 12 m)
CHECK_MIN_POINTS = 3  # fewer shared points: the frames saw different stretches, nothing to check


class RrcParams(Params):
    """Road Reactive Control (ARES §3.6.2)."""

    kp: float = param(
        0.0625,
        "per metre of offset from the centre (λ², λ = 0.25 /m: a lateral error settles in ~20 m)",
        unit="1/m^2",
        ge=0,
    )
    ki: float = param(0.002, "per metre·metre of offset travelled", unit="1/m^3", ge=0)
    kd: float = param(0.45, "per unit of de/ds = sin(heading to the road) (2ζλ, ζ = 0.9)", unit="1/m", ge=0)
    integral_limit_m2: float = param(5.0, "bound on ∫e ds (anti-windup)", unit="m^2", gt=0)
    curvature_lookahead_m: float = param(
        5.0,
        "the road's curvature fed forward is its mean over this distance "
        "ahead: the turn of its direction from the vehicle to there, there "
        "as the newest frame sees it (from ~4 m ahead: within its points)",
        unit="m",
        gt=0,
    )
    max_speed_mps: float = param(2.5, "the RRC's own speed cap", unit="m/s", gt=0)
    min_confidence: float = param(
        0.03,
        "below this the detection is not followed (docs/control.md's thresholds: right detections "
        "on grass verges score 0.07 (p05) to 0.16 (p50))",
        ge=0,
        le=1,
    )
    full_speed_confidence: float = param(
        0.25,
        "from this confidence the RRC drives at its cap; below, slower in proportion down to 0 at min_confidence",
        ge=0,
        le=1,
    )
    max_kappa: float = param(0.25, "largest curvature commanded", unit="1/m", gt=0)
    memory_m: float = param(
        8.0,
        "a lost road is steered along, remembered, for this distance travelled (a "
        "controlled stop from the cap speed takes ~4 m)",
        unit="m",
        ge=0,
    )
    view_from_m: float = param(
        3.0,
        "the offset and heading are read from the frames seen this far back or "
        "more (the road at the vehicle was then within their boundary points, "
        "which begin ~4 m ahead) ...",
        unit="m",
        ge=0,
    )
    view_to_m: float = param(
        6.0,
        "... up to this far (docs/control.md, `ares calibrate rrc-view`: in the 12 m bend "
        "the offset's p95 error fell from 1.45 m to 0.15 m)",
        unit="m",
        ge=0,
    )
    agree_m: float = param(
        1.0,
        "a new frame whose centre line lies farther than this (mean, 4-8 m ahead) from "
        "where the newest remembered frame saw the same road is not followed ...",
        unit="m",
        gt=0,
    )
    doubt_frames: int = param(
        20,
        "... unless this many frames in a row (2 s of LiDAR frames) agree with one "
        "another: then it was the remembered road that was wrong",
        ge=1,
    )

    @model_validator(mode="after")
    def _view_range(self):
        if self.view_to_m < self.view_from_m:
            raise ValueError("view_to_m must not be below view_from_m")
        return self


@dataclass(frozen=True)
class RoadView:
    """What road detection says of one frame (perception/road), in the vehicle frame."""

    lateral_offset_m: float  # + when the vehicle is left of the centre line
    heading_rad: float  # + when the vehicle points left of the road
    centre: list[float]  # centre line y = c0 + c1 x + c2 x² ..., lowest order first
    confidence: float
    stamp: float | None = None  # the frame's time: a view seen again is not a new frame (None: always new)


@dataclass(frozen=True)
class RrcCommand:
    v: float
    kappa: float
    error_m: float  # eq. 15
    feedforward: float  # b
    remembered: bool = False  # steering along the road last seen: for a controlled stop only (v = 0)
    heading_rad: float = 0.0  # the heading to the road the law used


@dataclass
class RememberedRoad:
    """The last road seen (its centre line in the vehicle frame of then) and the vehicle's pose in
    that frame since, moved by what was driven."""

    centre: list[float]
    x: float = 0.0
    y: float = 0.0
    yaw: float = 0.0
    travelled_m: float = 0.0
    stamp: float | None = None

    def advance(self, ds: float, kappa: float) -> None:
        """Move the vehicle ds metres along an arc of curvature kappa (exact for a constant kappa)."""
        self.x, self.y, self.yaw = arc_step(self.x, self.y, self.yaw, ds, kappa)
        self.travelled_m += ds

    def view(self, confidence: float) -> RoadView:
        """What road detection would say from here of the remembered centre line y = f(x): the offset
        across the line at the vehicle's x, the heading relative to the line's direction there."""
        f = poly.polyval(self.x, self.centre)
        road_yaw = math.atan(poly.polyval(self.x, poly.polyder(self.centre)))
        heading = math.remainder(self.yaw - road_yaw, 2.0 * math.pi)
        offset = (self.y - f) * math.cos(road_yaw)
        return RoadView(offset, heading, self.centre, confidence)


def disagreement(new: RememberedRoad, old: RememberedRoad) -> float | None:
    """How far (m, mean, across the road) the new frame's centre line 4-8 m ahead lies from the old
    frame's, where the old one had points there; None where they share too few."""
    xs = np.array(CHECK_AHEAD_M)
    xv, yv = local_to_vehicle(new.x, new.y, new.yaw, xs, poly.polyval(xs, new.centre))  # the vehicle now
    x_old, y_old = vehicle_to_local(old.x, old.y, old.yaw, xv, yv)  # the old frame
    shared = (x_old >= SEEN_M[0]) & (x_old <= SEEN_M[1])
    if shared.sum() < CHECK_MIN_POINTS:
        return None
    x_old, y_old = x_old[shared], y_old[shared]
    slope = poly.polyval(x_old, poly.polyder(old.centre))
    across = np.abs(y_old - poly.polyval(x_old, old.centre)) / np.sqrt(1.0 + slope * slope)  # not along y
    return float(across.mean())


def agree(frame: RememberedRoad, remembered: list[RememberedRoad], agree_m: float) -> bool:
    """Whether the frame agrees with the newest of the remembered frames that saw the same road
    (True when none did)."""
    for old in reversed(remembered):
        apart = disagreement(frame, old)
        if apart is not None:
            return apart <= agree_m
    return True


class RoadReactiveControl:
    """The PID on the offset from the road's centre (ARES eqs. 14-15), per metre travelled, reading
    the road from the frames it remembers (see the module's docstring); `step` once per frame."""

    def __init__(self, params: RrcParams | None = None):
        self.p = params or RrcParams()
        self.integral = 0.0  # ∫ e ds, m²
        self.seen: list[RememberedRoad] = []  # the confident frames of the last metres, oldest first
        self.doubted: list[RememberedRoad] = []  # the frames in a row that disagreed with them, oldest first
        self.replaced = False  # this cycle's frames replaced the memory they disagreed with

    @property
    def memory(self) -> RememberedRoad | None:
        """The road last seen."""
        return self.seen[-1] if self.seen else None

    def reset(self) -> None:
        self.integral = 0.0
        self.seen = []
        self.doubted = []

    def step(
        self,
        road: RoadView | None,
        travelled_m: float | None,
        driven_kappa: float = 0.0,
        since_frame_m: float = 0.0,
        driving: bool = True,
    ) -> RrcCommand | None:
        """One cycle: `travelled_m` since the last one (signed, + forwards), at the measured curvature
        `driven_kappa` (None: not measured, so the frames cannot be moved and only the newest is kept);
        `since_frame_m` driven since `road`'s frame was taken (perception's latency); `driving`:
        whether this controller's candidate is the one driving (else the integral stays at 0).
        None: nothing to follow, not even a road remembered."""
        p = self.p
        self.replaced = False
        unmeasured = travelled_m is None
        if unmeasured:
            self.seen, self.doubted = self.seen[-1:], []
        travelled_m = travelled_m or 0.0  # signed: backwards moves the frames back
        for frame in self.seen + self.doubted:
            frame.advance(travelled_m, driven_kappa)
        keep = max(p.memory_m, p.view_to_m)
        self.seen = [frame for frame in self.seen if frame.travelled_m <= keep]
        if (
            road is None
            or road.confidence < p.min_confidence
            or not all(math.isfinite(v) for v in (road.lateral_offset_m, road.heading_rad, *road.centre))
        ):
            self.doubted = []  # doubts count in a row
            return self._remembered()
        if not self._remember(road, since_frame_m, driven_kappa):
            return self._remembered(forget=False)  # the memory stays to check the next frames by
        if unmeasured:
            self.seen = self.seen[-1:]
        offset, heading, b = self._at_vehicle()
        self.integral = (
            max(-p.integral_limit_m2, min(p.integral_limit_m2, self.integral + offset * abs(travelled_m)))
            if driving
            else 0.0
        )
        kappa = self._law(offset, heading, b)
        share = min(1.0, (road.confidence - p.min_confidence) / max(p.full_speed_confidence - p.min_confidence, 1e-9))
        return RrcCommand(p.max_speed_mps * max(share, 0.0), kappa, offset, b, heading_rad=heading)

    def _remember(self, road: RoadView, since_frame_m: float, driven_kappa: float) -> bool:
        """Remember a new frame if it agrees with the road remembered; False: it is not followed."""
        newest = self.memory
        if road.stamp is not None and any(f.stamp == road.stamp for f in (newest, *self.doubted[-1:]) if f):
            return not self.doubted  # the same frame again (the loop outruns the LiDARs)
        frame = RememberedRoad(list(road.centre), stamp=road.stamp)
        frame.advance(since_frame_m, driven_kappa)  # the vehicle has moved on since the sweep
        if not agree(frame, self.seen, self.p.agree_m):
            self.doubted = self.doubted + [frame] if agree(frame, self.doubted, self.p.agree_m) else [frame]
            if len(self.doubted) < self.p.doubt_frames:
                return False
            self.seen, self.doubted = self.doubted[:-1], []  # they agreed with one another: the memory was wrong
            self.integral, self.replaced = 0.0, True
        self.doubted = []
        if len(self.seen) >= 2 and self.seen[-2].travelled_m - self.seen[-1].travelled_m < SPACING_M:
            self.seen.pop()  # the newest so far lies too close to the one before
        self.seen.append(frame)
        return True

    def _at_vehicle(self) -> tuple[float, float, float]:
        """Offset and heading where the vehicle is, as the frames seen view_from_m to view_to_m back
        saw the road there (mean), or else the frame seen nearest to that range; and b, the road's
        mean curvature over the next curvature_lookahead_m: the turn of its direction from here to
        there, there as the newest frame sees it (within its points)."""
        p = self.p
        distance = [max(p.view_from_m - f.travelled_m, f.travelled_m - p.view_to_m, 0.0) for f in self.seen]
        nearest = min(distance)
        views = [f.view(0.0) for f, d in zip(self.seen, distance) if d == nearest]
        offset = sum(v.lateral_offset_m for v in views) / len(views)
        heading = sum(v.heading_rad for v in views) / len(views)
        newest = self.seen[-1]
        ahead = newest.x + p.curvature_lookahead_m
        road_yaw_ahead = math.atan(poly.polyval(ahead, poly.polyder(newest.centre))) - newest.yaw  # vehicle frame
        b = math.remainder(road_yaw_ahead + heading, 2.0 * math.pi) / p.curvature_lookahead_m  # here: −heading
        return offset, heading, b

    def _remembered(self, forget: bool = True) -> RrcCommand | None:
        """A stop_only command along the road remembered; None beyond memory_m (then the memory is
        forgotten, unless `forget` is False: a doubted frame must not clear what it is checked by)."""
        memory = self.memory
        if memory is None or self.p.memory_m <= 0 or memory.travelled_m > self.p.memory_m:
            if forget:
                self.reset()
            return None
        offset, heading, b = self._at_vehicle()
        return RrcCommand(0.0, self._law(offset, heading, b), offset, b, remembered=True, heading_rad=heading)

    def _law(self, offset: float, heading: float, b: float) -> float:
        """Eq. 14 per metre: the curvature commanded, b the road's own curvature fed forward."""
        p = self.p
        kappa = -(p.kp * offset + p.ki * self.integral + p.kd * math.sin(heading)) + b
        return max(-p.max_kappa, min(p.max_kappa, kappa))
