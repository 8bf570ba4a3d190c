"""The Unscented Kalman Filter that fuses GNSS, pose-derived yaw, gyro and wheel odometry
(ARES paper §3.1.1), on filterpy's UnscentedKalmanFilter with Van der Merwe sigma points.

State (horizontal motion of the rear-axle centre, where the GNSS antenna is):

    s = [x, y, ψ, v, ψ̇]      local east/north (m), yaw (rad, CCW from east), speed (m/s),
                              yaw rate (rad/s)

Altitude is not in the state: nothing in the horizontal model depends on it, and it has its
own sources (GNSS height, the IMU pitch times the speed), so a scalar filter beside this one
(perception.localization.AltitudeFilter) keeps the UKF at five states — eleven sigma points —
which is what makes it fast enough.

Process model (constant speed and yaw rate over dt, heading at the step's midpoint, which is
the exact chord direction of a circular arc):

    x' = x + v·cos(ψ + ψ̇·dt/2)·dt     y' = y + v·sin(ψ + ψ̇·dt/2)·dt
    ψ' = ψ + ψ̇·dt                    v' = v                 ψ̇' = ψ̇

Process noise Q = diag(q_pos, q_pos, q_yaw, q_v, q_yaw_rate)·dt: random walks whose rates are
config. q_v and q_yaw_rate let speed and yaw rate follow the driving; q_pos and q_yaw stand
for what the kinematic model does not know (tyre slip, bumps, wheel radius): they set how
fast the position and heading covariance grow when GNSS corrections are lost, which is what
the odometry manager's score reads.

Measurements (each an update with its own h, R and residual):

    GNSS position    z = [x, y]      R from the fix's variances. RTK fixes have millimetre white
                                     noise and are used as they are. A fix WITHOUT corrections
                                     has an error that wanders slowly (first-order Gauss-Markov,
                                     τ ≈ 40 s): consecutive fixes are not independent, and
                                     fusing each with its own variance would make the filter
                                     believe N fixes are √N times better than one, and let
                                     a wandering fix drag a good estimate along. Such fixes are
                                     (1) inflated: R·(1 + 2τ/Δt_fix), the number of fixes per
                                     correlation time, i.e. the N fixes of a correlation time
                                     together count as ~one independent fix; and (2) gated:
                                     rejected when the Mahalanobis distance of the innovation
                                     exceeds a χ²(2) threshold.
    Pose yaw         z = [ψ]         eqs. 1-2 (perception.yaw_from_poses); residual wrapped.
    Gyro yaw rate    z = [ψ̇]         the IMU's z rate. NOT the IMU's yaw: its magnetometer has
                                     a calibration offset (the paper's point); a gyro rate
                                     has no such offset.
    Wheel odometry   z = [v, ψ̇]      CAN speed and eq. 5's yaw rate (perception.wheel_odometry).

Angles: the yaw is wrapped in every residual (state and measurement), the weighted mean of
sigma points is taken as the first (central) sigma point plus the weighted mean of wrapped
differences from it (a plain weighted mean of angles near ±π would average +179° and
−179° to 0°), and the state is wrapped after each update.

Speed: filterpy's predict/update are used as they are; two of its hooks are replaced by
vectorised equivalents (process sigmas through fx as one array operation, the cross
variance as one matrix product), and the unscented transform is passed in (filterpy's
`UT=` argument) as a vectorised one. `ukf_step_benchmark(n)` times one predict + one update.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable

import numpy as np
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

from ares.core.config import Params, param
from ares.core.geometry import wrap_angle

X, Y, YAW, V, W = range(5)
DIM = 5

# chi-square(2 dof) quantiles, for the GNSS gate
CHI2_2DOF = {0.99: 9.21, 0.999: 13.82, 0.9999: 18.42}


class SigmaPointParams(Params):
    """Merwe's scaled sigma points; the defaults spread them sqrt(5) sigma, no negative weights."""

    alpha: float = param(1.0, "spread of the sigma points", gt=0)
    beta: float = param(2.0, "prior knowledge of the distribution (2: Gaussian)", ge=0)
    kappa: float = param(0.0, "secondary scaling")


class ProcessNoise(Params):
    """Random-walk rates of the UKF's Q = diag(...) * dt."""

    pos_m2_per_s: float = param(
        1.0e-3,
        "what the kinematic model misses (slip, bumps): the position covariance grows this fast without RTK",
        unit="m^2/s",
        gt=0,
    )
    yaw_rad2_per_s: float = param(1.0e-6, "heading random walk", unit="rad^2/s", gt=0)
    speed_m2_s3: float = param(0.5, "speed changes (accelerations ~0.7 m/s^2 over a second)", unit="m^2/s^3", gt=0)
    yaw_rate_rad2_s3: float = param(0.05, "yaw-rate changes (entering a curve)", unit="rad^2/s^3", gt=0)


class GnssUpdateParams(Params):
    float_correlation_s: float = param(
        40.0, "uncorrected fixes wander with this time constant: R *= 1 + 2 tau / interval", unit="s", gt=0
    )
    gate_chi2: float = param(CHI2_2DOF[0.999], "Mahalanobis gate for uncorrected fixes: chi-square(2) 99.9 %", gt=0)
    min_var_m2: float = param(1.0e-6, "floor on a fix's variance", unit="m^2", gt=0)


def correlated_inflation(interval_s: float | None, correlation_s: float, default_interval_s: float = 0.2) -> float:
    """Variance factor for measurements whose error is first-order Gauss-Markov with time
    constant τ, taken every Δt: 1 + 2τ/Δt, the number of them per correlation time (the
    effective number of independent samples of such a process is ~T / 2τ). The interval is
    clamped to [0.01, 10] s; None (no previous one) means the default receiver period."""
    dt = default_interval_s if interval_s is None else min(max(interval_s, 0.01), 10.0)
    return 1.0 + 2.0 * correlation_s / dt


# ---- residuals and the unscented transform (vectorised: rows are sigma points) -------------


def residual_state(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    d = np.subtract(a, b)
    d[..., YAW] = wrap_angle(d[..., YAW])
    return d


def residual_angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """For a measurement that is one angle."""
    return wrap_angle(np.subtract(a, b))


def add_state(x: np.ndarray, dx: np.ndarray) -> np.ndarray:
    out = x + dx
    out[YAW] = wrap_angle(out[YAW])
    return out


def unscented_transform(
    sigmas: np.ndarray,
    Wm: np.ndarray,
    Wc: np.ndarray,
    noise_cov: np.ndarray,
    mean_fn=None,
    residual_fn: Callable = np.subtract,
) -> tuple[np.ndarray, np.ndarray]:
    """Mean and covariance of transformed sigma points, angles handled by residual_fn.

    The mean is the central sigma point plus the weighted mean of the (wrapped) differences
    from it: correct for angles, and equal to the ordinary weighted mean otherwise (weights
    sum to one). Same signature as filterpy's, which lets it be passed as `UT=`.
    """
    ref = sigmas[0]
    mean = ref + Wm @ residual_fn(sigmas, ref)
    mean = residual_fn(mean, np.zeros_like(mean))  # wraps the angles of the mean into [-π, π)
    dev = residual_fn(sigmas, mean)
    cov = (dev.T * Wc) @ dev + noise_cov
    return mean, cov


class _VectorisedUKF(UnscentedKalmanFilter):
    """filterpy's UKF with two hooks vectorised (same results, fewer Python loops)."""

    def compute_process_sigmas(self, dt, fx=None, **fx_args):
        fx = self.fx if fx is None else fx
        sigmas = self.points_fn.sigma_points(self.x, self.P)
        self.sigmas_f = fx(sigmas, dt, **fx_args)

    def cross_variance(self, x, z, sigmas_f, sigmas_h):
        dx = self.residual_x(sigmas_f, x)
        dz = self.residual_z(sigmas_h, z)
        return (dx.T * self.Wc) @ dz


def _cholesky_upper(a: np.ndarray) -> np.ndarray:
    # MerweScaledSigmaPoints takes the rows of an upper factor U (P = UᵀU); numpy's Cholesky
    # gives the lower one, and is several times quicker than scipy's for a 5x5 matrix.
    return np.linalg.cholesky(a).T


def process_model(sigmas: np.ndarray, dt: float) -> np.ndarray:
    """CTRV step of every row (a state or a sigma point) over dt."""
    out = np.array(sigmas, dtype=float, copy=True)
    yaw, v, w = sigmas[..., YAW], sigmas[..., V], sigmas[..., W]
    heading = yaw + 0.5 * w * dt
    out[..., X] += v * np.cos(heading) * dt
    out[..., Y] += v * np.sin(heading) * dt
    out[..., YAW] = yaw + w * dt
    return out


# measurement functions: one sigma point -> predicted measurement
def _h_position(s):
    return s[0:2]


def _h_yaw(s):
    return s[2:3]


def _h_yaw_rate(s):
    return s[4:5]


def _h_wheel(s):
    return s[3:5]


class PoseUKF:
    """The five-state UKF with its measurement updates and its own clock.

    `t` is the time the state refers to. Each update first predicts to the measurement's
    time; a measurement older than `t` (it arrived late) is applied at `t`.
    """

    def __init__(
        self,
        sigma_points: SigmaPointParams = SigmaPointParams(),
        process_noise: ProcessNoise = ProcessNoise(),
        gnss: GnssUpdateParams = GnssUpdateParams(),
    ):
        points = MerweScaledSigmaPoints(
            DIM,
            alpha=sigma_points.alpha,
            beta=sigma_points.beta,
            kappa=sigma_points.kappa,
            sqrt_method=_cholesky_upper,
            subtract=np.subtract,
        )
        self.ukf = _VectorisedUKF(
            dim_x=DIM,
            dim_z=2,
            dt=0.02,
            hx=_h_position,
            fx=process_model,
            points=points,
            sqrt_fn=_cholesky_upper,
            residual_x=residual_state,
            state_add=add_state,
        )
        q = process_noise
        self.q_rate = np.diag([q.pos_m2_per_s, q.pos_m2_per_s, q.yaw_rad2_per_s, q.speed_m2_s3, q.yaw_rate_rad2_s3])
        self.float_correlation_s = gnss.float_correlation_s
        self.gate_chi2 = gnss.gate_chi2
        self.min_var_m2 = gnss.min_var_m2
        self.t: float | None = None
        self.ut_state = self._ut(residual_state)
        self.ut_plain = self._ut(np.subtract)
        self.ut_angle = self._ut(residual_angle)
        self.rejected_fixes = 0
        self._last_float_fix_t: float | None = None
        # the sigma points were drawn from the current (x, P): a measurement at the time of the
        # last prediction needs no prediction of its own (the filter already holds its prior)
        self._sigmas_current = False

    @staticmethod
    def _ut(residual_fn):
        def ut(sigmas, Wm, Wc, noise_cov, mean_fn=None, _residual=None):
            return unscented_transform(sigmas, Wm, Wc, noise_cov, None, residual_fn)

        return ut

    # ---- state ----------------------------------------------------------------------------
    @property
    def initialized(self) -> bool:
        return self.t is not None

    @property
    def x(self) -> np.ndarray:
        return self.ukf.x

    @property
    def P(self) -> np.ndarray:
        return self.ukf.P

    def initialize(
        self,
        t: float,
        x: float,
        y: float,
        yaw: float,
        v: float = 0.0,
        yaw_rate: float = 0.0,
        variances: tuple[float, float, float, float, float] = (1.0, 1.0, 1.0, 1.0, 0.1),
    ) -> None:
        self.ukf.x = np.array([x, y, wrap_angle(yaw), v, yaw_rate], dtype=float)
        self.ukf.P = np.diag(np.asarray(variances, dtype=float))
        self.t = float(t)
        self._sigmas_current = False
        self.rejected_fixes = 0

    def reset_yaw(self, yaw: float, variance: float) -> None:
        """A new guess of the heading, uncorrelated with the rest of the state."""
        self.ukf.x[YAW] = yaw
        self.ukf.P[YAW, :] = 0.0
        self.ukf.P[:, YAW] = 0.0
        self.ukf.P[YAW, YAW] = variance
        self._sigmas_current = False

    # ---- predict ----------------------------------------------------------------------------
    def predict_to(self, t: float) -> None:
        dt = max(t - self.t, 0.0)
        if dt == 0.0 and self._sigmas_current:
            return
        self.ukf.Q = self.q_rate * dt
        try:
            self.ukf.predict(dt, UT=self.ut_state)
        except np.linalg.LinAlgError:
            self._repair()
            self.ukf.predict(dt, UT=self.ut_state)
        self.t = max(self.t, t)
        self._sigmas_current = True

    def extrapolate(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """State and covariance at a later time without changing the filter (for publishing
        between measurements): the mean through the process model, the covariance grown by
        the process noise."""
        dt = max(t - self.t, 0.0)
        return process_model(self.ukf.x, dt), self.ukf.P + self.q_rate * dt

    def _repair(self) -> None:
        """Make P symmetric positive definite again after round-off."""
        P = 0.5 * (self.ukf.P + self.ukf.P.T)
        vals, vecs = np.linalg.eigh(P)
        self.ukf.P = (vecs * np.maximum(vals, 1e-12)) @ vecs.T

    def _update(self, t: float, z: np.ndarray, R: np.ndarray, hx, ut, residual_z) -> None:
        self.predict_to(t)
        self.ukf.residual_z = residual_z
        self.ukf.update(z, R=R, UT=ut, hx=hx)
        P = self.ukf.P
        self.ukf.P = 0.5 * (P + P.T)
        self._sigmas_current = False

    # ---- updates ----------------------------------------------------------------------------
    def update_position(self, t: float, x: float, y: float, var_x: float, var_y: float, rtk: bool) -> bool:
        """A GNSS fix; returns False when a fix without corrections was gated out."""
        R = np.diag([max(var_x, self.min_var_m2), max(var_y, self.min_var_m2)])
        if not rtk:
            interval = None if self._last_float_fix_t is None else t - self._last_float_fix_t
            R = R * correlated_inflation(interval, self.float_correlation_s)
            self._last_float_fix_t = t
            self.predict_to(t)
            innovation = np.array([x, y]) - self.ukf.x[:2]  # h is linear: exact from x, P
            S = self.ukf.P[:2, :2] + R
            if float(innovation @ np.linalg.solve(S, innovation)) > self.gate_chi2:
                self.rejected_fixes += 1
                return False
        else:
            self._last_float_fix_t = None
        self._update(t, np.array([x, y]), R, _h_position, self.ut_plain, np.subtract)
        return True

    def update_yaw(self, t: float, yaw: float, variance: float) -> None:
        self._update(t, np.array([yaw]), np.array([[variance]]), _h_yaw, self.ut_angle, residual_angle)

    def update_yaw_rate(self, t: float, yaw_rate: float, variance: float) -> None:
        self._update(t, np.array([yaw_rate]), np.array([[variance]]), _h_yaw_rate, self.ut_plain, np.subtract)

    def update_wheel(self, t: float, v: float, yaw_rate: float, var_v: float, var_yaw_rate: float) -> None:
        self._update(t, np.array([v, yaw_rate]), np.diag([var_v, var_yaw_rate]), _h_wheel, self.ut_plain, np.subtract)


# ---- benchmark -------------------------------------------------------------------------------


def ukf_step_benchmark(n: int = 2000, seed: int = 0) -> list[float]:
    """Wall seconds of each of n (predict + update) steps, cycling through the measurement
    kinds in the proportions the localization node sees them (IMU 50 Hz, CAN 20 Hz, GNSS and
    pose yaw 5 Hz), on a vehicle driving a circle."""
    rng = np.random.default_rng(seed)
    f = PoseUKF()
    f.initialize(0.0, 0.0, 0.0, 0.0, 3.0, 0.1, (0.01, 0.01, 0.01, 0.01, 0.01))
    kinds = ["imu"] * 10 + ["can"] * 4 + ["gnss", "yaw"]
    times: list[float] = []
    t = 0.0
    for i in range(n):
        t += 0.0125
        truth_yaw = 0.1 * t
        kind = kinds[i % len(kinds)]
        started = time.perf_counter()
        if kind == "imu":
            f.update_yaw_rate(t, 0.1 + 0.002 * rng.standard_normal(), 4e-6)
        elif kind == "can":
            f.update_wheel(t, 3.0 + 0.01 * rng.standard_normal(), 0.1, 1e-4, 1e-4)
        elif kind == "gnss":
            f.update_position(t, 30.0 * math.sin(truth_yaw), 30.0 * (1 - math.cos(truth_yaw)), 5e-5, 5e-5, True)
        else:
            f.update_yaw(t, wrap_angle(truth_yaw), 1e-4)
        times.append(time.perf_counter() - started)
    return times


if __name__ == "__main__":
    samples_ms = np.array(ukf_step_benchmark(5000)) * 1e3
    print(
        f"UKF predict + update: median {np.percentile(samples_ms, 50):.3f} ms, "
        f"p99 {np.percentile(samples_ms, 99):.3f} ms over {len(samples_ms)} steps"
    )
