"""Model predictive control on the kinematic model (ARES paper §3.6.1, eqs. 11-13), with CasADi.

Over N steps of dt the model of eq. 11 predicts the vehicle from its state (x, y, ψ, v) under
the inputs (δ, a), in the frame of the vehicle where the command will start to act:

    x' = x + v cos(ψ + Δψ/2) dt       y' = y + v sin(ψ + Δψ/2) dt
    ψ' = ψ + Δψ,  Δψ = v tan(δ) / L dt      v' = v + a dt

(the paper's v/L_f·δ is the small-angle form of v·tan(δ)/L for a reference point on the rear
axle, which is ours). Each step moves along the heading halfway through it (the paper's form
moves along the heading at its start): at dt = 0.15 s the difference settled the vehicle 2 cm
inside every bend of the tour. The errors of eq. 13 are measured against the path manager's path
ahead: each predicted step t has a reference pose (x_r, y_r, ψ_r) on the path, at the arc length where
the last solution predicted the vehicle to be at that step, and

    cte_t = −sin(ψ_r)(x_t − x_r) + cos(ψ_r)(y_t − y_r)      (across the path: + vehicle left)
    eψ_t  = ψ_t − ψ_r

The paper (after its source) fits a cubic y = f(x) to the path in the vehicle's frame instead;
that cannot follow a roundabout's S-bends at speed (a cubic over 15 m of entry, ring and exit),
whereas reference poses follow any path, and for a straight or an arc they give the same errors.
The inputs are bounded as in eq. 12 with the vehicle profile's figures: |δ| <= the largest wheel
angle, a within its acceleration and deceleration, v >= 0, and δ changes no faster than the
steering motor turns (the first step from where the wheels are headed: a bumpless hand-over). The
cost is eq. 13, with the speed reference the path's speed limit at each step:

    J = Σ_{t=1..N} w_cte(v0) cte_t² + w_eψ eψ_t² + w_v (v_t − v_ref,t)²
        + Σ_{t=0..N−1} w_δ δ_t² + w_a a_t²
        + Σ_{t=1..N−1} w_rate_δ (δ_t − δ_{t−1})² + w_rate_a (a_t − a_{t−1})²

(w_cte(v0) = w_cte · min(1, (v_full / v0)²): above v_full the cross-track weight falls with the
square of the speed, so that a centimetre off asks for the same yaw rate at any speed.)

The solver: a real-time iteration. J is a sum of squares of residuals r(U) of the inputs U (the
states follow from eq. 11, single shooting), so each Gauss-Newton step is the quadratic
programme min ½ ΔUᵀ JᵀJ ΔU + (Jᵀr)ᵀ ΔU under the (linear) constraints of eq. 12, which DAQP
solves in tens of microseconds. CasADi builds r, J and JᵀJ once, as compiled expression graphs.
Each cycle starts from the previous solution shifted by one step (warm start) and takes
`sqp_iterations` steps (the first solve, from a straight run, `first_iterations`): at 10 Hz the
optimum moves little between cycles, so one or two steps keep up with it.

Dead time: a command reaches the wheels after the actuators' transport delays (the steering
motor's, the traction controller's). The problem is therefore solved from the state predicted
that far ahead with the commands already sent, so that its first input is the one that will be
acting then.

A solve that fails (the QP solver's status, a non-finite answer, too little path ahead) or that
runs over max_solve_ms is answered with the previous solution shifted instead, while it lasts;
after max_reused such answers in a row the controller asks for a hand-over (`handover`): the
control manager then forwards its fallback.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import casadi as ca
import numpy as np

from ares.core.config import Params, VehicleProfile, param

poly = np.polynomial.polynomial


class MpcParams(Params):
    """The MPC's horizon, weights (eq. 13) and solver budget."""

    rate_hz: float = param(10.0, "solves per second", unit="Hz", gt=0)
    horizon_steps: int = param(12, "N: steps predicted", ge=2, le=60)
    step_s: float = param(0.15, "dt: the model's step", unit="s", gt=0)
    w_cte: float = param(
        200.0,
        "eq. 13: weight of the cross-track error, up to w_cte_full_speed_mps (300 weaves "
        "the Techs4AgeCar off the campus road leaving its first roundabout)",
        unit="1/m^2",
        ge=0,
    )
    w_cte_full_speed_mps: float = param(
        4.0,
        "faster, w_cte falls as 1/v²: the same weight asks the same correction "
        "in metres, which at twice the speed is a four times sharper turn, and "
        "the actuators' lag does not shrink",
        unit="m/s",
        gt=0,
    )
    w_epsi: float = param(200.0, "eq. 13: weight of the heading error", unit="1/rad^2", ge=0)
    w_v: float = param(1.0, "eq. 13: weight of the speed error", unit="s^2/m^2", ge=0)
    w_delta: float = param(1.0, "eq. 13: weight of the wheel angle", unit="1/rad^2", ge=0)
    w_accel: float = param(1.0, "eq. 13: weight of the acceleration", unit="s^4/m^2", ge=0)
    w_delta_rate: float = param(
        1000.0,
        "eq. 13: weight of the change of wheel angle between steps (1000 rather "
        "than 100: the stack's own latency, 0.1-0.2 s from pose to wheels, makes "
        "100 oscillate; docs/control.md)",
        unit="1/rad^2",
        ge=0,
    )
    w_accel_rate: float = param(
        10.0, "eq. 13: weight of the change of acceleration between steps", unit="s^4/m^2", ge=0
    )
    sqp_iterations: int = param(
        1, "Gauss-Newton steps per solve, from the shifted previous solution (1: the real-time iteration)", ge=1, le=50
    )
    first_iterations: int = param(8, "... and for a solve without a previous solution", ge=1, le=50)
    rejoin_band_m: float = param(
        0.15,
        "further from the path than this, the reference is a way back to it, not the path itself "
        "(the path from half a metre aside made the MPC stand, or weave lock to lock; docs/control.md)",
        unit="m",
        ge=0,
    )
    rejoin_length_m: float = param(
        4.0, "... L: the way back's length scale, at least (e ~ exp(-d / L) over the distance d ahead)", unit="m", gt=0
    )
    rejoin_speed_mps: float = param(
        2.0,
        "... on the way back, no faster than this (from twice the band; between the band and twice "
        "it, the cap falls from the path's limit): the steering turns further per metre when slower",
        unit="m/s",
        gt=0,
    )
    rejoin_turn_share: float = param(
        0.5,
        "... and longer if its first turn, beside the path's own, would ask more than this share "
        "of the largest curvature the vehicle steers",
        gt=0,
        le=1,
    )
    compensate_dead_time: bool = param(True, "solve from the state the actuators' dead time ahead")
    max_solve_ms: float = param(
        60.0, "a solve taking longer counts as failed (its answer would be late)", unit="ms", gt=0
    )
    max_reused: int = param(
        3,
        "failed solves in a row answered with the previous solution, shifted; one more "
        "and the MPC asks for a hand-over",
        ge=0,
    )


@dataclass(frozen=True)
class VehicleState:
    """Where the vehicle is (any planar frame: the path's poses must be in the same one)."""

    x: float
    y: float
    yaw: float
    v: float
    delta: float = 0.0  # front wheel angle now, rad
    accel: float = 0.0  # the acceleration last commanded, m/s²


@dataclass(frozen=True)
class MpcCommand:
    ok: bool  # a fresh solve (False: reused, or nothing to give)
    handover: bool  # too many failures in a row: the fallback should drive
    delta: float  # wheel angle to command, rad
    accel: float  # acceleration to command, m/s²
    v: float  # speed to command: one step ahead, m/s
    kappa: float  # curvature to command: tan(δ) / L, 1/m
    predicted_x: np.ndarray  # (N + 1,) the predicted trajectory, in the state's frame
    predicted_y: np.ndarray
    cte: float  # cross-track error now (from the fitted path), + vehicle right of it
    epsi: float  # heading error now, rad
    solve_ms: float
    status: str  # the solver's return status, or why nothing was solved
    reused: int  # previous solutions reused in a row


def predict(x, y, yaw, v, delta, accel, dt: float, wheelbase: float, steps: int = 1):
    """Eq. 11's motion (the kinematic model), `steps` steps of dt; numpy or CasADi values."""
    trig = ca if any(isinstance(value, (ca.SX, ca.MX)) for value in (yaw, delta)) else math
    for _ in range(steps):
        turn = v * trig.tan(delta) / wheelbase * dt
        # along the heading halfway through the step (an arc's chord): along the heading at the
        # step's start, every step would end outside the arc, and the plan, believing the vehicle
        # wider than it is, would settle it inside every bend (2 cm in the tour's 30 m bends)
        heading = yaw + 0.5 * turn
        x, y, yaw, v = (x + v * trig.cos(heading) * dt, y + v * trig.sin(heading) * dt, yaw + turn, v + accel * dt)
    return x, y, yaw, v


class Mpc:
    """One MPC for one vehicle (ARES eqs. 11-13: the model, the input bounds, the cost): the problem
    is built once; `solve` is called each cycle."""

    def __init__(self, vehicle: VehicleProfile, params: MpcParams | None = None):
        self.params = p = params or MpcParams()
        self.wheelbase = vehicle.wheelbase_m
        self.max_delta = vehicle.max_wheel_angle_rad
        self.max_accel, self.max_decel = vehicle.max_accel_mps2, vehicle.max_decel_mps2
        self.max_speed = vehicle.max_speed_mps
        self.max_kappa = vehicle.max_curvature
        steering = vehicle.actuators.steering
        self.wheel_rate = wheel_rate = vehicle.max_wheel_rate_rad_s
        self.max_delta_step = wheel_rate * p.step_s
        # between two solves the wheels turn only a cycle's worth: a first step asking for more would
        # be cut short by the actuator, and the next solve would
        # start from wheels that are not where it believes
        self.max_first_step = wheel_rate * min(p.step_s, 1.0 / p.rate_hz)
        self.steer_dead_s = steering.dead_time_s
        self.traction_dead_s = vehicle.actuators.traction.dead_time_s
        self.failures = 0  # failed solves since start (counted for the status)
        self.reused = 0  # ... in a row
        self._previous: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # (X, U, start) of the last good solve
        self._sent_delta: float | None = None  # the wheel angle last commanded
        self._limit_here = math.inf  # the path's speed limit where the vehicle is (last solve)
        self._build()

    # ---- the problem (once) -------------------------------------------------------------------
    def _build(self) -> None:
        """r(U; P), JᵀJ, Jᵀr and the rollout as CasADi functions; the constant constraint matrix;
        the QP solver. U = [δ_0..δ_{N−1}, a_0..a_{N−1}]; P = [v0, x_r(N), y_r(N), ψ_r(N), v_ref(N)]."""
        p, n, dt, wb = self.params, self.params.horizon_steps, self.params.step_s, self.wheelbase
        U = ca.SX.sym("U", 2 * n)
        P = ca.SX.sym("P", 1 + 4 * n)
        delta, accel = U[:n], U[n:]
        xr, yr, psir, vref = P[1 : 1 + n], P[1 + n : 1 + 2 * n], P[1 + 2 * n : 1 + 3 * n], P[1 + 3 * n :]
        x, y, yaw, v = ca.SX(0), ca.SX(0), ca.SX(0), P[0]
        states, residuals = [ca.vertcat(x, y, yaw, v)], []
        root_w_cte = math.sqrt(p.w_cte) * ca.fmin(1.0, p.w_cte_full_speed_mps / ca.fmax(P[0], 1e-3))
        for t in range(n):
            x, y, yaw, v = predict(x, y, yaw, v, delta[t], accel[t], dt, wb)
            states.append(ca.vertcat(x, y, yaw, v))
            cte = -ca.sin(psir[t]) * (x - xr[t]) + ca.cos(psir[t]) * (y - yr[t])
            residuals += [root_w_cte * cte, math.sqrt(p.w_epsi) * (yaw - psir[t]), math.sqrt(p.w_v) * (v - vref[t])]
        residuals += [
            math.sqrt(p.w_delta) * delta,
            math.sqrt(p.w_accel) * accel,
            math.sqrt(p.w_delta_rate) * ca.diff(delta),
            math.sqrt(p.w_accel_rate) * ca.diff(accel),
        ]
        r = ca.vertcat(*residuals)
        J = ca.jacobian(r, U)
        self._gauss_newton = ca.Function("gauss_newton", [U, P], [J.T @ J, J.T @ r, 0.5 * ca.sumsqr(r)])
        self._rollout = ca.Function("rollout", [U, P], [ca.horzcat(*states)])
        # linear constraints A·U: the steering rate (δ_0 − δ_now, δ_t − δ_{t−1}), then v_{t+1} = v0 + dt Σ a >= 0
        A = np.zeros((2 * n, 2 * n))
        A[0, 0] = 1.0
        for t in range(1, n):
            A[t, t], A[t, t - 1] = 1.0, -1.0
        A[n:, n:] = dt * np.tril(np.ones((n, n)))
        self._lbu = np.r_[np.full(n, -self.max_delta), np.full(n, -self.max_decel)]
        self._ubu = np.r_[np.full(n, self.max_delta), np.full(n, self.max_accel)]
        qp = ca.conic(
            "mpc_qp",
            "daqp",
            {"h": ca.Sparsity.dense(2 * n, 2 * n), "a": ca.Sparsity.dense(2 * n, 2 * n)},
            {"error_on_fail": False},
        )
        # one Gauss-Newton step as one compiled call (the QP data, the QP, the step, the new rollout):
        # from Python, each call costs more than the arithmetic in it
        U0, P0 = ca.MX.sym("U", 2 * n), ca.MX.sym("P", 1 + 4 * n)
        lba, uba = ca.MX.sym("lba", 2 * n), ca.MX.sym("uba", 2 * n)
        H, g, _ = self._gauss_newton(U0, P0)
        Adm = ca.DM(A)
        step = qp(
            h=H,
            g=g,
            a=Adm,
            lbx=ca.DM(self._lbu) - U0,
            ubx=ca.DM(self._ubu) - U0,
            lba=lba - ca.mtimes(Adm, U0),
            uba=uba - ca.mtimes(Adm, U0),
        )["x"]
        U1 = ca.fmin(ca.fmax(U0 + step, ca.DM(self._lbu)), ca.DM(self._ubu))
        self._step = ca.Function("gauss_newton_step", [U0, P0, lba, uba], [U1, self._rollout(U1, P0)])

    # ---- each cycle ---------------------------------------------------------------------------
    def solve(
        self, state: VehicleState, path_x, path_y, path_speed, latency_s: float = 0.0, delta_age_s: float = 0.0
    ) -> MpcCommand:
        """One cycle: the path ahead (poses in the state's frame, from near the vehicle onwards, and
        the speed limit at each) → the command to send now. `latency_s`: how much later than the
        state's time the command reaches the actuators (the state's age, the processes between);
        `delta_age_s`: how much older than the state the measured wheel angle is."""
        p, n = self.params, self.params.horizon_steps
        started = time.perf_counter()
        start, delta_start = self._after_dead_time(state, max(latency_s, 0.0), max(delta_age_s, 0.0))
        # the path in the frame of the (predicted) vehicle: x ahead, y left
        c, s = math.cos(start[2]), math.sin(start[2])
        dx, dy = np.asarray(path_x, float) - start[0], np.asarray(path_y, float) - start[1]
        px, py = c * dx + s * dy, -s * dx + c * dy
        if len(px) < 2 or float(np.hypot(px[-1] - px[0], py[-1] - py[0])) < 1.0:
            return self._fallback(state, started, "too little path ahead")
        path = _Polyline(px, py, np.minimum(np.asarray(path_speed, float), self.max_speed))
        path.rejoin(p.rejoin_band_m, p.rejoin_length_m, p.rejoin_turn_share * self.max_kappa, p.rejoin_speed_mps)
        first = self._previous is None
        U = self._initial_guess(start[3], state.delta)
        # the first step may move δ from where the wheels will be when it acts, at the motor's rate: at
        # 25 km/h the wheels lag the commands by a few tenths of a second when they turn at full rate,
        # and a plan that starts from the last command instead believes them further round than they are
        now = float(np.clip(delta_start, -self.max_delta, self.max_delta))
        lba = np.r_[now - self.max_first_step, np.full(n - 1, -self.max_delta_step), np.full(n, -start[3])]
        uba = np.r_[now + self.max_first_step, np.full(n - 1, self.max_delta_step), np.full(n, np.inf)]
        no_path = np.zeros(4 * n)
        X = np.asarray(self._rollout(U, np.r_[start[3], no_path]))
        for _ in range(p.first_iterations if first else p.sqp_iterations):
            U_dm, X_dm = self._step(U, np.r_[start[3], path.references(X[0, 1:], X[1, 1:])], lba, uba)
            U, X = np.asarray(U_dm).ravel(), np.asarray(X_dm)
            if not (np.all(np.isfinite(U)) and np.all(np.isfinite(X))):
                return self._fallback(state, started, "the QP gave no finite step")
        status = "solved"
        solve_ms = (time.perf_counter() - started) * 1e3
        if solve_ms > p.max_solve_ms:
            return self._fallback(state, started, f"late: {solve_ms:.1f} ms")
        self._previous, self.reused = (X, U.reshape(2, n), start), 0
        cte, epsi = path.errors_at_origin()
        self._limit_here = path.speed_at_vehicle()
        return self._command(state, X, U.reshape(2, n), (cte, epsi), True, solve_ms, status, start)

    def _after_dead_time(
        self, state: VehicleState, latency_s: float, delta_age_s: float = 0.0
    ) -> tuple[np.ndarray, float]:
        """(x, y, ψ, v) and δ when a command sent now starts to act: the last commands run meanwhile."""
        if not self.params.compensate_dead_time:
            return np.array([state.x, state.y, state.yaw, state.v]), state.delta
        steps = 4
        ahead = self.steer_dead_s + latency_s
        x, y, yaw, v = state.x, state.y, state.yaw, state.v
        # the wheels are on their way to the last command sent (it was sent a cycle ago, at least a
        # dead time ago at 10 Hz): they turn at the motor's rate towards it, since they were measured
        target = state.delta if self._sent_delta is None else self._sent_delta

        def turned(delta: float, seconds: float) -> float:
            return delta + float(np.clip(target - delta, -self.wheel_rate * seconds, self.wheel_rate * seconds))

        delta = turned(state.delta, delta_age_s)
        for _ in range(steps):
            delta = turned(delta, ahead / steps)
            x, y, yaw, _ = predict(x, y, yaw, v, delta, 0.0, ahead / steps, self.wheelbase)
        v = max(0.0, v + state.accel * (self.traction_dead_s + latency_s))
        return np.array([x, y, yaw, v]), delta

    def _initial_guess(self, v0: float, delta0: float) -> np.ndarray:
        """The previous solution's inputs shifted by one step (warm start), or holding the wheels
        where they are at v0."""
        n = self.params.horizon_steps
        if self._previous is not None:
            _, U, _ = self._previous
            return np.r_[U[0, 1:], U[0, -1], U[1, 1:], U[1, -1]]
        return np.r_[np.full(n, float(np.clip(delta0, -self.max_delta, self.max_delta))), np.zeros(n)]

    def _fallback(self, state: VehicleState, started: float, why: str) -> MpcCommand:
        self.failures += 1
        self.reused += 1
        solve_ms = (time.perf_counter() - started) * 1e3
        if self._previous is None or self.reused > min(self.params.max_reused, self.params.horizon_steps - 1):
            return MpcCommand(
                False,
                True,
                state.delta,
                -self.max_decel,
                0.0,
                math.tan(state.delta) / self.wheelbase,
                np.zeros(0),
                np.zeros(0),
                math.nan,
                math.nan,
                solve_ms,
                why,
                self.reused,
            )
        X, U, start = self._previous
        k = self.reused  # steps since that solution was made
        shifted_U = np.c_[U[:, k:], np.repeat(U[:, -1:], k, axis=1)]
        shifted_X = np.c_[X[:, k:], np.repeat(X[:, -1:], k, axis=1)]
        return self._command(state, shifted_X, shifted_U, None, False, solve_ms, why, start)

    def _command(self, state, X, U, errors, ok, solve_ms, status, start) -> MpcCommand:
        delta, accel = float(U[0, 0]), float(U[1, 0])
        # a speed limit is a limit: the plan's speed one step ahead, never above the path's limit here
        v = float(np.clip(X[3, 1], 0.0, min(self.max_speed, self._limit_here)))
        # the prediction in the state's frame (it was solved in the predicted start's frame)
        c, s = math.cos(start[2]), math.sin(start[2])
        px, py = start[0] + c * X[0] - s * X[1], start[1] + s * X[0] + c * X[1]
        cte, epsi = errors if errors is not None else (math.nan, math.nan)
        self._sent_delta = delta
        return MpcCommand(
            ok,
            False,
            delta,
            accel,
            v,
            math.tan(delta) / self.wheelbase,
            np.asarray(px),
            np.asarray(py),
            cte,
            epsi,
            solve_ms,
            status,
            self.reused,
        )


class _Polyline:
    """The path ahead in the solve's frame: arc length, headings (unwrapped), speed limits."""

    def __init__(self, x: np.ndarray, y: np.ndarray, speed: np.ndarray):
        keep = np.r_[True, np.hypot(np.diff(x), np.diff(y)) > 1e-6]  # repeated poses carry no heading
        self.x, self.y, self.speed = x[keep], y[keep], speed[keep]
        self.dx, self.dy = np.diff(self.x), np.diff(self.y)
        self.seg = np.hypot(self.dx, self.dy)
        self.s = np.r_[0.0, np.cumsum(self.seg)]
        self.yaw = np.unwrap(np.arctan2(self.dy, self.dx))  # per segment
        # the heading in the solve's frame lies near 0 where the vehicle is: unwrap around it
        k, self.s_vehicle = self._project(np.zeros(1), np.zeros(1))
        self.k_vehicle = int(k[0])
        self.yaw -= 2 * math.pi * round(float(self.yaw[self.k_vehicle]) / (2 * math.pi))
        self.rejoin_e0, self.rejoin_slope, self.rejoin_m = 0.0, 0.0, 1.0  # no way back: the path itself
        self.rejoin_speed = math.inf

    def rejoin(self, band_m: float, length_m: float, max_kappa: float, speed_mps: float) -> None:
        """References from where the vehicle is, as it is headed, back to the path. Over the
        distance d ahead, the references lie this far to the left of the path:

            e(d) = (e0 + (e0 / L + θ0) d) exp(−d / L)        (e(0) = e0, e'(0) = θ0)

        a critically damped approach from the vehicle's offset beyond `band_m` (e0) and its heading
        to the path (θ0). The references thus start `band_m` nearer the path than the vehicle, a
        pull the MPC keeps answering, instead of the whole offset: from half a metre aside and
        turned away, the path itself is a plan to stand (every start first adds to the offset)
        or, moving, to turn lock to lock. The curve is the same from anywhere on it, headed along
        it, so a later cycle asks for nothing new but that pull. Within the band the references
        are the path; the heading counts in proportion up to twice the band, so the references
        move smoothly as the vehicle leaves the band.

        L is `length_m` or, if the first turn e''(0) = −(2 θ0 / L + e0 / L²), beside the path's
        own curvature, would ask more than `max_kappa`, the length at which it asks just that (a
        way back the vehicle cannot steer is one it leaves at once: it crawls, or stands); but,
        when headed back already, no longer than e0 / |θ0|, beyond which the curve would itself
        cross the path. On the way back the speed is capped at `speed_mps`, in proportion too."""
        cte, epsi = self.errors_at_origin()
        left = -cte
        e0 = math.copysign(max(abs(left) - band_m, 0.0), left)
        if e0 == 0.0:
            return
        share = min(1.0, abs(e0) / band_m) if band_m > 0 else 1.0
        slope = share * math.tan(epsi)
        turn = -math.copysign(1.0, 2 * slope * length_m + e0)  # which way the way back first turns
        ahead = float(np.interp(self.s_vehicle[0] + 5.0, self.s[:-1], self.yaw))
        path_kappa = (ahead - float(self.yaw[self.k_vehicle])) / 5.0
        room = max(max_kappa - turn * path_kappa, 0.2 * max_kappa)
        needed = (abs(slope) + math.sqrt(slope * slope + room * abs(e0))) / room
        if slope * e0 < 0:
            needed = min(needed, abs(e0) / abs(slope))
        self.rejoin_e0, self.rejoin_slope, self.rejoin_m = e0, slope, max(length_m, needed)
        self.rejoin_speed = speed_mps + (1.0 - share) * float(np.max(self.speed))

    def _project(self, xs: np.ndarray, ys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For each point, the nearest segment and the arc length of the nearest point on it."""
        ex, ey = xs[:, None] - self.x[None, :-1], ys[:, None] - self.y[None, :-1]
        t = np.clip((ex * self.dx + ey * self.dy) / np.maximum(self.seg * self.seg, 1e-12), 0.0, 1.0)
        k = np.argmin(np.hypot(ex - t * self.dx, ey - t * self.dy), axis=1)
        rows = np.arange(len(xs))
        return k, self.s[k] + t[rows, k] * self.seg[k]

    def references(self, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
        """[x_r, y_r, ψ_r, v_ref] for predicted positions: the path at the arc length each projects
        to, never going back (beyond the path's end: extended along its last heading)."""
        _, s_at = self._project(np.asarray(xs), np.asarray(ys))
        s_at = np.maximum.accumulate(np.maximum(s_at, self.s_vehicle[0]))
        k = np.clip(np.searchsorted(self.s, s_at, side="right") - 1, 0, len(self.yaw) - 1)
        beyond = s_at - self.s[k]
        yaw = self.yaw[k]
        # the way back: an offset to the left of the path, and the slope of its approach
        d, e0, length = s_at - self.s_vehicle[0], self.rejoin_e0, self.rejoin_m
        fade = np.exp(-d / length)
        offset = (e0 + (e0 / length + self.rejoin_slope) * d) * fade
        slope = (self.rejoin_slope - (e0 / length + self.rejoin_slope) * d / length) * fade
        return np.concatenate(
            [
                self.x[k] + beyond * np.cos(yaw) - offset * np.sin(yaw),
                self.y[k] + beyond * np.sin(yaw) + offset * np.cos(yaw),
                yaw + np.arctan(slope),
                np.minimum(np.interp(s_at, self.s, self.speed), self.rejoin_speed),
            ]
        )

    def speed_at_vehicle(self) -> float:
        return float(np.interp(self.s_vehicle[0], self.s, self.speed))

    def errors_at_origin(self) -> tuple[float, float]:
        """(cte, eψ) of the vehicle at the origin heading 0: cte + when the vehicle is right of the path."""
        yaw = float(self.yaw[self.k_vehicle])
        s = float(self.s_vehicle[0])
        rx, ry = float(np.interp(s, self.s, self.x)), float(np.interp(s, self.s, self.y))
        left = math.sin(yaw) * rx - math.cos(yaw) * ry
        return -left, -yaw
