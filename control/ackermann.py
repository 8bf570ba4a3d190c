"""Ackermann conversions of the drive-by-wire bridge (DBW paper §4.6, eqs. 9-14).

The navigation stack speaks in (v, κ): linear speed of the rear-axle centre (m/s) and
curvature (1/m, positive = left turn, negative = right turn, as in the paper). The
drive-by-wire board speaks in steering-wheel angle α and front drive-wheel speed ω_w.
This module converts both ways:

    ω   = v · κ                              (9)   yaw rate of the vehicle
    R   = 1 / κ                                    turning radius of the rear-axle centre
    tan θ  = S / R = κ · S                   (10)  θ: imaginary wheel in the middle of the front axle
    tan θi = S / (R − L/2)                   (11)  wheel on the inside of the turn
    tan θd = S / (R + L/2)                   (12)  wheel on the outside of the turn
    α   = ratio · θ = ratio · atan(κ · S)    (13)  steering-wheel angle, ratio = 40 on the car
    ω_w = v / (cos θ · r)                    (14)  front wheels are driven, and travel faster than
                                                   the rear-axle centre by 1 / cos θ

and back, so that the board's measurements can be reported as (v, κ):

    κ = tan(α / ratio) / S,    v = ω_w · r · cos(α / ratio).

S is the wheelbase, L the track, r the wheel radius. Eqs. 9-12 and 14 are plain functions of
floats, the vehicle parameters passed in; eq. 13, the steering ratio, is the vehicle's own
(`VehicleProfile.steering_wheel_angle` and `.road_wheel_angle`: every part of the stack that turns
one angle into the other does it there). `SetpointConversion` holds a vehicle profile of
ares/core/config/vehicles/. Angles are radians unless a name says `_deg`; the paper's board works
in degrees (integer arithmetic on the STM32), hence the degree helpers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

from ares.core.config import VehicleProfile

# --- Equations (9)-(12): curvature, yaw rate, radius, wheel angles ---------------------------


def angular_speed(v: float, kappa: float) -> float:
    """Yaw rate ω = v·κ (rad/s), eq. (9)."""
    return v * kappa


def turning_radius(kappa: float) -> float:
    """R = 1/κ (m), signed like κ; a straight line (κ = 0) has an infinite radius."""
    if kappa == 0.0:
        return math.inf
    return 1.0 / kappa


def curvature_from_radius(radius_m: float) -> float:
    """κ = 1/R; an infinite radius is a straight line (κ = 0)."""
    if math.isinf(radius_m):
        return 0.0
    return 1.0 / radius_m


def curvature_to_wheel_angle(kappa: float, wheelbase_m: float) -> float:
    """Front (imaginary centre) wheel angle θ = atan(κ·S), eq. (10). Negative = right turn."""
    return math.atan(kappa * wheelbase_m)


def wheel_angle_to_curvature(wheel_angle_rad: float, wheelbase_m: float) -> float:
    """Inverse of eq. (10): κ = tan θ / S."""
    return math.tan(wheel_angle_rad) / wheelbase_m


def max_curvature(wheelbase_m: float, max_wheel_angle_rad: float) -> float:
    """Tightest curvature the steering allows: tan(θ_max) / S (1/m, a magnitude)."""
    return math.tan(abs(max_wheel_angle_rad)) / wheelbase_m


def limit_wheel_angle(wheel_angle_rad: float, max_wheel_angle_rad: float) -> float:
    """Clamp θ to ±θ_max: the one place where the steering limit is applied to a command."""
    limit = abs(max_wheel_angle_rad)
    return max(-limit, min(limit, wheel_angle_rad))


def left_right_wheel_angles(kappa: float, wheelbase_m: float, track_m: float) -> tuple[float, float]:
    """Angles (left, right) of the two real front wheels, eqs. (11)-(12).

    With a signed radius R = 1/κ the paper's equations give the left wheel from S/(R − L/2)
    and the right wheel from S/(R + L/2) for both directions of turn: in a left turn (R > 0)
    the left wheel is the inner one, in a right turn (R < 0) the right wheel is. Multiplying
    through by κ, tan θ_left = S·κ / (1 − κ·L/2), which needs no special case for the straight
    line (κ = 0 gives 0 for both). atan2 keeps the angle continuous should the centre of
    rotation ever fall between the wheels (|R| < L/2); no real command gets near that.
    """
    half_track = track_m / 2.0
    left = math.atan2(wheelbase_m * kappa, 1.0 - kappa * half_track)
    right = math.atan2(wheelbase_m * kappa, 1.0 + kappa * half_track)
    return left, right


def inner_outer_wheel_angles(kappa: float, wheelbase_m: float, track_m: float) -> tuple[float, float]:
    """Angles (inner θi, outer θd) of the front wheels, signed like the turn (negative = right).

    The inner wheel turns more than the outer one: |θi| > |θd| for any curve.
    """
    left, right = left_right_wheel_angles(kappa, wheelbase_m, track_m)
    if kappa >= 0.0:
        return left, right
    return right, left


# --- Equation (14): drive-wheel speed ---------------------------------------------------------


def wheel_speed(v: float, wheel_angle_rad: float, wheel_radius_m: float) -> float:
    """Front drive-wheel speed ω_w = v / (cos θ · r) (rad/s), eq. (14).

    The steered front wheels run on a larger circle than the rear-axle centre, whose speed
    is v, hence the 1 / cos θ. θ must be below 90°, which any limited command is.
    """
    return v / (math.cos(wheel_angle_rad) * wheel_radius_m)


def wheel_speed_deg(v: float, wheel_angle_rad: float, wheel_radius_m: float) -> float:
    """ω_w in degrees per second, the unit of the paper's board."""
    return math.degrees(wheel_speed(v, wheel_angle_rad, wheel_radius_m))


def wheel_speed_to_linear_speed(wheel_speed_rad_s: float, wheel_angle_rad: float, wheel_radius_m: float) -> float:
    """Inverse of eq. (14): v = ω_w · r · cos θ (m/s at the rear-axle centre)."""
    return wheel_speed_rad_s * wheel_radius_m * math.cos(wheel_angle_rad)


# --- The bridge's conversion, bound to one vehicle ---------------------------------------------


class SpeedCurvature(NamedTuple):
    """A motion in the navigation stack's terms."""

    v: float  # m/s at the rear-axle centre
    kappa: float  # 1/m, positive = left


@dataclass(frozen=True)
class ActuatorSetpoint:
    """What the drive-by-wire board is asked for, in both units it may want."""

    wheel_angle_rad: float  # θ after limiting to ±max_wheel_angle
    steering_wheel_angle_rad: float  # α = ratio · θ (eq. 13, the vehicle's ratio)
    steering_wheel_angle_deg: float
    wheel_speed_rad_s: float  # ω_w = v / (cos θ · r), with the limited θ
    wheel_speed_deg_s: float
    angular_speed_rad_s: float  # ω = v · κ of the curvature actually commanded
    wheel_angle_limited: bool  # True when the requested curvature was too tight


class SetpointConversion:
    """(v, κ) <-> (steering-wheel angle, wheel speed) for one vehicle (DBW eqs. 9-14). Its geometry is
    the profile's, validated there (positive and finite, the wheel angle below 1.5 rad: eq. 14
    divides by cos θ)."""

    def __init__(self, profile: VehicleProfile):
        self.profile = profile
        self.wheelbase_m = profile.wheelbase_m
        self.track_m = profile.track_m
        self.wheel_radius_m = profile.wheel_radius_m
        self.max_wheel_angle_rad = profile.max_wheel_angle_rad

    @property
    def max_curvature(self) -> float:
        return max_curvature(self.wheelbase_m, self.max_wheel_angle_rad)

    def to_actuators(self, v: float, kappa: float) -> ActuatorSetpoint:
        """Setpoint (v, κ) -> what the board should do, with the steering limit applied."""
        requested = curvature_to_wheel_angle(kappa, self.wheelbase_m)
        theta = limit_wheel_angle(requested, self.max_wheel_angle_rad)
        alpha_deg = self.profile.steering_wheel_angle(theta)
        omega_w = wheel_speed(v, theta, self.wheel_radius_m)
        return ActuatorSetpoint(
            wheel_angle_rad=theta,
            steering_wheel_angle_rad=math.radians(alpha_deg),
            steering_wheel_angle_deg=alpha_deg,
            wheel_speed_rad_s=omega_w,
            wheel_speed_deg_s=math.degrees(omega_w),
            angular_speed_rad_s=angular_speed(v, wheel_angle_to_curvature(theta, self.wheelbase_m)),
            wheel_angle_limited=theta != requested,
        )

    def to_speed_curvature_deg(self, steering_wheel_angle_deg: float, wheel_speed_deg_s: float) -> SpeedCurvature:
        """The board's measurement, in its degrees -> (v, κ). Not limited: a measurement is reported
        as it is."""
        theta = self.profile.road_wheel_angle(steering_wheel_angle_deg)
        return SpeedCurvature(
            v=wheel_speed_to_linear_speed(math.radians(wheel_speed_deg_s), theta, self.wheel_radius_m),
            kappa=wheel_angle_to_curvature(theta, self.wheelbase_m),
        )

    def to_speed_curvature(self, steering_wheel_angle_rad: float, wheel_speed_rad_s: float) -> SpeedCurvature:
        """Same as `to_speed_curvature_deg` for a measurement in radians."""
        return self.to_speed_curvature_deg(math.degrees(steering_wheel_angle_rad), math.degrees(wheel_speed_rad_s))

    def wheel_angles(self, kappa: float) -> tuple[float, float]:
        """(inner, outer) front wheel angles for κ after limiting, signed like the turn."""
        theta = limit_wheel_angle(curvature_to_wheel_angle(kappa, self.wheelbase_m), self.max_wheel_angle_rad)
        return inner_outer_wheel_angles(
            wheel_angle_to_curvature(theta, self.wheelbase_m), self.wheelbase_m, self.track_m
        )
