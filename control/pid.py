"""Discrete PID of the drive-by-wire board (DBW paper §4.5, eqs. 4-8).

    error        = reference - measure                      (4)
    proportional = error · Kp                               (5)
    integral     = integral + error · Ki · Δt               (6)
    derivative   = (error - error_previous) · Kd / Δt       (7)
    control      = proportional + integral + derivative     (8)

The board runs one of these for the steering-wheel angle and one for the drive-wheel speed,
every Δt = 100 ms. The paper removed the derivative term after tuning (it worsened the
transient), so Kd defaults to 0; when it is used it can act on the measurement instead of
the error, so that a step of the reference does not kick the actuator.

Three additions a real board needs and the paper's equations leave out:
  * output limits: the effort is a normalised voltage in [-1, 1];
  * a feed-forward: an effort known without feedback (the speed loop's: the commanded speed's
    steady effort), added to (8) before the limits, so that the anti-windup below sees it;
  * anti-windup by clamping: while the output is saturated the integral stops growing in
    the direction that pushes further into saturation, and it is also bounded on its own.
    Without this, a long saturated stretch (a 200° steering step, a climb at full throttle)
    would wind the integral up and cause a large overshoot afterwards.

The integral is kept in effort units (Ki already multiplied in, as in eq. 6), so changing Ki
on the fly does not make the output jump.
"""

from __future__ import annotations

import math

from ares.core.config import PidGains


class PID:
    """The board's discrete PID (DBW eqs. 4-8): error, proportional, integral, derivative, their sum."""

    def __init__(
        self,
        kp: float,
        ki: float = 0.0,
        kd: float = 0.0,
        *,
        out_min: float = -1.0,
        out_max: float = 1.0,
        integral_limit: float | None = None,
        derivative_on_measurement: bool = True,
    ):
        if out_min >= out_max:
            raise ValueError(f"PID: out_min ({out_min}) must be below out_max ({out_max})")
        self.kp = float(kp)
        self.ki = float(ki)
        self.kd = float(kd)
        self.out_min = float(out_min)
        self.out_max = float(out_max)
        # By default the integral alone may use the whole output range, no more.
        self.integral_limit = max(abs(out_min), abs(out_max)) if integral_limit is None else abs(float(integral_limit))
        self.derivative_on_measurement = derivative_on_measurement
        self.reset()

    @classmethod
    def from_gains(cls, gains: PidGains) -> PID:
        """From a `dbw_pid.<loop>` block of a vehicle profile."""
        return cls(
            gains.kp,
            gains.ki,
            gains.kd,
            out_min=gains.out_min,
            out_max=gains.out_max,
            integral_limit=gains.integral_limit,
            derivative_on_measurement=gains.derivative_on_measurement,
        )

    def reset(self, integral: float = 0.0) -> None:
        """Forget the past: used when the board enters automatic mode or stops after a timeout.
        `integral`: where the integral starts (within its limit), when the effort to hold is known."""
        self.integral = min(max(float(integral), -self.integral_limit), self.integral_limit)
        self._prev_error: float | None = None
        self._prev_measurement: float | None = None
        self.last_output = 0.0

    def step(self, reference: float, measurement: float, dt: float, feedforward: float = 0.0) -> float:
        """One controller period: the effort to hold until the next call. `feedforward`, an effort
        known without feedback, is added before the output's limits, so the anti-windup sees it."""
        if not (dt > 0.0 and math.isfinite(dt)):
            raise ValueError(f"PID.step: dt must be a positive number, got {dt!r}")
        error = reference - measurement  # (4)
        proportional = self.kp * error  # (5)

        derivative = 0.0  # (7)
        if self.kd:
            if self.derivative_on_measurement:
                if self._prev_measurement is not None:
                    derivative = -self.kd * (measurement - self._prev_measurement) / dt
            elif self._prev_error is not None:
                derivative = self.kd * (error - self._prev_error) / dt
        self._prev_error = error
        self._prev_measurement = measurement

        candidate = self.integral + self.ki * error * dt  # (6)
        candidate = min(max(candidate, -self.integral_limit), self.integral_limit)
        unclamped = proportional + candidate + derivative + feedforward  # (8)
        # Clamping anti-windup: keep the new integral unless the output saturates and the
        # integral step pushes it further the same way.
        pushes_up = unclamped > self.out_max and candidate > self.integral
        pushes_down = unclamped < self.out_min and candidate < self.integral
        if not (pushes_up or pushes_down):
            self.integral = candidate
        output = proportional + self.integral + derivative + feedforward
        self.last_output = min(max(output, self.out_min), self.out_max)
        return self.last_output
