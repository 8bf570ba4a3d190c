"""Wheel odometry from the CAN bus with a kinematic bicycle (ARES paper §3.1, eqs. 3-5).

    β  = atan(k_cg · tan δ)                      slip angle of the reference point
    ΔX = v · cos(ψ + β) · ΔT                     (3)
    ΔY = v · sin(ψ + β) · ΔT                     (4)
    Δψ = v · cos β · tan δ / w_b · ΔT            (5)

δ is the front wheel angle, δ = α / steering_ratio from the steering-wheel angle α the CAN
bus reports; w_b the wheelbase; k_cg places the reference point (the centre of gravity)
along the wheelbase. Read as equations, β = atan(k_cg·tan δ) is the slip angle of the point
k_cg·w_b ahead of the rear axle (k_cg = 0: the rear axle, no slip; k_cg = 1: the front
axle, β = δ); the paper's prose names the ends the other way round, and the shuttle's 0.5
(vehicle profile) reads the same both ways.

What the CAN bus reports is the REAR-AXLE speed v_r (simulator.sensors.CanSensor: the driven
front wheel's speed times r·cos δ, DBW eq. 14). A rigid body turning about the rear-axle
line moves its point at k_cg with v = v_r / cos β, so eq. 5 gives ψ̇ = v_r·tan δ / w_b — the
yaw rate is the same whichever point one follows, as it must be. This module therefore
converts the CAN speed to the reference point's speed before using eqs. 3-5.

On a slope the wheels roll along the road while the map (and GNSS) are horizontal: the
horizontal speed is v·cos(pitch), with the IMU's pitch (stable: it does not depend on the
magnetometer, and the paper uses it too). Without that, a 12 % grade stretches the track
by 0.7 %, half a metre over a 70 m dead zone.

For the UKF only the speed and the yaw rate are used (the paper: "only position, orientation
increments and speed are considered"), as a measurement of the state's v and ψ̇.
`WheelOdometry.integrate` accumulates eqs. 3-5 into a dead-reckoned pose, for tests and
diagnostics.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ares.core.config import VehicleProfile
from ares.core.geometry import wrap_angle


def slip_angle(delta: float, k_cg: float) -> float:
    """β = atan(k_cg · tan δ)."""
    return math.atan(k_cg * math.tan(delta))


def increments(
    v: float, yaw: float, delta: float, dt: float, k_cg: float, wheelbase_m: float
) -> tuple[float, float, float]:
    """(ΔX, ΔY, Δψ) of eqs. 3-5; v is the speed of the reference point (at k_cg)."""
    beta = slip_angle(delta, k_cg)
    dx = v * math.cos(yaw + beta) * dt  # (3)
    dy = v * math.sin(yaw + beta) * dt  # (4)
    dyaw = v * math.cos(beta) * math.tan(delta) / wheelbase_m * dt  # (5)
    return dx, dy, dyaw


@dataclass(frozen=True)
class WheelReading:
    t: float
    v: float  # horizontal speed of the rear-axle centre, m/s
    delta: float  # front wheel angle, rad
    yaw_rate: float  # eq. 5 / ΔT, rad/s


class WheelOdometry:
    def __init__(self, profile: VehicleProfile):
        self.profile = profile
        self.wheelbase_m = float(profile.wheelbase_m)
        self.k_cg = float(profile.k_cg)
        # dead-reckoned pose of the reference point (at k_cg), from integrate()
        self.x = self.y = self.yaw = 0.0
        self._t: float | None = None

    def reference_speed(self, rear_axle_speed: float, delta: float) -> float:
        """Speed of the point at k_cg from the rear-axle speed: v_r / cos β."""
        return rear_axle_speed / math.cos(slip_angle(delta, self.k_cg))

    def reading(self, t: float, speed_mps: float, steering_wheel_deg: float, pitch: float = 0.0) -> WheelReading:
        """Speed and yaw rate from one CAN frame (and the IMU's pitch for the slope)."""
        delta = self.profile.road_wheel_angle(steering_wheel_deg)
        v_rear = speed_mps * math.cos(pitch)
        v_ref = self.reference_speed(v_rear, delta)
        _, _, dyaw = increments(v_ref, 0.0, delta, 1.0, self.k_cg, self.wheelbase_m)  # Δψ per second
        return WheelReading(t, v_rear, delta, dyaw)

    # ---- dead reckoning ------------------------------------------------------------------
    def reset(self, x: float = 0.0, y: float = 0.0, yaw: float = 0.0) -> None:
        """Start dead reckoning with the reference point at (x, y), heading yaw."""
        self.x, self.y, self.yaw = float(x), float(y), float(yaw)
        self._t = None

    def integrate(
        self, t: float, speed_mps: float, steering_wheel_deg: float, pitch: float = 0.0
    ) -> tuple[float, float, float]:
        """Accumulate eqs. 3-5 from the previous frame to this one (the frame's speed and
        steering held over the interval, heading at its midpoint); returns (x, y, yaw)."""
        if self._t is not None and t > self._t:
            dt = t - self._t
            r = self.reading(t, speed_mps, steering_wheel_deg, pitch)
            v_ref = self.reference_speed(r.v, r.delta)
            _, _, dyaw = increments(v_ref, self.yaw, r.delta, dt, self.k_cg, self.wheelbase_m)
            dx, dy, _ = increments(v_ref, self.yaw + 0.5 * dyaw, r.delta, dt, self.k_cg, self.wheelbase_m)
            self.x += dx
            self.y += dy
            self.yaw = wrap_angle(self.yaw + dyaw)
        self._t = t
        return self.x, self.y, self.yaw

    def rear_axle(self) -> tuple[float, float]:
        """The rear-axle centre behind the dead-reckoned reference point."""
        back = self.k_cg * self.wheelbase_m
        return self.x - back * math.cos(self.yaw), self.y - back * math.sin(self.yaw)
