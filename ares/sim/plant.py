"""Physics of the simulated vehicle: raw actuators, kinematic bicycle on a 3-D road.

What the drive-by-wire bridge drives are the RAW actuators of the DBW paper (§4.1-4.2):

  * SteeringActuator: a DC motor on the steering column. Input: effort in [-1, 1] (the
    normalised voltage the board sends to the IBT-2 driver). Output: steering-wheel angle α
    in degrees; the front wheel turns α / steering_ratio (ratio 40, paper eq. 13).
  * TractionActuator: the AC traction motor's controller (positive effort, the throttle
    voltage) and the brake (negative effort). Output: longitudinal speed v, and with the
    steering the drive-wheel speed ω_w = v / (cos δ · r) (paper eq. 14: the front wheels
    are driven).

Both have a transport delay (paper §5.1: 100 ms steering, 320 ms throttle), a first-order
lag, and the steering has static friction. Their parameters live in the vehicle profile
(`actuators:` block) and were tuned so that the closed loop with the board's 10 Hz PID
(`dbw_pid:` block, control/pid.py) reproduces the step responses the paper measured;
`step_response()` runs that closed loop and measures the figures.

VehiclePlant puts them on a kinematic bicycle (rear-axle reference point, as the ARES
odometry of §3.1 and the bridge's Ackermann conversions assume) driving on a Route: the road
height and grade come from the route's elevation profile at the vehicle's arc length s.

Frames and signs (right-handed, REP-103 / ISO 8855): local x east, y north, z up; yaw from the
x axis, counter-clockwise; body x forward, y left, z up. Hence pitch is positive NOSE DOWN:
climbing a grade gives a negative pitch (the `grade` field, dz/ds, has the intuitive sign).
A positive wheel/steering angle turns left.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import asdict, dataclass, field
from typing import Mapping

import numpy as np

from ares import config as ares_config
from ares.route import Route
from control.pid import PID

GRAVITY = 9.81          # m/s^2
AIR_DENSITY = 1.2       # kg/m^3
PID_PERIOD_S = 0.1      # the DBW board's loop period (paper §4.5)
PHYSICS_DT = 0.01       # 100 Hz physics


def _vehicle(profile: Mapping | str) -> Mapping:
    return ares_config.load_vehicle(profile) if isinstance(profile, str) else profile


def _wrap_angle(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


class _TransportDelay:
    """A pure dead time: what goes in at time t comes out at t + delay.

    The effort in force at the start of a physics step holds for the whole step, so with a
    100 Hz physics a 100 ms delay is exactly ten steps.
    """

    def __init__(self, delay_s: float, initial: float = 0.0):
        self.delay_s = float(delay_s)
        self.t = 0.0
        self.output = initial
        self._queue: deque[tuple[float, float]] = deque()

    def __call__(self, value: float, dt: float) -> float:
        self._queue.append((self.t + self.delay_s, value))
        while self._queue and self._queue[0][0] <= self.t + 1e-9:
            self.output = self._queue.popleft()[1]
        self.t += dt
        return self.output

    def flush(self, value: float = 0.0) -> None:
        self._queue.clear()
        self.output = value


def _lag(current: float, target: float, tau: float, dt: float) -> float:
    """Exact first-order lag step (stable for any dt)."""
    if tau <= 0.0:
        return target
    return target + (current - target) * math.exp(-dt / tau)


# ---- steering ---------------------------------------------------------------------------

class SteeringActuator:
    """DC motor turning the steering column (the Opel Corsa power-steering motor of §4.1).

    effort --[dead time]--> stiction dead band --> motor speed (first-order lag, time
    constant τ, full effort = max_rate) --> ∫ --> α, clamped at ±steering_ratio·θ_max.

    The dead band is the static friction of the column: an effort smaller than
    `stiction_effort` does not move it. With the board's PID this leaves the steering wheel
    stopped wherever |Kp·error| falls below the band, which is the paper's ±4° steady-state
    error (±0.1° at the wheels).
    """

    def __init__(self, params: Mapping, steering_ratio: float, max_wheel_angle_rad: float):
        self.dead_time_s = float(params["dead_time_s"])
        self.max_rate_deg_s = float(params["max_rate_deg_s"])
        self.time_constant_s = float(params["time_constant_s"])
        self.stiction_effort = float(params["stiction_effort"])
        self.limit_deg = steering_ratio * math.degrees(max_wheel_angle_rad)
        self._delay = _TransportDelay(self.dead_time_s)
        self.angle_deg = 0.0
        self.rate_deg_s = 0.0

    def step(self, effort: float, dt: float) -> float:
        u = self._delay(min(max(float(effort), -1.0), 1.0), dt)
        # Static friction: only the part of the effort above the band turns the motor,
        # rescaled so that full effort still gives the full rate.
        drive = math.copysign(max(abs(u) - self.stiction_effort, 0.0), u) / (1.0 - self.stiction_effort)
        target = drive * self.max_rate_deg_s
        new_rate = _lag(self.rate_deg_s, target, self.time_constant_s, dt)
        self._integrate(0.5 * (self.rate_deg_s + new_rate), new_rate, dt)
        return self.angle_deg

    def turn_by_hand(self, target_deg: float, dt: float, time_constant_s: float,
                     max_rate_deg_s: float) -> float:
        """A driver turns the wheel (the motor is back-driven, the board's effort is ignored)."""
        self._delay(0.0, dt)  # keep the board's dead time running, with nothing in it
        rate = (target_deg - self.angle_deg) / max(time_constant_s, dt)
        rate = min(max(rate, -max_rate_deg_s), max_rate_deg_s)
        self._integrate(rate, rate, dt)
        return self.angle_deg

    def _integrate(self, mean_rate: float, new_rate: float, dt: float) -> None:
        angle = self.angle_deg + mean_rate * dt
        if abs(angle) >= self.limit_deg:
            # End stop of the rack: the column stops dead; it can only move back out.
            angle = math.copysign(self.limit_deg, angle)
            if new_rate * angle > 0.0:
                new_rate = 0.0
        self.angle_deg = angle
        self.rate_deg_s = new_rate

    def reset(self, angle_deg: float = 0.0) -> None:
        self.angle_deg = float(angle_deg)
        self.rate_deg_s = 0.0
        self._delay.flush()


# ---- traction ---------------------------------------------------------------------------

class TractionActuator:
    """AC traction motor, its controller and the brakes, driving the longitudinal speed.

    effort --[dead time]--> first-order lag (the controller's ramp) --> throttle = max(effort, 0),
    brake = max(−effort, 0):

      * The controller sets the induction motor's supply frequency, i.e. its synchronous speed,
        in proportion to the throttle: v_sync = throttle · full_effort_speed. The motor's torque
        grows with the slip, so the wheels push with F_motor = k_slip · (v_sync − v), up to the
        current limit F_max when driving and up to F_regen when it opposes the motion
        (regenerative braking, which the DBW paper found enough to slow the car). Released
        throttle (v_sync = 0) is therefore a gentle regenerative brake that fades to nothing
        at standstill; rolling backwards, the motor pushes forwards against the roll. The slip stiffness is why the closed loop depends only mildly on the load:
        the motor behaves much like a speed source; a heavier vehicle only slows its pole m/k_slip.
      * The friction brake adds brake · max_brake_force against the motion. Force is monotonic
        in effort, which keeps the board's PID loop well behaved through zero effort.
      * At standstill with no throttle an electromagnetic parking brake holds the vehicle (up
        to parking_hold_force), as on low-speed electric vehicles; throttle releases it.

        m · dv/dt = F_motor − F_brake·sgn(v) − c_rr·m·g·cos(φ)·sgn(v) − ½ρ·CdA·v·|v| − m·g·sin(φ)

    with m = empty mass + passengers · passenger mass and φ = atan(grade). Brakes and rolling
    resistance are friction: they oppose motion and can hold the vehicle still, but never push
    it backwards. Regeneration pulls towards v_sync ≥ 0 and never reverses the vehicle either.
    A throttle too weak for the slope lets the vehicle roll back, as it would.
    """

    def __init__(self, params: Mapping, empty_mass_kg: float, passenger_mass_kg: float,
                 passengers: int = 0):
        self.dead_time_s = float(params["dead_time_s"])
        self.time_constant_s = float(params["time_constant_s"])
        self.full_effort_speed_mps = float(params["full_effort_speed_mps"])
        self.slip_stiffness = float(params["slip_stiffness_n_per_mps"])
        self.max_drive_force_n = float(params["max_drive_force_n"])
        self.max_regen_force_n = float(params["max_regen_force_n"])
        self.max_brake_force_n = float(params["max_brake_force_n"])
        self.parking_hold_force_n = float(params.get("parking_hold_force_n", 0.0))
        self.rolling_resistance = float(params["rolling_resistance"])
        self.drag_area_m2 = float(params.get("drag_area_m2", 0.0))
        self.empty_mass_kg = float(empty_mass_kg)
        self.passenger_mass_kg = float(passenger_mass_kg)
        self.passengers = int(passengers)
        self._delay = _TransportDelay(self.dead_time_s)
        self.effort = 0.0        # lagged effort acting on motor and brake
        self.v = 0.0
        self.accel = 0.0

    @property
    def mass_kg(self) -> float:
        return self.empty_mass_kg + self.passengers * self.passenger_mass_kg

    def motor_force(self, v: float) -> float:
        v_sync = max(self.effort, 0.0) * self.full_effort_speed_mps
        force = self.slip_stiffness * (v_sync - v)
        if force < 0.0 and v > 0.0:
            # Running faster than synchronous: the motor generates (regenerative braking).
            return max(force, -self.max_regen_force_n)
        # Below synchronous speed, also when rolling backwards: it drives, up to its current limit.
        return max(min(force, self.max_drive_force_n), -self.max_drive_force_n)

    def step(self, effort: float, dt: float, grade: float = 0.0) -> float:
        u = self._delay(min(max(float(effort), -1.0), 1.0), dt)
        self.effort = _lag(self.effort, u, self.time_constant_s, dt)
        m = self.mass_kg
        slope = math.atan(grade)
        v0 = self.v
        # Friction-like forces: available to oppose motion (or to hold at standstill).
        friction = (max(-self.effort, 0.0) * self.max_brake_force_n
                    + self.rolling_resistance * m * GRAVITY * math.cos(slope))
        if v0 == 0.0 and self.effort <= 0.0:
            friction += self.parking_hold_force_n
        active = (self.motor_force(v0) - m * GRAVITY * math.sin(slope)
                  - 0.5 * AIR_DENSITY * self.drag_area_m2 * v0 * abs(v0))

        if v0 == 0.0 and abs(active) <= friction:
            v1 = 0.0                                    # held by brakes / rolling resistance
        else:
            direction = math.copysign(1.0, v0) if v0 != 0.0 else math.copysign(1.0, active)
            v1 = v0 + (active - direction * friction) / m * dt
            if v0 != 0.0 and v1 * v0 < 0.0:
                # The vehicle came to rest within this step: it stops there rather than being
                # pushed backwards by the brake; the next step decides whether it stays.
                v1 = 0.0
        self.accel = (v1 - v0) / dt
        self.v = v1
        return v1

    def reset(self, v: float = 0.0) -> None:
        self.v = float(v)
        self.effort = 0.0
        self.accel = 0.0
        self._delay.flush()


# ---- road roughness -------------------------------------------------------------------------

class RoadRoughness:
    """A random but repeatable road surface felt through the suspension.

    The surface height under the wheels is a sum of sinusoids in distance travelled, with
    random phases and wavelengths between the configured bounds, amplitudes growing with
    wavelength (longer undulations are larger, as in real road profiles) and scaled so the
    surface RMS is `sigma_m`. The body follows through a second-order suspension, which gives
    the IMU its vertical acceleration; the height difference between the front and rear axle
    tilts the body (pitch jitter). Nothing moves while the vehicle stands still.
    """

    N_WAVES = 12

    def __init__(self, sigma_m: float, wheelbase_m: float, wavelength_m: tuple[float, float],
                 natural_hz: float, damping_ratio: float, rng: np.random.Generator):
        self.wheelbase_m = wheelbase_m
        lam = np.geomspace(wavelength_m[0], wavelength_m[1], self.N_WAVES)
        self.k = 2.0 * np.pi / lam                       # rad per metre
        amp = lam / lam.max()
        rms = math.sqrt(float(np.sum(amp ** 2)) / 2.0)
        self.amp = amp * (sigma_m / rms if rms > 0 else 0.0)
        self.phase = rng.uniform(0.0, 2.0 * np.pi, self.N_WAVES)
        self.wn = 2.0 * math.pi * natural_hz
        self.zeta = damping_ratio
        self.z_body = 0.0          # body height over the mean road surface
        self.vz_body = 0.0
        self.az_body = 0.0

    def settle(self, distance_m: float) -> None:
        """Body at rest on the road at this distance (no bounce at standstill)."""
        self.z_body = self.height(distance_m)
        self.vz_body = 0.0
        self.az_body = 0.0

    def height(self, d: float) -> float:
        return float(np.sum(self.amp * np.sin(self.k * d + self.phase)))

    def slope(self, d: float) -> float:
        return float(np.sum(self.amp * self.k * np.cos(self.k * d + self.phase)))

    def step(self, distance_m: float, v: float, dt: float) -> None:
        h = self.height(distance_m)
        hdot = self.slope(distance_m) * v
        # Suspension: spring and damper between the road under the wheel and the body.
        self.az_body = (self.wn ** 2 * (h - self.z_body)
                        + 2.0 * self.zeta * self.wn * (hdot - self.vz_body))
        self.vz_body += self.az_body * dt            # semi-implicit Euler: stable at 100 Hz
        self.z_body += self.vz_body * dt

    def pitch_jitter(self, distance_m: float) -> float:
        """Body pitch from the surface height under the front and rear axles (REP-103 sign:
        front higher than rear is nose up, a negative pitch)."""
        front = self.height(distance_m)
        rear = self.height(distance_m - self.wheelbase_m)
        return -math.atan2(front - rear, self.wheelbase_m)


# ---- the vehicle ------------------------------------------------------------------------------

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


def _grade_at(route: Route, s: float) -> float:
    s = route.wrap_s(s)
    i = route.index_at(s)
    n = len(route.s)
    j = (i + 1) % n if route.closed else min(i + 1, n - 1)
    seg = (route.length if j == 0 else route.s[j]) - route.s[i]
    f = 0.0 if seg <= 0 else min(max((s - route.s[i]) / seg, 0.0), 1.0)
    return float(route.grade[i] + f * (route.grade[j] - route.grade[i]))


class VehiclePlant:
    """The whole vehicle: actuators + kinematic bicycle on the route's 3-D road.

    `step()` is one physics step in automatic mode (efforts from the bridge's PIDs);
    `step_manual()` is one step with a human driving (pedals and steering wheel).
    """

    def __init__(self, route: Route, vehicle_profile: Mapping | str,
                 sim_cfg: Mapping | None = None, passengers: int | None = None,
                 seed: int | None = None, s0: float = 0.0):
        profile = _vehicle(vehicle_profile)
        sim = dict(sim_cfg) if sim_cfg is not None else ares_config.stack_defaults()["sim"]
        self.route = route
        self.profile = profile
        self.sim_cfg = sim
        self.wheelbase_m = float(profile["wheelbase_m"])
        self.wheel_radius_m = float(profile["wheel_radius_m"])
        self.steering_ratio = float(profile.get("steering_ratio", 40.0))
        act = profile["actuators"]
        self.steering = SteeringActuator(act["steering"], self.steering_ratio,
                                         float(profile["max_wheel_angle_rad"]))
        n_pax = int(sim.get("passengers", 0) if passengers is None else passengers)
        self.traction = TractionActuator(act["traction"], profile["empty_mass_kg"],
                                         profile["passenger_mass_kg"], n_pax)
        driver = sim.get("driver", {})
        self.driver_steer_tau_s = float(driver.get("steering_time_constant_s", 0.3))
        self.driver_steer_max_rate = float(driver.get("steering_max_rate_deg_s", 360.0))
        self.driver_torque_threshold_deg = float(driver.get("torque_threshold_deg", 2.0))
        self.rng = np.random.default_rng(sim.get("seed", 0) if seed is None else seed)
        susp = sim.get("suspension", {})
        self.roughness = RoadRoughness(
            float(sim.get("road_roughness_m", 0.0)), self.wheelbase_m,
            tuple(sim.get("roughness_wavelength_m", (1.5, 15.0))),
            float(susp.get("natural_hz", 1.5)), float(susp.get("damping_ratio", 0.35)), self.rng)
        self.state = VehicleState()
        self.place_on_route(s0)

    @classmethod
    def from_config(cls, cfg: Mapping, route: Route, s0: float = 0.0) -> "VehiclePlant":
        """From a run configuration (ares.config.build_run_config / current())."""
        return cls(route, cfg["vehicle_profile"], cfg["sim"], s0=s0)

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
        st.grade = _grade_at(self.route, st.s)
        self.roughness.settle(st.odometer)
        st.z = z + self.roughness.z_body
        st.pitch = -math.atan(st.grade) + self.roughness.pitch_jitter(st.odometer)
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
            float(steering_wheel_target_deg), dt, self.driver_steer_tau_s, self.driver_steer_max_rate)
        effort = -brake if brake > 0.0 else throttle
        self.traction.step(effort, dt, st.grade)
        st.steer_effort, st.drive_effort = 0.0, effort
        st.throttle_pedal, st.brake_pedal = throttle, brake
        st.steering_torque = (abs(steering_wheel_target_deg - before) > self.driver_torque_threshold_deg)
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
        st.yaw = _wrap_angle(new_yaw)
        st.odometer += abs(v_mid) * dt
        st.t += dt

        # Keep track of s with a hint: the tour crosses itself, the nearest point alone
        # could jump to the other pass.
        st.s, _, _ = self.route.project(st.x, st.y, s_hint=st.s)
        _, _, z_road, road_yaw = self.route.point_at(st.s)
        # The slope felt along the vehicle's heading (a vehicle driving the route the other
        # way round goes down where the route goes up).
        st.grade = _grade_at(self.route, st.s) * math.cos(st.yaw - road_yaw)

        self.roughness.step(st.odometer, v_mid, dt)
        pitch_prev = st.pitch
        st.z = z_road + self.roughness.z_body
        st.pitch = -math.atan(st.grade) + self.roughness.pitch_jitter(st.odometer)
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


# ---- closed-loop step response of the drive-by-wire board --------------------------------------

@dataclass
class StepResponse:
    """A simulated closed-loop step and the paper's figures measured on it (§5.1).

    Times are from the step instant. Rise time: until the response first reaches 90 % of its
    steady-state value (the paper's definition). Dead time: until it has moved by 1 % of
    the step. Overshoot: peak beyond the steady-state value, in % of the steady-state change.
    Settling: from the step until the response stays within ±`settle_band` (a fraction) of the
    steady-state value. Steady-state value: mean of the last second. Steady-state error:
    reference − steady-state value, in the loop's unit.
    """

    kind: str
    vehicle: str
    passengers: int
    unit: str
    reference: float
    dead_time_s: float
    rise_time_s: float
    overshoot_pct: float
    settling_time_s: float
    steady_state_error: float
    t: np.ndarray = field(repr=False)
    y: np.ndarray = field(repr=False)
    effort: np.ndarray = field(repr=False)
    step_label: str = ""

    def summary(self) -> str:
        step = self.step_label or f"{self.reference:g} {self.unit}"
        return (f"{self.vehicle} {self.kind} ({self.passengers} passengers, step {step}): "
                f"dead time {self.dead_time_s * 1000:.0f} ms, rise {self.rise_time_s * 1000:.0f} ms, "
                f"overshoot {self.overshoot_pct:.2f} %, settling {self.settling_time_s:.2f} s, "
                f"steady-state error {self.steady_state_error:+.2f} {self.unit}")


def measure_step(t: np.ndarray, y: np.ndarray, reference: float, y0: float = 0.0,
                 settle_band: float = 0.02, tail_s: float = 1.0,
                 motion_fraction: float = 0.01) -> dict:
    """Dead time, rise time, overshoot, settling time and steady-state error of a step."""
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    final = float(np.mean(y[t >= t[-1] - tail_s]))
    change = final - y0
    if change == 0.0:
        raise ValueError("the response did not move")
    progress = (y - y0) / change                 # 0 at the start, 1 at steady state
    moved = np.nonzero(np.abs(y - y0) > motion_fraction * abs(reference - y0))[0]
    risen = np.nonzero(progress >= 0.9)[0]
    outside = np.nonzero(np.abs(y - final) > settle_band * abs(change))[0]
    return {
        "dead_time_s": float(t[moved[0]]) if len(moved) else math.nan,
        "rise_time_s": float(t[risen[0]]) if len(risen) else math.nan,
        "overshoot_pct": max(float(np.max(progress)) - 1.0, 0.0) * 100.0,
        "settling_time_s": float(t[min(outside[-1] + 1, len(t) - 1)]) if len(outside) else 0.0,
        "steady_state_error": float(reference - final),
    }


def step_response(kind: str, vehicle_profile: Mapping | str, passengers: int = 2,
                  step: float | None = None, duration_s: float | None = None,
                  gains: Mapping | None = None, actuator_params: Mapping | None = None,
                  grade: float = 0.0, settle_band: float = 0.02) -> StepResponse:
    """Closed-loop step of one drive-by-wire loop as the board runs it.

    kind "steering": reference = `step` degrees of steering wheel (default 200°).
    kind "throttle": reference = `step` m/s of vehicle speed from standstill (default 3 m/s);
    the loop runs on the drive-wheel speed in rad/s (ω_w = v / r when straight), the
    variable the paper's board controls and reports.

    The PID (gains from the profile's `dbw_pid` block unless given) runs every 100 ms on the
    measurement sampled at that instant and its effort is held in between (zero-order hold);
    the physics runs at 100 Hz. The step is applied at t = 0, on a PID tick.
    """
    profile = _vehicle(vehicle_profile)
    acts = dict(profile.get("actuators", {}))
    if actuator_params is not None:
        acts = {**acts, kind if kind == "steering" else "traction": actuator_params}
    r = float(profile["wheel_radius_m"])
    if kind == "steering":
        loop_gains = gains if gains is not None else profile["dbw_pid"]["steering"]
        plant = SteeringActuator(acts["steering"], float(profile.get("steering_ratio", 40.0)),
                                 float(profile["max_wheel_angle_rad"]))
        reference = 200.0 if step is None else float(step)
        duration_s = 3.0 if duration_s is None else duration_s
        unit = "deg"
        label = f"{reference:g} deg"

        def advance(u: float) -> float:
            return plant.step(u, PHYSICS_DT)
    elif kind == "throttle":
        loop_gains = gains if gains is not None else profile["dbw_pid"]["throttle"]
        plant = TractionActuator(acts["traction"], profile["empty_mass_kg"],
                                 profile["passenger_mass_kg"], passengers)
        speed = 3.0 if step is None else float(step)
        reference = speed / r
        duration_s = 12.0 if duration_s is None else duration_s
        unit = "rad/s"
        label = f"0 -> {speed:g} m/s = {reference:.2f} rad/s"

        def advance(u: float) -> float:
            return plant.step(u, PHYSICS_DT, grade) / r
    else:
        raise ValueError(f"unknown loop {kind!r}: expected 'steering' or 'throttle'")

    pid = PID.from_config(loop_gains)
    ticks_per_pid = round(PID_PERIOD_S / PHYSICS_DT)
    n = round(duration_s / PHYSICS_DT)
    t = np.arange(n + 1) * PHYSICS_DT
    y = np.zeros(n + 1)
    efforts = np.zeros(n + 1)
    u = 0.0
    for k in range(n):
        if k % ticks_per_pid == 0:
            u = pid.step(reference, y[k], PID_PERIOD_S)
        efforts[k] = u
        y[k + 1] = advance(u)
    efforts[n] = u
    figures = measure_step(t, y, reference, settle_band=settle_band)
    return StepResponse(kind=kind, vehicle=str(profile.get("name", "?")), passengers=passengers,
                        unit=unit, reference=reference, t=t, y=y, effort=efforts, step_label=label,
                        **figures)
