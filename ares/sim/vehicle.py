"""The simulated vehicle: VehiclePlant and the VehicleState it advances.

VehiclePlant puts the raw actuators (ares/sim/actuators.py) on a kinematic bicycle (rear-axle
reference point, as the ARES odometry of §3.1 and the bridge's Ackermann conversions assume)
driving on a Route: the road height and grade come from the route's elevation profile at the
vehicle's arc length s, and the roughness of its surface shakes the body (ares/sim/road.py).

Frames and signs (right-handed, REP-103 / ISO 8855): local x east, y north, z up; yaw from the
x axis, counter-clockwise; body x forward, y left, z up. Hence pitch is positive NOSE DOWN:
climbing a grade gives a negative pitch (the `grade` field, dz/ds, has the intuitive sign).
A positive wheel/steering angle turns left.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from ares import config as ares_config
from ares.config import VehicleProfile
from ares.geometry import wrap_angle
from ares.route import Route
from ares.sim.actuators import SteeringActuator, TractionActuator
from ares.sim.params import SimParams
from ares.sim.road import grade_at, roughness_for

PHYSICS_DT = 0.01       # 100 Hz physics


def loaded_profile(profile: VehicleProfile | str) -> VehicleProfile:
    """A vehicle profile, given by its name in ares/config/vehicles or already loaded."""
    return ares_config.load_vehicle(profile) if isinstance(profile, str) else profile


@dataclass
class VehicleState:
    t: float = 0.0
    x: float = 0.0                  # rear-axle centre, local frame (m)
    y: float = 0.0
    z: float = 0.0
    yaw: float = 0.0                # rad, CCW from x (east)
    pitch: float = 0.0              # rad, REP-103: positive nose down
    roll: float = 0.0
    v: float = 0.0                  # longitudinal speed of the rear-axle centre (m/s)
    yaw_rate: float = 0.0           # rad/s
    pitch_rate: float = 0.0         # rad/s
    accel: float = 0.0              # longitudinal acceleration dv/dt (m/s^2)
    lateral_accel: float = 0.0      # v · yaw_rate (m/s^2, positive to the left)
    vertical_accel: float = 0.0     # body bounce over the road (m/s^2), without gravity
    grade: float = 0.0              # slope of the road along the heading, dz/dx (positive uphill)
    steering_wheel_deg: float = 0.0
    wheel_angle_rad: float = 0.0    # front wheel angle δ = α / steering_ratio
    wheel_speed_rad_s: float = 0.0  # driven front wheels: v / (cos δ · r), DBW eq. 14
    s: float = 0.0                  # progress along the route (m)
    odometer: float = 0.0           # distance travelled (m)
    steer_effort: float = 0.0       # efforts last applied by the board
    drive_effort: float = 0.0
    throttle_pedal: float = 0.0     # driver model: pedal positions in [0, 1]
    brake_pedal: float = 0.0
    steering_torque: bool = False   # a driver is forcing the steering wheel
    manual: bool = False            # the last step was driven by a human

    def as_dict(self) -> dict:
        return asdict(self)


def start_pose(route: Route, s: float = 0.0) -> tuple[float, float, float, float]:
    """(x, y, z, yaw) of a vehicle standing on the route at arc length s, facing along it."""
    return route.point_at(s)


class VehiclePlant:
    """The whole vehicle: actuators + kinematic bicycle on the route's 3-D road.

    `step()` is one physics step in automatic mode (efforts from the bridge's PIDs);
    `step_manual()` is one step with a human driving (pedals and steering wheel).
    """

    def __init__(self, route: Route, vehicle_profile: VehicleProfile | str, sim: SimParams = SimParams(),
                 passengers: int | None = None, seed: int | None = None, s0: float = 0.0):
        profile = loaded_profile(vehicle_profile)
        self.route = route
        self.profile = profile
        self.sim = sim
        self.wheelbase_m = profile.wheelbase_m
        self.wheel_radius_m = profile.wheel_radius_m
        self.steering_ratio = profile.steering_ratio
        self.steering = SteeringActuator(profile.actuators.steering, self.steering_ratio, profile.max_wheel_angle_rad)
        self.traction = TractionActuator(profile.actuators.traction, profile.empty_mass_kg, profile.passenger_mass_kg,
                                         sim.passengers if passengers is None else passengers)
        self.driver = sim.driver
        self.rng = np.random.default_rng(sim.seed if seed is None else seed)
        self.roughness = roughness_for(route, sim if seed is None else sim.model_copy(update={"seed": seed}),
                                       self.wheelbase_m)
        self.state = VehicleState()
        self.place_on_route(s0)

    @property
    def passengers(self) -> int:
        return self.traction.passengers

    @passengers.setter
    def passengers(self, n: int) -> None:
        self.traction.passengers = int(n)

    def place_on_route(self, s: float = 0.0) -> VehicleState:
        """Stand the vehicle still on the route at arc length s, facing along the route."""
        x, y, z, yaw = start_pose(self.route, s)
        self.steering.reset()
        self.traction.reset()
        st = self.state
        st.x, st.y, st.yaw = x, y, yaw
        st.s = self.route.wrap_s(s)
        st.grade = grade_at(self.route, st.s)
        self.roughness.settle(st.s)
        st.z = z + self.roughness.z_body
        st.pitch = -math.atan(st.grade) + self.roughness.pitch_jitter(st.s)
        st.v = st.yaw_rate = st.pitch_rate = st.accel = st.lateral_accel = st.vertical_accel = 0.0
        st.steering_wheel_deg = st.wheel_angle_rad = st.wheel_speed_rad_s = 0.0
        return st

    # ---- stepping -----------------------------------------------------------------------
    def step(self, steer_effort: float, drive_effort: float, dt: float = PHYSICS_DT) -> VehicleState:
        """One physics step with the board's efforts (automatic mode)."""
        st = self.state
        st.steering_wheel_deg = self.steering.step(steer_effort, dt)
        self.traction.step(drive_effort, dt, st.grade)
        st.steer_effort, st.drive_effort = float(steer_effort), float(drive_effort)
        st.throttle_pedal = st.brake_pedal = 0.0
        st.steering_torque = False
        st.manual = False
        return self._advance(dt)

    def step_manual(self, throttle_pedal: float, brake_pedal: float,
                    steering_wheel_target_deg: float, dt: float = PHYSICS_DT) -> VehicleState:
        """One physics step with a human driving.

        The driver turns the steering wheel towards `steering_wheel_target_deg` (a human arm:
        first-order approach, rate-limited); the pedals (0..1) act on the same motor
        controller and brake as the board's effort, the brake pedal taking precedence.
        The torque sensor in the column reports the driver while they are forcing the wheel.
        """
        st = self.state
        throttle = min(max(float(throttle_pedal), 0.0), 1.0)
        brake = min(max(float(brake_pedal), 0.0), 1.0)
        before = self.steering.angle_deg
        st.steering_wheel_deg = self.steering.turn_by_hand(
            float(steering_wheel_target_deg), dt, self.driver.steering_time_constant_s,
            self.driver.steering_max_rate_deg_s)
        effort = -brake if brake > 0.0 else throttle
        self.traction.step(effort, dt, st.grade)
        st.steer_effort, st.drive_effort = 0.0, effort
        st.throttle_pedal, st.brake_pedal = throttle, brake
        st.steering_torque = (abs(steering_wheel_target_deg - before) > self.driver.torque_threshold_deg)
        st.manual = True
        return self._advance(dt)

    def _advance(self, dt: float) -> VehicleState:
        """Kinematic bicycle about the rear axle, then the road under the new position."""
        st = self.state
        v_prev = st.v
        v = self.traction.v
        delta = math.radians(st.steering_wheel_deg) / self.steering_ratio
        v_mid = 0.5 * (v_prev + v)
        v_h = v_mid * math.cos(math.atan(st.grade))   # s and x, y are horizontal distances
        yaw_rate = v_h * math.tan(delta) / self.wheelbase_m
        # Exact arc for constant speed and steering over the step (a circle of radius
        # wheelbase / tan δ), so long runs do not drift from the bicycle's true circle.
        if abs(yaw_rate) > 1e-9:
            radius = v_h / yaw_rate
            new_yaw = st.yaw + yaw_rate * dt
            st.x += radius * (math.sin(new_yaw) - math.sin(st.yaw))
            st.y -= radius * (math.cos(new_yaw) - math.cos(st.yaw))
        else:
            new_yaw = st.yaw
            st.x += v_h * math.cos(st.yaw) * dt
            st.y += v_h * math.sin(st.yaw) * dt
        st.yaw = wrap_angle(new_yaw)
        st.odometer += abs(v_mid) * dt
        st.t += dt

        # Keep track of s with a hint: the tour crosses itself, the nearest point alone
        # could jump to the other pass.
        st.s, _, _ = self.route.project(st.x, st.y, s_hint=st.s)
        _, _, z_road, road_yaw = self.route.point_at(st.s)
        # The slope felt along the vehicle's heading (a vehicle driving the route the other
        # way round goes down where the route goes up).
        st.grade = grade_at(self.route, st.s) * math.cos(st.yaw - road_yaw)

        self.roughness.step(st.s, v_mid, dt)
        pitch_prev = st.pitch
        st.z = z_road + self.roughness.z_body
        st.pitch = -math.atan(st.grade) + self.roughness.pitch_jitter(st.s)
        st.roll = 0.0
        st.pitch_rate = (st.pitch - pitch_prev) / dt
        st.vertical_accel = self.roughness.az_body
        st.v = v
        st.accel = self.traction.accel
        st.yaw_rate = yaw_rate
        st.lateral_accel = v * yaw_rate
        st.wheel_angle_rad = delta
        st.wheel_speed_rad_s = v / (math.cos(delta) * self.wheel_radius_m)
        return st
