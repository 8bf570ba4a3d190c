"""Vehicle profiles (vehicles/*.yaml): geometry, limits, masses, the raw actuators the simulator
models, the drive-by-wire board's inner-loop gains and the LiDARs with their extrinsics."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, Literal

from ares.core.config.base import Params, deep_merge, load_yaml, named_file, param, validated


class SteeringActuatorParams(Params):
    dead_time_s: float = param(doc="transport delay of the steering motor", unit="s", ge=0)
    max_rate_deg_s: float = param(doc="steering-wheel speed at full effort", unit="deg/s", gt=0)
    time_constant_s: float = param(doc="motor speed lag", unit="s", ge=0)
    stiction_effort: float = param(doc="static friction: smaller efforts do not turn the column", ge=0, lt=1)


class TractionActuatorParams(Params):
    dead_time_s: float = param(doc="transport delay of the motor controller", unit="s", ge=0)
    time_constant_s: float = param(doc="controller ramp", unit="s", ge=0)
    full_effort_speed_mps: float = param(doc="synchronous speed at full effort", unit="m/s", gt=0)
    slip_stiffness_n_per_mps: float = param(doc="motor force per m/s below synchronous speed", unit="N/(m/s)", gt=0)
    max_drive_force_n: float = param(doc="current limit", unit="N", gt=0)
    max_regen_force_n: float = param(doc="regenerative braking", unit="N", ge=0)
    max_brake_force_n: float = param(doc="friction brake at full effort", unit="N", ge=0)
    parking_hold_force_n: float = param(0.0, "electromagnetic brake at standstill, throttle released", unit="N", ge=0)
    rolling_resistance: float = param(doc="rolling resistance coefficient", ge=0)
    drag_area_m2: float = param(0.0, "Cd times frontal area", unit="m^2", ge=0)


class ActuatorParams(Params):
    steering: SteeringActuatorParams
    traction: TractionActuatorParams


class PidGains(Params):
    kp: float = param(doc="proportional gain")
    ki: float = param(0.0, "integral gain")
    kd: float = param(0.0, "derivative gain")
    out_min: float = param(-1.0, "lowest effort")
    out_max: float = param(1.0, "highest effort")
    integral_limit: float | None = param(None, "bound on the integral alone (default: the output range)")
    derivative_on_measurement: bool = param(True, "derivative of the measurement, not the error (no kick)")


class DbwPidParams(Params):
    steering: PidGains
    throttle: PidGains


class LidarLayers(Params):
    count: int = param(doc="lasers in this block", ge=1)
    top_deg: float = param(doc="elevation of the block's highest laser", unit="deg")
    bottom_deg: float = param(doc="elevation of its lowest laser", unit="deg")


class LidarModel(Params):
    """A spinning LiDAR's datasheet: its lasers, azimuth resolution and range."""

    layers: list[LidarLayers] = param(doc="blocks of evenly spaced lasers, top to bottom", min_length=1)
    azimuth_step_deg: float = param(doc="angle between firings at 10 Hz", unit="deg", gt=0)
    min_range_m: float = param(doc="closer returns are discarded by the sensor", unit="m", ge=0)
    max_range_m: float = param(doc="farthest return (good reflectors)", unit="m", gt=0)
    range_sigma_m: float = param(doc="range noise", unit="m", ge=0)

    def elevations_deg(self) -> list[float]:
        """Every laser's elevation, ring 0 the lowest."""
        out: list[float] = []
        for block in self.layers:
            step = (block.top_deg - block.bottom_deg) / max(block.count - 1, 1)
            out += [block.bottom_deg + i * step for i in range(block.count)]
        return sorted(out)


# The two sensor classes of the ARES shuttle (docs/design.md §3): the HDL-64E's two blocks of 32 lasers
# (+2° to −8.33° in 1/3° steps, −8.83° to −24.33° in 1/2° steps) and the VLP-16's ±15° in 2° steps.
LIDAR_MODELS: dict[str, LidarModel] = {
    "hdl64e": LidarModel(
        layers=[
            LidarLayers(count=32, top_deg=2.0, bottom_deg=-8.33),
            LidarLayers(count=32, top_deg=-8.83, bottom_deg=-24.33),
        ],
        azimuth_step_deg=0.17,
        min_range_m=0.9,
        max_range_m=120.0,
        range_sigma_m=0.02,
    ),
    "vlp16": LidarModel(
        layers=[LidarLayers(count=16, top_deg=15.0, bottom_deg=-15.0)],
        azimuth_step_deg=0.2,
        min_range_m=0.5,
        max_range_m=100.0,
        range_sigma_m=0.03,
    ),
}
LIDAR_NAMES = ("roof", "front_left", "front_right")


class LidarMount(Params):
    """One LiDAR on the vehicle: its class and its extrinsics in the vehicle frame (origin at the
    rear-axle centre on the road, x forward, y left, z up); rotations roll, pitch, yaw applied
    about z, then y, then x (ZYX). Pitch positive tilts the sensor nose down."""

    model: Literal["hdl64e", "vlp16"] = param(doc="sensor class (config.LIDAR_MODELS)")
    xyz_m: tuple[float, float, float] = param(doc="position", unit="m")
    rpy_deg: tuple[float, float, float] = param((0.0, 0.0, 0.0), "roll, pitch, yaw", unit="deg")

    def datasheet(self) -> LidarModel:
        return LIDAR_MODELS[self.model]


class VehicleProfile(Params):
    """A vehicle: geometry, limits, masses, the raw actuators the simulator models and the gains
    of the drive-by-wire board's inner loops (DBW paper §4-5)."""

    name: str
    wheelbase_m: float = param(doc="wheelbase S", unit="m", gt=0)
    track_m: float = param(doc="track L", unit="m", gt=0)
    wheel_radius_m: float = param(doc="wheel radius r", unit="m", gt=0)
    length_m: float = param(doc="body length", unit="m", gt=0)
    width_m: float = param(doc="body width", unit="m", gt=0)
    height_m: float | None = param(None, "body height (maker's figure; not used by the stack)", unit="m", gt=0)
    turn_radius_m: float | None = param(None, "smallest turning radius (maker's figure)", unit="m", gt=0)
    max_climb_pct: float | None = param(None, "steepest climb (maker's figure)", unit="%", gt=0)
    top_speed_mps: float | None = param(
        None, "the vehicle's own top speed; max_speed_mps is the stack's limit", unit="m/s", gt=0
    )
    k_cg: float = param(doc="centre of gravity: 0 front axle, 1 rear axle (ARES eqs. 3-5)", ge=0, le=1)
    steering_ratio: float = param(doc="steering-wheel angle / front wheel angle", gt=0)
    max_wheel_angle_rad: float = param(doc="largest front wheel angle", unit="rad", gt=0, lt=1.5)
    max_speed_mps: float = param(doc="top speed", unit="m/s", gt=0)
    max_accel_mps2: float = param(doc="largest acceleration", unit="m/s^2", gt=0)
    max_decel_mps2: float = param(doc="largest deceleration", unit="m/s^2", gt=0)
    max_lateral_accel_mps2: float = param(doc="largest lateral acceleration", unit="m/s^2", gt=0)
    empty_mass_kg: float = param(doc="mass without passengers", unit="kg", gt=0)
    passenger_mass_kg: float = param(doc="mass of one passenger", unit="kg", ge=0)
    seats: int = param(doc="passenger seats", ge=0)
    # Lateral dynamics of the simulator's dynamic bicycle (simulator/vehicle.py). The centre of
    # gravity along the wheelbase is k_cg above; the figures are for the empty vehicle.
    # Without them (a profile, or a recorded run, from before they existed) the simulator drives the
    # kinematic bicycle.
    yaw_inertia_kgm2: float | None = param(
        None, "yaw moment of inertia I_z, empty (scaled with the load's mass)", unit="kg m^2", gt=0
    )
    cornering_stiffness_front_n_per_rad: float | None = param(
        None, "front axle cornering stiffness C_f (both tyres): lateral force per rad of slip", unit="N/rad", gt=0
    )
    cornering_stiffness_rear_n_per_rad: float | None = param(
        None, "rear axle cornering stiffness C_r (both tyres)", unit="N/rad", gt=0
    )
    actuators: ActuatorParams
    dbw_pid: DbwPidParams
    ground_clearance_m: float = param(0.25, "underside of the body above the road", unit="m", ge=0)
    lidars: dict[Literal["roof", "front_left", "front_right"], LidarMount] = param(
        factory=dict, doc="the LiDARs and their extrinsics (ARES §3.4.1); `ares calibrate lidars` writes them"
    )

    # ---- the steering ratio (DBW eq. 13): the one place it converts ------------------------------
    def road_wheel_angle(self, steering_wheel_deg: float) -> float:
        """rad: the front (road) wheel angle δ = α / steering_ratio of a steering-wheel angle α in
        degrees, the unit the CAN bus reports. The ratio is linear: a rate in deg/s converts the same
        way, to rad/s."""
        return math.radians(steering_wheel_deg) / self.steering_ratio

    def steering_wheel_angle(self, road_wheel_rad: float) -> float:
        """deg: the steering-wheel angle α = steering_ratio · δ that turns the front wheels by δ rad
        (DBW eq. 13)."""
        return self.steering_ratio * math.degrees(road_wheel_rad)

    # ---- figures that follow from the above ------------------------------------------------------
    @property
    def max_curvature(self) -> float:
        """1/m: tan(largest wheel angle) / wheelbase."""
        return math.tan(self.max_wheel_angle_rad) / self.wheelbase_m

    @property
    def max_steering_wheel_deg(self) -> float:
        """deg: the steering wheel at the rack's end (the largest wheel angle)."""
        return self.steering_wheel_angle(self.max_wheel_angle_rad)

    @property
    def max_wheel_rate_rad_s(self) -> float:
        """rad/s: how fast the steering motor at full effort turns the front wheels."""
        return self.road_wheel_angle(self.actuators.steering.max_rate_deg_s)

    @property
    def max_curvature_rate(self) -> float:
        """1/m/s, at least: the steering motor's wheel rate over the wheelbase (d tan δ / dt >= dδ/dt)."""
        return self.max_wheel_rate_rad_s / self.wheelbase_m

    def curvature_of(self, steering_wheel_deg: float) -> float:
        """1/m: the curvature a steering-wheel angle drives (kinematic: tan(wheel angle) / wheelbase)."""
        return math.tan(self.road_wheel_angle(steering_wheel_deg)) / self.wheelbase_m

    @property
    def front_bumper_m(self) -> float:
        """The front bumper ahead of the rear axle: the wheelbase and half the overhangs."""
        return self.wheelbase_m + (self.length_m - self.wheelbase_m) / 2.0


def load_vehicle(name: str, overrides: Mapping[str, Any] | None = None) -> VehicleProfile:
    path = named_file("vehicles", name)
    data = deep_merge(load_yaml(path), dict(overrides or {}))
    return validated(VehicleProfile, data, str(path))
