"""Yaw from GNSS positions d metres apart (ARES paper §3.1, eqs. 1-2).

The shuttle's magnetometer cannot be calibrated (the vehicle is too heavy to turn around on
the spot), so its yaw carries an offset. RTK positions are millimetre-accurate, so the
direction of the chord between the current fix and the last fix at least d metres behind it
gives the heading instead:

    chord   = atan2(ΔY, ΔX)                                                  (eq. 1)
    ψ_t     = chord + Δψ_chord / 2

On a curve the chord does not point where the vehicle points now: it points along the
heading half-way between the two fixes. The vehicle has turned by Δψ_chord since the older
fix (the yaw rate integrated over the chord, which the paper writes as d·ψ̇/v: the time to
cover d metres times the yaw rate), so the current heading is the chord plus half of it.
The caller passes the heading change, integrated from a yaw rate (gyro or wheels), so a
yaw rate that varies along the chord is handled too.

Its variance (eq. 2), the first-order propagation of the four position variances through
atan2 (∂ψ/∂ΔX = −ΔY/r², ∂ψ/∂ΔY = ΔX/r², r² = ΔX² + ΔY²):

    σψ² = (ΔY²·(σX,t−1 + σX) + ΔX²·(σY,t−1 + σY)) / (ΔX² + ΔY²)²             (eq. 2)

where the σ are position VARIANCES (m²). The paper prints (1 + ΔY/ΔX)⁻² in front, a typo
for (1 + (ΔY/ΔX)²)⁻²; multiplied out, that is the form above, which also needs no division
by ΔX (the printed form blows up when the vehicle drives north, ΔX → 0). The paper's σψ is
the square root of this. The yaw-rate correction's own error is added on top:
(Δψ_chord's standard error / 2)².

A measurement is only emitted when it means something:
  * the vehicle is moving (a standing vehicle's fixes only scatter around one point);
  * both fixes are of compatible quality (both RTK, or both without corrections): a chord
    from an uncorrected fix to an RTK one measures the receiver's jump, not the motion;
  * the chord was covered in at most `max_chord_s` (a slow crawl makes the yaw-rate
    correction, and the assumption of a smooth path between the fixes, unreliable).

Parameters (config `localization.yaw_from_poses`): distance_m (d), min_speed_mps,
max_chord_s.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

from ares.core.config import Params, param
from ares.core.geometry import wrap_angle


def chord_yaw(dx: float, dy: float) -> float:
    """Direction of the chord between two positions: arctan(ΔY/ΔX) of eq. 1, in all quadrants."""
    return math.atan2(dy, dx)


def yaw_from_poses(x_prev: float, y_prev: float, x: float, y: float, heading_change: float = 0.0) -> float:
    """Eq. 1: the current yaw from the previous and current positions, and the heading change
    since the previous one (the chord points along the heading half-way between them)."""
    return wrap_angle(chord_yaw(x - x_prev, y - y_prev) + 0.5 * heading_change)


def yaw_variance(dx: float, dy: float, var_x_prev: float, var_y_prev: float, var_x: float, var_y: float) -> float:
    """Eq. 2 (variance, rad²) in its well-conditioned form; the σ of the paper are variances."""
    r2 = dx * dx + dy * dy
    if r2 <= 0.0:
        return math.inf
    return (dy * dy * (var_x_prev + var_x) + dx * dx * (var_y_prev + var_y)) / (r2 * r2)


@dataclass(frozen=True)
class PoseFix:
    """One position as this module needs it: time, local x/y, their variances, its quality."""

    t: float
    x: float
    y: float
    var_x: float
    var_y: float
    rtk: bool
    heading: float  # the caller's integrated heading (e.g. ∫ gyro) at time t, rad


@dataclass(frozen=True)
class YawMeasurement:
    t: float  # time of the current fix: the yaw is the heading then
    yaw: float
    variance: float  # rad²
    chord_m: float
    chord_s: float


class YawFromPosesParams(Params):
    """ARES eqs. 1-2."""

    distance_m: float = param(
        1.5, "d: chord length; sigma_yaw ~ 0.007 m * 2 / d = 0.5 deg per measurement with RTK", unit="m", gt=0
    )
    min_speed_mps: float = param(0.5, "only while moving", unit="m/s", ge=0)
    max_chord_s: float = param(5.0, "a chord covered more slowly than this is not used", unit="s", gt=0)
    use_without_rtk: bool = param(
        False, "chords between uncorrected fixes: eq. 2 gives ~0.5 rad, they add only correlated noise"
    )
    heading_change_var_per_s: float = param(
        1.0e-6, "uncertainty of the yaw-rate correction over the chord, per second of chord", unit="rad^2/s", ge=0
    )


class YawFromPoses:
    """Keeps the recent fixes and turns each new one into a yaw measurement and its variance (ARES
    eqs. 1-2) when it can."""

    def __init__(
        self,
        distance_m: float = 1.5,
        min_speed_mps: float = 0.5,
        max_chord_s: float = 5.0,
        heading_change_var_per_s: float = 1e-6,
    ):
        if distance_m <= 0:
            raise ValueError("yaw_from_poses: distance_m must be positive")
        self.distance_m = float(distance_m)
        self.min_speed_mps = float(min_speed_mps)
        self.max_chord_s = float(max_chord_s)
        # variance of the integrated heading change per second of chord (gyro noise/bias)
        self.heading_change_var_per_s = float(heading_change_var_per_s)
        self._fixes: deque[PoseFix] = deque()

    @classmethod
    def from_params(cls, params: YawFromPosesParams) -> YawFromPoses:
        return cls(params.distance_m, params.min_speed_mps, params.max_chord_s, params.heading_change_var_per_s)

    def reset(self) -> None:
        self._fixes.clear()

    def add(self, fix: PoseFix, speed_mps: float) -> YawMeasurement | None:
        """Record a fix; return the yaw at its time if a chord of at least d metres, of
        compatible quality and covered quickly enough, ends at it and the vehicle moves."""
        fixes = self._fixes
        # Anything older than the longest useful chord can never be used again.
        while fixes and fix.t - fixes[0].t > self.max_chord_s:
            fixes.popleft()
        if fixes and fixes[-1].rtk != fix.rtk:
            # A change of quality restarts the history: no chord across the jump.
            fixes.clear()
        # The most recent stored fix at least d metres away starts the chord.
        start = None
        d2_min = self.distance_m * self.distance_m
        for i in range(len(fixes) - 1, -1, -1):
            p = fixes[i]
            if (fix.x - p.x) ** 2 + (fix.y - p.y) ** 2 >= d2_min:
                start = i
                break
        measurement = None
        if start is not None:
            p = fixes[start]
            # Older fixes than the chord's start are no longer needed: the next chord starts
            # at this one or later.
            for _ in range(start):
                fixes.popleft()
            if abs(speed_mps) >= self.min_speed_mps and fix.t > p.t:
                dx, dy = fix.x - p.x, fix.y - p.y
                turned = wrap_angle(fix.heading - p.heading)
                yaw = yaw_from_poses(p.x, p.y, fix.x, fix.y, turned)
                if speed_mps < 0:  # reversing: the chord points backwards
                    yaw = wrap_angle(yaw + math.pi)
                chord_s = fix.t - p.t
                var = (
                    yaw_variance(dx, dy, p.var_x, p.var_y, fix.var_x, fix.var_y)
                    + 0.25 * self.heading_change_var_per_s * chord_s
                )
                measurement = YawMeasurement(fix.t, yaw, var, math.hypot(dx, dy), chord_s)
        fixes.append(fix)
        return measurement
