"""The odometry score: how far the pose estimate can be trusted (ARES paper §3.1.2, eq. 6).

    score(t) = 1 − a / (1 + exp(−b·(cov(t) − c)))                                   (eq. 6)

cov(t) is the largest eigenvalue of the pose's x-y covariance (m²), i.e. the variance along
the worst direction, the square of Pose.position_std_m. It does not depend on how the axes
are oriented (cov_xx + cov_yy would, only mildly, and would double-count a round covariance),
and an error ellipse stretched across the road counts fully.

With a = 1 the score falls from 1 (cov ≪ c) through 0.5 (cov = c) to 0 (cov ≫ c); b sets how
sharp the step is. The paper chose a, b, c "from experimental analysis where the covariance
starts rising due to ... DGPS lost signal, 4G lost signal"; `ares calibrate odometry`
(ares/tools/harness/odometry_score.py) repeats that experiment in simulation (docs/odometry_score.md).

A pose older than stale_after_s — or none at all — gets score 0 (no trust): a localization
that stopped talking is no better than one that is lost. The message then carries the last
pose's covariance (0 before the first pose) and the pose's age (for no pose at all: the time
since this manager started).
"""

from __future__ import annotations

import math

from scipy.special import expit

from ares.core.config import Params, param
from ares.core.messages import CorrectionsStatus, Pose


def score(cov: float, a: float, b: float, c: float) -> float:
    """Eq. 6, clamped to [0, 1]. Written with the logistic function expit(u) = 1/(1+e^(−u)),
    which neither overflows nor loses precision for any b·(cov − c)."""
    value = 1.0 - a * float(expit(b * (cov - c)))
    return min(max(value, 0.0), 1.0)


def pose_covariance(pose: Pose) -> float:
    """cov(t): the largest eigenvalue of [[cov_xx, cov_xy], [cov_xy, cov_yy]] (m²)."""
    mean = 0.5 * (pose.cov_xx + pose.cov_yy)
    half_diff = 0.5 * (pose.cov_xx - pose.cov_yy)
    return max(mean + math.hypot(half_diff, pose.cov_xy), 0.0)


class OdometryParams(Params):
    rate_hz: float = param(20.0, "loop and publishing rate", unit="Hz", gt=0)
    stale_after_s: float = param(
        1.0, "an older pose (or none) scores 0, as path_manager.pose_timeout_s", unit="s", gt=0
    )
    # From the simulated experiment of docs/odometry_score.md: covariance with RTK p99.9 3.1e-4 m²,
    # inside RTK-loss zones (after 2 s) p0.1 2.4e-3 m²; c between them, moved up from their
    # geometric mean (8.6e-4) so that a fix or two arriving late on a loaded machine does not read
    # as lost corrections: the score stays >= 0.9 for ~0.75 s without a fix and is <= 0.3 after ~1.4 s.
    a: float = param(1.0, "eq. 6: depth of the drop (1: the score spans 0..1)", ge=0, le=1)
    b: float = param(5000.0, "eq. 6: sharpness of the drop", unit="1/m^2", gt=0)
    c: float = param(1.4e-3, "eq. 6: covariance at which the score is 1 - a/2", unit="m^2", gt=0)


class OdometryScorer:
    """Eq. 6 with its parameters, and the staleness rule; no bus."""

    def __init__(self, a: float, b: float, c: float, stale_after_s: float):
        self.a, self.b, self.c = float(a), float(b), float(c)
        self.stale_after_s = float(stale_after_s)

    @classmethod
    def from_params(cls, params: OdometryParams) -> OdometryScorer:
        return cls(params.a, params.b, params.c, params.stale_after_s)

    def __call__(self, cov: float) -> float:
        return score(cov, self.a, self.b, self.c)

    def assess(self, pose: Pose | None, pose_age_s: float) -> tuple[float, float]:
        """(score, covariance) for the latest pose and its age."""
        if pose is None:
            return 0.0, 0.0
        cov = pose_covariance(pose)
        if not pose_age_s <= self.stale_after_s:
            return 0.0, cov
        return self(cov), cov


def no_rtk_cause(corrections: CorrectionsStatus | None, now: float) -> str:
    """Why a pose has no RTK, from the corrections' state: the papers' main cause is a 4G link lost."""
    if corrections is None or corrections.stale(now):
        return "no RTK (the corrections' state unknown)"
    outage = corrections.outage()
    if outage is not None:
        return f"no RTK: corrections {outage}"
    return "no RTK with fresh corrections (the sky blocked, or the receiver fixing again)"
