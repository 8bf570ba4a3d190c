"""The simulated vehicle: VehiclePlant and the VehicleState it advances.

VehiclePlant puts the raw actuators (simulator/actuators.py) on a bicycle driving on a Route: a
dynamic bicycle with linear tyres (`lateral_step`), which blends into the kinematic bicycle at
walking speed, where the dynamic equations become singular. The position is that of the
rear-axle centre, as the ARES odometry of §3.1 and the bridge's Ackermann conversions assume.
On the route, the road height and grade come from the route's elevation profile at the
vehicle's arc length s, and the roughness of its surface shakes the body (simulator/road.py).

Frames and signs (right-handed, REP-103 / ISO 8855): local x east, y north, z up; yaw from the
x axis, counter-clockwise; body x forward, y left, z up. Hence pitch is positive NOSE DOWN:
climbing a grade gives a negative pitch (the `grade` field, dz/ds, has the intuitive sign).
A positive wheel/steering angle turns left.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from ares.core import config as ares_config
from ares.core.config import VehicleProfile
from ares.core.geometry import wrap_angle
from ares.core.route import Route
from simulator.actuators import SteeringActuator, TractionActuator
from simulator.params import SimParams
from simulator.road import grade_at, roughness_for

PHYSICS_DT = 0.01  # 100 Hz physics
# Below BLEND_LOW_MPS the plant is the kinematic bicycle, above BLEND_HIGH_MPS the dynamic one;
# in between their lateral states are mixed with a smoothstep, so nothing jumps.
BLEND_LOW_MPS = 1.5
BLEND_HIGH_MPS = 3.0


@dataclass(frozen=True)
class LateralParams:
    """The dynamic bicycle's figures: CG to front / rear axle, cornering stiffnesses, mass, I_z."""

    l_f: float
    l_r: float
    c_f: float | None  # None (no tyre figures in the profile): the kinematic bicycle at every speed
    c_r: float | None
    mass: float
    i_z: float | None

    @classmethod
    def of(cls, profile: VehicleProfile, mass_kg: float) -> LateralParams:
        """The profile's figures at a laden mass (the inertia grows with the mass)."""
        l_f = profile.k_cg * profile.wheelbase_m
        i_z = None if profile.yaw_inertia_kgm2 is None else profile.yaw_inertia_kgm2 * mass_kg / profile.empty_mass_kg
        return cls(
            l_f,
            profile.wheelbase_m - l_f,
            profile.cornering_stiffness_front_n_per_rad,
            profile.cornering_stiffness_rear_n_per_rad,
            mass_kg,
            i_z,
        )

    @property
    def dynamic(self) -> bool:
        return self.c_f is not None and self.c_r is not None and self.i_z is not None

    def understeer_gradient(self) -> float:
        """K (s^2/m^2) of the steady-state yaw rate r = v δ / (L (1 + K v^2))."""
        wheelbase = self.l_f + self.l_r
        return self.mass / wheelbase**2 * (self.l_r / self.c_f - self.l_f / self.c_r)


def lateral_step(p: LateralParams, v_y: float, r: float, v: float, delta: float, dt: float) -> tuple[float, float]:
    """One step of the lateral states (v_y at the CG, yaw rate r) at speed v and wheel angle δ.

    Dynamic bicycle, linear tyres (small angles, constant v):
        α_f = δ - (v_y + l_f r) / v        α_r = -(v_y - l_r r) / v
        F_f = C_f α_f                      F_r = C_r α_r
        m (dv_y/dt + v r) = F_f + F_r      I_z dr/dt = l_f F_f - l_r F_r
    Kinematic bicycle (no slip at the rear axle): r = v tan δ / L, v_y = l_r r.
    The dynamic system is stiff at low speed (time constants ~ m v / C), so it is integrated with
    implicit Euler (stable at any step, and its steady state is exact); below BLEND_LOW_MPS it
    hands over to the kinematic states, with a smoothstep weight up to BLEND_HIGH_MPS.
    """
    r_kin = v * math.tan(delta) / (p.l_f + p.l_r)
    v_y_kin = p.l_r * r_kin
    # Rolling backwards (v < 0) stays kinematic: the linear tyre model is for driving forwards.
    w = min(max((v - BLEND_LOW_MPS) / (BLEND_HIGH_MPS - BLEND_LOW_MPS), 0.0), 1.0)
    w = w * w * (3.0 - 2.0 * w)
    if w == 0.0 or not p.dynamic:
        return v_y_kin, r_kin
    # d[v_y, r]/dt = A [v_y, r] + B δ; implicit Euler: (I - dt A) x' = x + dt B δ.
    a11 = -(p.c_f + p.c_r) / (p.mass * v)
    a12 = -(p.c_f * p.l_f - p.c_r * p.l_r) / (p.mass * v) - v
    a21 = -(p.c_f * p.l_f - p.c_r * p.l_r) / (p.i_z * v)
    a22 = -(p.c_f * p.l_f**2 + p.c_r * p.l_r**2) / (p.i_z * v)
    b1, b2 = p.c_f / p.mass, p.c_f * p.l_f / p.i_z
    m11, m12, m21, m22 = 1.0 - dt * a11, -dt * a12, -dt * a21, 1.0 - dt * a22
    rhs1, rhs2 = v_y + dt * b1 * delta, r + dt * b2 * delta
    det = m11 * m22 - m12 * m21
    v_y_dyn = (rhs1 * m22 - m12 * rhs2) / det
    r_dyn = (m11 * rhs2 - m21 * rhs1) / det
    return w * v_y_dyn + (1.0 - w) * v_y_kin, w * r_dyn + (1.0 - w) * r_kin


def loaded_profile(profile: VehicleProfile | str) -> VehicleProfile:
    """A vehicle profile, given by its name in ares/core/config/vehicles or already loaded."""
    return ares_config.load_vehicle(profile) if isinstance(profile, str) else profile


@dataclass
class VehicleState:
    t: float = 0.0
    x: float = 0.0  # rear-axle centre, local frame (m)
    y: float = 0.0
    z: float = 0.0
    yaw: float = 0.0  # rad, CCW from x (east)
    pitch: float = 0.0  # rad, REP-103: positive nose down
    roll: float = 0.0
    v: float = 0.0  # longitudinal speed of the rear-axle centre (m/s)
    yaw_rate: float = 0.0  # rad/s
    lateral_velocity: float = 0.0  # v_y of the centre of gravity, body frame (m/s, + to the left)
    pitch_rate: float = 0.0  # rad/s
    accel: float = 0.0  # longitudinal acceleration dv/dt (m/s^2)
    lateral_accel: float = 0.0  # dv_y/dt + v · yaw_rate at the CG (m/s^2, positive to the left)
    vertical_accel: float = 0.0  # body bounce over the road (m/s^2), without gravity
    grade: float = 0.0  # slope of the road along the heading, dz/dx (positive uphill)
    steering_wheel_deg: float = 0.0
    wheel_angle_rad: float = 0.0  # front wheel angle δ = α / steering_ratio (VehicleProfile.road_wheel_angle)
    wheel_speed_rad_s: float = 0.0  # driven front wheels: v / (cos δ · r), DBW eq. 14
    s: float = 0.0  # progress along the route (m)
    odometer: float = 0.0  # distance travelled (m)
    steer_effort: float = 0.0  # efforts last applied by the board
    drive_effort: float = 0.0
    throttle_pedal: float = 0.0  # driver model: pedal positions in [0, 1]
    brake_pedal: float = 0.0
    steering_torque: bool = False  # a driver is forcing the steering wheel
    manual: bool = False  # the last step was driven by a human

    def as_dict(self) -> dict:
        return asdict(self)


def start_pose(route: Route, s: float = 0.0) -> tuple[float, float, float, float]:
    """(x, y, z, yaw) of a vehicle standing on the route at arc length s, facing along it."""
    return route.point_at(s)


class VehiclePlant:
    """The whole vehicle: actuators + dynamic bicycle on the route's 3-D road.

    `step()` is one physics step in automatic mode (efforts from the bridge's PIDs);
    `step_manual()` is one step with a human driving (pedals and steering wheel).
    """

    def __init__(
        self,
        route: Route,
        vehicle_profile: VehicleProfile | str,
        sim: SimParams = SimParams(),
        passengers: int | None = None,
        seed: int | None = None,
        s0: float = 0.0,
    ):
        profile = loaded_profile(vehicle_profile)
        self.route = route
        self.profile = profile
        self.sim = sim
        self.wheelbase_m = profile.wheelbase_m
        self.wheel_radius_m = profile.wheel_radius_m
        self.steering = SteeringActuator(profile.actuators.steering, profile.max_steering_wheel_deg)
        self.traction = TractionActuator(
            profile.actuators.traction,
            profile.empty_mass_kg,
            profile.passenger_mass_kg,
            sim.passengers if passengers is None else passengers,
        )
        self.driver = sim.driver
        self._lateral: LateralParams | None = None  # made again when the laden mass changes
        self.rng = np.random.default_rng(sim.seed if seed is None else seed)
        self.roughness = roughness_for(
            route, sim if seed is None else sim.model_copy(update={"seed": seed}), self.wheelbase_m
        )
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
        st.v = st.yaw_rate = st.lateral_velocity = st.pitch_rate = st.accel = st.lateral_accel = st.vertical_accel = 0.0
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

    def step_manual(
        self, throttle_pedal: float, brake_pedal: float, steering_wheel_target_deg: float, dt: float = PHYSICS_DT
    ) -> VehicleState:
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
            float(steering_wheel_target_deg),
            dt,
            self.driver.steering_time_constant_s,
            self.driver.steering_max_rate_deg_s,
        )
        effort = -brake if brake > 0.0 else throttle
        self.traction.step(effort, dt, st.grade)
        st.steer_effort, st.drive_effort = 0.0, effort
        st.throttle_pedal, st.brake_pedal = throttle, brake
        st.steering_torque = abs(steering_wheel_target_deg - before) > self.driver.torque_threshold_deg
        st.manual = True
        return self._advance(dt)

    def _advance(self, dt: float) -> VehicleState:
        """Bicycle (lateral_step) about the rear axle, then the road under the new position."""
        st = self.state
        v_prev = st.v
        v = self.traction.v
        delta = self.profile.road_wheel_angle(st.steering_wheel_deg)
        v_mid = 0.5 * (v_prev + v)
        v_h = v_mid * math.cos(math.atan(st.grade))  # s and x, y are horizontal distances
        lateral = self._lateral
        if lateral is None or lateral.mass != self.traction.mass_kg:  # passengers on or off
            lateral = self._lateral = LateralParams.of(self.profile, self.traction.mass_kg)
        v_y_prev = st.lateral_velocity
        v_y, yaw_rate = lateral_step(lateral, v_y_prev, st.yaw_rate, v_h, delta, dt)
        # The rear axle slides sideways at v_y - l_r r (zero for the kinematic bicycle): it moves
        # at the slip angle β off the heading. Exact arc for constant speed, slip and yaw rate
        # over the step, so long runs do not drift from the bicycle's true circle.
        v_y_rear = v_y - lateral.l_r * yaw_rate
        speed = math.hypot(v_h, v_y_rear)
        beta = math.atan2(v_y_rear, v_h) if speed > 1e-9 else 0.0
        new_yaw = st.yaw + yaw_rate * dt
        if abs(yaw_rate) > 1e-9:
            radius = speed / yaw_rate
            st.x += radius * (math.sin(new_yaw + beta) - math.sin(st.yaw + beta))
            st.y -= radius * (math.cos(new_yaw + beta) - math.cos(st.yaw + beta))
        else:
            st.x += speed * math.cos(st.yaw + beta) * dt
            st.y += speed * math.sin(st.yaw + beta) * dt
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
        st.lateral_velocity = v_y
        st.lateral_accel = (v_y - v_y_prev) / dt + v_h * yaw_rate
        st.wheel_angle_rad = delta
        st.wheel_speed_rad_s = v / (math.cos(delta) * self.wheel_radius_m)
        return st
