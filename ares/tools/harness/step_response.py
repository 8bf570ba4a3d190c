"""Closed-loop step responses of the drive-by-wire board, as the DBW paper measures them (§5.1).

A raw actuator of the simulator (simulator/actuators.py) under the board's 10 Hz PID
(control/pid.py): the check that the actuator parameters of a vehicle profile reproduce the
paper's measured steps (the figures are reported in ares/core/config/vehicles/*.yaml). It joins
the simulator and the controller in one process, which is why it lives in the composition
layer rather than in either of them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ares.core.config import PidGains, SteeringActuatorParams, TractionActuatorParams, VehicleProfile
from control.pid import PID
from simulator.actuators import SteeringActuator, TractionActuator
from simulator.vehicle import PHYSICS_DT, loaded_profile

PID_PERIOD_S = 0.1  # the DBW board's loop period (paper §4.5)


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
        return (
            f"{self.vehicle} {self.kind} ({self.passengers} passengers, step {step}): "
            f"dead time {self.dead_time_s * 1000:.0f} ms, rise {self.rise_time_s * 1000:.0f} ms, "
            f"overshoot {self.overshoot_pct:.2f} %, settling {self.settling_time_s:.2f} s, "
            f"steady-state error {self.steady_state_error:+.2f} {self.unit}"
        )


def measure_step(
    t: np.ndarray,
    y: np.ndarray,
    reference: float,
    y0: float = 0.0,
    settle_band: float = 0.02,
    tail_s: float = 1.0,
    motion_fraction: float = 0.01,
) -> dict:
    """Dead time, rise time, overshoot, settling time and steady-state error of a step."""
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    final = float(np.mean(y[t >= t[-1] - tail_s]))
    change = final - y0
    if change == 0.0:
        raise ValueError("the response did not move")
    progress = (y - y0) / change  # 0 at the start, 1 at steady state
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


def step_response(
    kind: str,
    vehicle_profile: VehicleProfile | str,
    passengers: int = 2,
    step: float | None = None,
    duration_s: float | None = None,
    gains: PidGains | None = None,
    actuator_params: SteeringActuatorParams | TractionActuatorParams | None = None,
    grade: float = 0.0,
    settle_band: float = 0.02,
) -> StepResponse:
    """Closed-loop step of one drive-by-wire loop as the board runs it.

    kind "steering": reference = `step` degrees of steering wheel (default 200°).
    kind "throttle": reference = `step` m/s of vehicle speed from standstill (default 3 m/s);
    the loop runs on the drive-wheel speed in rad/s (ω_w = v / r when straight), the
    variable the paper's board controls and reports.

    The PID (gains from the profile's `dbw_pid` block unless given) runs every 100 ms on the
    measurement sampled at that instant and its effort is held in between (zero-order hold);
    the physics runs at 100 Hz. The step is applied at t = 0, on a PID tick.
    """
    profile = loaded_profile(vehicle_profile)
    r = profile.wheel_radius_m
    if kind == "steering":
        loop_gains = gains if gains is not None else profile.dbw_pid.steering
        plant = SteeringActuator(actuator_params or profile.actuators.steering, profile.max_steering_wheel_deg)
        reference = 200.0 if step is None else float(step)
        duration_s = 3.0 if duration_s is None else duration_s
        unit = "deg"
        label = f"{reference:g} deg"

        def advance(u: float) -> float:
            return plant.step(u, PHYSICS_DT)
    elif kind == "throttle":
        loop_gains = gains if gains is not None else profile.dbw_pid.throttle
        plant = TractionActuator(
            actuator_params or profile.actuators.traction, profile.empty_mass_kg, profile.passenger_mass_kg, passengers
        )
        speed = 3.0 if step is None else float(step)
        reference = speed / r
        duration_s = 12.0 if duration_s is None else duration_s
        unit = "rad/s"
        label = f"0 -> {speed:g} m/s = {reference:.2f} rad/s"

        def advance(u: float) -> float:
            return plant.step(u, PHYSICS_DT, grade) / r
    else:
        raise ValueError(f"unknown loop {kind!r}: expected 'steering' or 'throttle'")

    pid = PID.from_gains(loop_gains)
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
    return StepResponse(
        kind=kind,
        vehicle=profile.name,
        passengers=passengers,
        unit=unit,
        reference=reference,
        t=t,
        y=y,
        effort=efforts,
        step_label=label,
        **figures,
    )
