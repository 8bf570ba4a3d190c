"""Model predictive control on the kinematic model (ARES paper §3.6.1, eqs. 11-13), with CasADi.

The path ahead (the path manager's poses) is taken into the vehicle's frame and fitted with a
cubic y = f(x). Over N steps of dt the model of eq. 11 predicts the vehicle from its state
(x, y, ψ, v) under the inputs (δ, a):

    x'   = x + v cos(ψ) dt            y'  = y + v sin(ψ) dt
    ψ'   = ψ + v tan(δ) / L dt        v'  = v + a dt
    cte  = f(x) − y                   eψ  = ψ − atan(f'(x))

(the paper's v/L_f·δ is the small-angle form of v·tan(δ)/L for a reference point on the rear
axle, which is ours; cte and eψ are written as functions of the state rather than as two more
states: the same thing, two fewer equality constraints). The inputs are bounded as in eq. 12,
with the vehicle profile's figures: |δ| <= the largest wheel angle, a within its acceleration and
deceleration, and δ changes no faster than the steering motor turns (a bumpless hand-over needs
it: the first step may move δ only as far as the actuator can from where the wheels are). The
cost is eq. 13 with every reference 0 but the speed's, which is the path's speed limit at the
distance each step is predicted to reach:

    J = Σ_{t=1..N} w_cte cte_t² + w_eψ eψ_t² + w_v (v_t − v_ref,t)²
        + Σ_{t=0..N−1} w_δ δ_t² + w_a a_t²
        + Σ_{t=1..N−1} w_rate_δ (δ_t − δ_{t−1})² + w_rate_a (a_t − a_{t−1})²

Dead time: a command reaches the wheels after the actuators' transport delays (the steering
motor's, the traction controller's). The problem is therefore solved from the state predicted
that far ahead with the commands already sent, so that its first input is the one that will be
acting then.

Each solve starts from the previous solution shifted by one step (warm start). A solve that
fails, or that runs over max_solve_ms, is answered with the previous solution shifted instead,
while it lasts; after max_reused such answers in a row the controller asks for a hand-over
(`handover`): the control manager then forwards its fallback.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import casadi as ca
import numpy as np

from ares.config import Params, VehicleProfile, param

poly = np.polynomial.polynomial


class MpcParams(Params):
    """The MPC's horizon, weights (eq. 13) and solver budget."""
    rate_hz: float = param(10.0, "solves per second", unit="Hz", gt=0)
    horizon_steps: int = param(12, "N: steps predicted", ge=2, le=60)
    step_s: float = param(0.15, "dt: the model's step", unit="s", gt=0)
    w_cte: float = param(200.0, "eq. 13: weight of the cross-track error", unit="1/m^2", ge=0)
    w_epsi: float = param(200.0, "eq. 13: weight of the heading error", unit="1/rad^2", ge=0)
    w_v: float = param(1.0, "eq. 13: weight of the speed error", unit="s^2/m^2", ge=0)
    w_delta: float = param(1.0, "eq. 13: weight of the wheel angle", unit="1/rad^2", ge=0)
    w_accel: float = param(1.0, "eq. 13: weight of the acceleration", unit="s^4/m^2", ge=0)
    w_delta_rate: float = param(100.0, "eq. 13: weight of the change of wheel angle between steps",
                                unit="1/rad^2", ge=0)
    w_accel_rate: float = param(10.0, "eq. 13: weight of the change of acceleration between steps",
                                unit="s^4/m^2", ge=0)
    path_min_reach_m: float = param(6.0, "the path is fitted at least this far ahead (the horizon's reach at "
                                          "walking pace is a few metres: too short to fit a cubic)", unit="m", gt=0)
    compensate_dead_time: bool = param(True, "solve from the state the actuators' dead time ahead")
    max_solve_ms: float = param(60.0, "a solve taking longer counts as failed (its answer would be late)",
                                unit="ms", gt=0)
    max_reused: int = param(3, "failed solves in a row answered with the previous solution, shifted; one more "
                               "and the MPC asks for a hand-over", ge=0)


@dataclass(frozen=True)
class VehicleState:
    """Where the vehicle is (any planar frame: the path's poses must be in the same one)."""
    x: float
    y: float
    yaw: float
    v: float
    delta: float = 0.0          # front wheel angle now, rad
    accel: float = 0.0          # the acceleration last commanded, m/s²


@dataclass(frozen=True)
class MpcCommand:
    ok: bool                    # a fresh solve (False: reused, or nothing to give)
    handover: bool              # too many failures in a row: the fallback should drive
    delta: float                # wheel angle to command, rad
    accel: float                # acceleration to command, m/s²
    v: float                    # speed to command: one step ahead, m/s
    kappa: float                # curvature to command: tan(δ) / L, 1/m
    predicted_x: np.ndarray     # (N + 1,) the predicted trajectory, in the state's frame
    predicted_y: np.ndarray
    cte: float                  # cross-track error now (from the fitted path), + vehicle right of it
    epsi: float                 # heading error now, rad
    solve_ms: float
    status: str                 # the solver's return status, or why nothing was solved
    reused: int                 # previous solutions reused in a row


def predict(x, y, yaw, v, delta, accel, dt: float, wheelbase: float, steps: int = 1):
    """Eq. 11's motion (the kinematic model), `steps` steps of dt; numpy or CasADi values."""
    trig = ca if isinstance(yaw, ca.MX) else math
    for _ in range(steps):
        x, y, yaw, v = (x + v * trig.cos(yaw) * dt, y + v * trig.sin(yaw) * dt,
                        yaw + v * trig.tan(delta) / wheelbase * dt, v + accel * dt)
    return x, y, yaw, v


class Mpc:
    """One MPC for one vehicle: the problem is built once; `solve` is called each cycle."""

    def __init__(self, vehicle: VehicleProfile, params: MpcParams | None = None):
        self.params = p = params or MpcParams()
        self.wheelbase = vehicle.wheelbase_m
        self.max_delta = vehicle.max_wheel_angle_rad
        self.max_accel, self.max_decel = vehicle.max_accel_mps2, vehicle.max_decel_mps2
        self.max_speed = vehicle.max_speed_mps
        steering = vehicle.actuators.steering
        self.max_delta_step = math.radians(steering.max_rate_deg_s) / vehicle.steering_ratio * p.step_s
        self.steer_dead_s = steering.dead_time_s
        self.traction_dead_s = vehicle.actuators.traction.dead_time_s
        self.failures = 0                       # failed solves since start (counted for the status)
        self.reused = 0                         # ... in a row
        self._previous: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None   # (X, U, start) of the last good solve
        self._sent_delta: float | None = None   # the wheel angle last commanded
        self._build()

    # ---- the problem (once) -------------------------------------------------------------------
    def _build(self) -> None:
        p, n, dt, wb = self.params, self.params.horizon_steps, self.params.step_s, self.wheelbase
        opti = ca.Opti()
        X = opti.variable(4, n + 1)             # x, y, ψ, v
        U = opti.variable(2, n)                 # δ, a
        x0 = opti.parameter(4)
        delta_now = opti.parameter()
        coef = opti.parameter(4)                # the path y = f(x), cubic, lowest order first
        v_ref = opti.parameter(n)
        opti.subject_to(X[:, 0] == x0)
        cost = 0
        for t in range(n):
            nxt = predict(X[0, t], X[1, t], X[2, t], X[3, t], U[0, t], U[1, t], dt, wb)
            opti.subject_to(X[:, t + 1] == ca.vertcat(*nxt))
            xs, ys, yaw, v = X[0, t + 1], X[1, t + 1], X[2, t + 1], X[3, t + 1]
            f = coef[0] + xs * (coef[1] + xs * (coef[2] + xs * coef[3]))
            slope = coef[1] + xs * (2 * coef[2] + xs * 3 * coef[3])
            cte, epsi = f - ys, yaw - ca.atan(slope)
            cost += p.w_cte * cte ** 2 + p.w_epsi * epsi ** 2 + p.w_v * (v - v_ref[t]) ** 2
            cost += p.w_delta * U[0, t] ** 2 + p.w_accel * U[1, t] ** 2
            if t > 0:
                cost += p.w_delta_rate * (U[0, t] - U[0, t - 1]) ** 2 + p.w_accel_rate * (U[1, t] - U[1, t - 1]) ** 2
        opti.minimize(cost)
        opti.subject_to(opti.bounded(-self.max_delta, U[0, :], self.max_delta))          # eq. 12
        opti.subject_to(opti.bounded(-self.max_decel, U[1, :], self.max_accel))
        opti.subject_to(opti.bounded(-self.max_delta_step, U[0, 0] - delta_now, self.max_delta_step))
        for t in range(1, n):
            opti.subject_to(opti.bounded(-self.max_delta_step, U[0, t] - U[0, t - 1], self.max_delta_step))
        opti.subject_to(X[3, :] >= 0)
        opti.solver("ipopt", {"print_time": False, "error_on_fail": False},
                    {"print_level": 0, "sb": "yes", "max_cpu_time": p.max_solve_ms / 1e3, "max_iter": 200,
                     "warm_start_init_point": "yes"})
        self._opti, self._X, self._U = opti, X, U
        self._x0, self._delta_now, self._coef, self._v_ref = x0, delta_now, coef, v_ref

    # ---- each cycle ---------------------------------------------------------------------------
    def solve(self, state: VehicleState, path_x, path_y, path_speed) -> MpcCommand:
        """One cycle: the path ahead (poses in the state's frame, from near the vehicle onwards, and
        the speed limit at each) → the command to send now."""
        p, n, dt = self.params, self.params.horizon_steps, self.params.step_s
        started = time.perf_counter()
        start = self._after_dead_time(state)
        # the path in the frame of the (predicted) vehicle: x ahead, y left
        c, s = math.cos(start[2]), math.sin(start[2])
        dx, dy = np.asarray(path_x, float) - start[0], np.asarray(path_y, float) - start[1]
        px, py = c * dx + s * dy, -s * dx + c * dy
        reach = max(p.path_min_reach_m, 1.5 * max(start[3], 1.0) * n * dt)
        use = (px >= -2.0) & (px <= reach)
        if use.sum() < 4 or np.ptp(px[use]) < 1.0:
            return self._fallback(state, started, "too little path ahead")
        coef = poly.polyfit(px[use], py[use], 3)
        along = np.r_[0.0, np.cumsum(np.hypot(np.diff(px), np.diff(py)))]
        speed = np.minimum(np.asarray(path_speed, float), self.max_speed)
        reached = np.cumsum(np.full(n, max(start[3], 0.5) * dt))
        v_ref = np.interp(reached + along[np.argmin(np.hypot(px, py))], along, speed)

        opti = self._opti
        opti.set_value(self._x0, [0.0, 0.0, 0.0, start[3]])
        # the first step may move δ from where the wheels are headed (the last command) at the motor's rate
        now = state.delta if self._sent_delta is None else self._sent_delta
        opti.set_value(self._delta_now, float(np.clip(now, -self.max_delta, self.max_delta)))
        opti.set_value(self._coef, coef)
        opti.set_value(self._v_ref, v_ref)
        X0, U0 = self._initial_guess(start[3], state.delta)
        opti.set_initial(self._X, X0)
        opti.set_initial(self._U, U0)
        solution = opti.solve_limited()
        stats = opti.stats()
        solve_ms = (time.perf_counter() - started) * 1e3
        ok = bool(stats.get("success", False)) and solve_ms <= p.max_solve_ms
        if not ok:
            return self._fallback(state, started, stats.get("return_status", "failed"))
        X, U = np.asarray(solution.value(self._X)), np.asarray(solution.value(self._U))
        self._previous, self.reused = (X, U, start), 0
        return self._command(state, X, U, coef, True, solve_ms, stats.get("return_status", ""), start)

    def _after_dead_time(self, state: VehicleState) -> np.ndarray:
        """(x, y, ψ, v) when a command sent now starts to act: the last commands run meanwhile."""
        if not self.params.compensate_dead_time:
            return np.array([state.x, state.y, state.yaw, state.v])
        steps = 10
        x, y, yaw, v = state.x, state.y, state.yaw, state.v
        # the wheels are on their way to the last command sent (it was sent a cycle ago, at least a
        # dead time ago at 10 Hz): they turn at the motor's rate towards it
        delta, rate = state.delta, self.max_delta_step / self.params.step_s * self.steer_dead_s / steps
        target = state.delta if self._sent_delta is None else self._sent_delta
        for _ in range(steps):
            delta += float(np.clip(target - delta, -rate, rate))
            x, y, yaw, _ = predict(x, y, yaw, v, delta, 0.0, self.steer_dead_s / steps, self.wheelbase)
        v = max(0.0, v + state.accel * self.traction_dead_s)
        return np.array([x, y, yaw, v])

    def _initial_guess(self, v0: float, delta0: float) -> tuple[np.ndarray, np.ndarray]:
        """The previous solution shifted by one step (warm start), or a straight run at v0."""
        n, dt = self.params.horizon_steps, self.params.step_s
        if self._previous is not None:
            _, U, _ = self._previous
            U = np.c_[U[:, 1:], U[:, -1:]]
            # the previous prediction, re-expressed from the new start: re-simulate its inputs
            xs = [np.array([0.0, 0.0, 0.0, v0])]
            for t in range(n):
                xs.append(np.array(predict(*xs[-1], U[0, t], U[1, t], dt, self.wheelbase)))
            return np.array(xs).T, U
        X = np.zeros((4, n + 1))
        X[0] = v0 * dt * np.arange(n + 1)
        X[3] = v0
        U = np.zeros((2, n))
        U[0] = delta0
        return X, U

    def _fallback(self, state: VehicleState, started: float, why: str) -> MpcCommand:
        self.failures += 1
        self.reused += 1
        solve_ms = (time.perf_counter() - started) * 1e3
        if self._previous is None or self.reused > min(self.params.max_reused, self.params.horizon_steps - 1):
            return MpcCommand(False, True, state.delta, -self.max_decel, 0.0, math.tan(state.delta) / self.wheelbase,
                              np.zeros(0), np.zeros(0), math.nan, math.nan, solve_ms, why, self.reused)
        X, U, start = self._previous
        k = self.reused                         # steps since that solution was made
        shifted_U = np.c_[U[:, k:], np.repeat(U[:, -1:], k, axis=1)]
        shifted_X = np.c_[X[:, k:], np.repeat(X[:, -1:], k, axis=1)]
        return self._command(state, shifted_X, shifted_U, None, False, solve_ms, why, start)

    def _command(self, state, X, U, coef, ok, solve_ms, status, start) -> MpcCommand:
        delta, accel = float(U[0, 0]), float(U[1, 0])
        v = float(np.clip(X[3, 1], 0.0, self.max_speed))
        # the prediction in the state's frame (it was solved in the predicted start's frame)
        c, s = math.cos(start[2]), math.sin(start[2])
        px, py = start[0] + c * X[0] - s * X[1], start[1] + s * X[0] + c * X[1]
        cte = epsi = math.nan
        if coef is not None:
            cte = float(coef[0])                # f(0) − 0: + when the path lies left, vehicle right of it
            epsi = -math.atan(float(coef[1]))
        self._sent_delta = delta
        return MpcCommand(ok, False, delta, accel, v, math.tan(delta) / self.wheelbase, np.asarray(px),
                          np.asarray(py), cte, epsi, solve_ms, status, self.reused)
