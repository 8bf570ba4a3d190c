"""Raw actuators of the simulated vehicle.

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
ares/tools/harness/step_response.py runs that closed loop and measures the figures.
"""

from __future__ import annotations

import math
from collections import deque

from ares.core.config import SteeringActuatorParams, TractionActuatorParams

GRAVITY = 9.81  # m/s^2
AIR_DENSITY = 1.2  # kg/m^3


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

    def __init__(self, params: SteeringActuatorParams, limit_deg: float):
        self.dead_time_s = params.dead_time_s
        self.max_rate_deg_s = params.max_rate_deg_s
        self.time_constant_s = params.time_constant_s
        self.stiction_effort = params.stiction_effort
        self.limit_deg = float(limit_deg)
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

    def turn_by_hand(self, target_deg: float, dt: float, time_constant_s: float, max_rate_deg_s: float) -> float:
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
        at standstill; rolling backwards, the motor pushes forwards against the roll. The slip
        stiffness is why the closed loop depends only mildly on the load:
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

    def __init__(
        self, params: TractionActuatorParams, empty_mass_kg: float, passenger_mass_kg: float, passengers: int = 0
    ):
        self.dead_time_s = params.dead_time_s
        self.time_constant_s = params.time_constant_s
        self.full_effort_speed_mps = params.full_effort_speed_mps
        self.slip_stiffness = params.slip_stiffness_n_per_mps
        self.max_drive_force_n = params.max_drive_force_n
        self.max_regen_force_n = params.max_regen_force_n
        self.max_brake_force_n = params.max_brake_force_n
        self.parking_hold_force_n = params.parking_hold_force_n
        self.rolling_resistance = params.rolling_resistance
        self.drag_area_m2 = params.drag_area_m2
        self.empty_mass_kg = float(empty_mass_kg)
        self.passenger_mass_kg = float(passenger_mass_kg)
        self.passengers = int(passengers)
        self._delay = _TransportDelay(self.dead_time_s)
        self.effort = 0.0  # lagged effort acting on motor and brake
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
        friction = max(-self.effort, 0.0) * self.max_brake_force_n + self.rolling_resistance * m * GRAVITY * math.cos(
            slope
        )
        if v0 == 0.0 and self.effort <= 0.0:
            friction += self.parking_hold_force_n
        active = (
            self.motor_force(v0) - m * GRAVITY * math.sin(slope) - 0.5 * AIR_DENSITY * self.drag_area_m2 * v0 * abs(v0)
        )

        if v0 == 0.0 and abs(active) <= friction:
            v1 = 0.0  # held by brakes / rolling resistance
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
