"""Odometry manager: how far the pose estimate can be trusted (ARES paper §3.1.2, eq. 6).

Inputs:   localization/pose (Pose with its covariance)
Outputs:  odometry/score (OdometryScore) at odometry_manager.rate_hz
Params:   odometry_manager.rate_hz, .stale_after_s, .a, .b, .c (see docs/odometry_score.md)

    score(t) = 1 − a / (1 + exp(−b·(cov(t) − c)))                                   (eq. 6)

cov(t) is the largest eigenvalue of the pose's x-y covariance (m²), i.e. the variance along
the worst direction, the square of Pose.position_std_m. It does not depend on how the axes
are oriented (cov_xx + cov_yy would, only mildly, and would double-count a round covariance),
and an error ellipse stretched across the road counts fully.

With a = 1 the score falls from 1 (cov ≪ c) through 0.5 (cov = c) to 0 (cov ≫ c); b sets how
sharp the step is. The paper chose a, b, c "from experimental analysis where the covariance
starts rising due to ... DGPS lost signal, 4G lost signal"; `calibrate()` repeats that
experiment in simulation (docs/odometry_score.md): it drives the tour in the closed loop,
records the covariance where RTK corrections are available and inside the RTK-loss zones,
places c between the two populations and picks b so that both are clearly classified.

A pose older than stale_after_s — or none at all — gets score 0 (no trust): a localization
that stopped talking is no better than one that is lost. The message then carries the last
pose's covariance (0 before the first pose) and the pose's age (for no pose at all: the time
since this manager started).
"""
from __future__ import annotations

import argparse
import json
import math
from typing import Mapping

import numpy as np
from scipy.special import expit

from ares.messages import OdometryScore, Pose
from ares.node import Node, run_node


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


class OdometryScorer:
    """Eq. 6 with its parameters, and the staleness rule; no bus."""

    def __init__(self, a: float, b: float, c: float, stale_after_s: float = 0.5):
        self.a, self.b, self.c = float(a), float(b), float(c)
        self.stale_after_s = float(stale_after_s)

    @classmethod
    def from_config(cls, params: Mapping) -> "OdometryScorer":
        return cls(params["a"], params["b"], params["c"], params.get("stale_after_s", 0.5))

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


class OdometryManager(Node):
    name = "odometry_manager"
    rate_key = "odometry_manager.rate_hz"
    default_rate_hz = 20.0

    def setup(self) -> None:
        self.scorer = OdometryScorer.from_config(self.cfg["odometry_manager"])
        self.pose = self.bus.subscribe("localization/pose")
        self.scores = self.bus.publisher("odometry/score")
        self.started = self.clock.now()

    def step(self, now: float) -> None:
        pose = self.pose.latest
        # age from the pose's own stamp: a pose delivered late is as old as it says
        age = (now - pose.t) if pose is not None else (now - self.started)
        age = max(age, 0.0)
        value, cov = self.scorer.assess(pose, age)
        self.scores.put(OdometryScore(t=now, score=value, covariance=cov, pose_age_s=age))


# ---- the paper's experiment, in simulation ------------------------------------------------------

def choose_parameters(cov_rtk: np.ndarray, cov_lost: np.ndarray, margin_score: float = 0.02,
                      low_q: float = 99.9, high_q: float = 0.1) -> dict:
    """a, b, c from the two covariance populations.

    a = 1 (the score spans 0..1). c sits between the populations, at the geometric mean of
    the RTK population's high percentile and the RTK-loss population's low percentile: they
    are orders of magnitude apart, so the midpoint is taken on a log scale. b makes the score
    at those two percentiles 1 − margin and margin respectively, using the nearer one (the
    sharper requirement): b = ln((1 − m) / m) / min(c − rtk_hi, lost_lo − c).
    """
    rtk_hi = float(np.percentile(cov_rtk, low_q))
    lost_lo = float(np.percentile(cov_lost, high_q))
    if not lost_lo > rtk_hi:
        raise ValueError(f"the populations overlap: RTK p{low_q} {rtk_hi:.3g} m² >= "
                         f"RTK-loss p{high_q} {lost_lo:.3g} m²; tune the filter's process noise first")
    c = math.sqrt(rtk_hi * lost_lo)
    b = math.log((1.0 - margin_score) / margin_score) / min(c - rtk_hi, lost_lo - c)
    return {"a": 1.0, "b": b, "c": c, "rtk_hi": rtk_hi, "lost_lo": lost_lo}


def _percentiles(values: np.ndarray) -> dict:
    qs = (0, 1, 5, 50, 95, 99, 99.9, 100)
    return {f"p{q:g}": float(np.percentile(values, q)) for q in qs} if len(values) else {}


def calibrate(laps: float = 1.0, seed: int | None = None, settle_s: float = 2.0, cfg: dict | None = None,
              verbose: bool = True) -> dict:
    """Re-run the experiment of docs/odometry_score.md and return (and print) the recommended
    a, b, c with the covariance percentiles of both populations.

    RTK population: every pose sample with RTK available for at least `settle_s` (after the
    start and after each RTK-loss zone). RTK-loss population: every sample at least `settle_s`
    inside an RTK-loss zone — the time the score is allowed to take to drop.
    """
    from ares.sim.closed_loop import run, settled_masks     # the closed loop imports this module
    result = run(laps=laps, seed=seed, cfg=cfg)
    rtk, lost = settled_masks(result["t"], result["rtk_available"], settle_s)
    cov = result["cov"]
    params = choose_parameters(cov[rtk], cov[lost])
    report = {"a": params["a"], "b": float(f"{params['b']:.4g}"), "c": float(f"{params['c']:.4g}"),
              "samples_rtk": int(rtk.sum()), "samples_rtk_loss": int(lost.sum()),
              "cov_rtk": _percentiles(cov[rtk]), "cov_rtk_loss": _percentiles(cov[lost]),
              "laps": laps, "seed": seed, "wall_s": result["wall_s"]}
    if verbose:
        print(json.dumps(report, indent=1))
        print(f"odometry_manager: a: {report['a']:g}  b: {report['b']:g}  c: {report['c']:g}")
    return report


def main() -> None:
    run_node(OdometryManager)


def calibrate_main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="Re-run the odometry-score experiment and print a, b, c.")
    parser.add_argument("--laps", type=float, default=1.0)
    parser.add_argument("--seed", type=int, default=None)
    args = parser.parse_args(argv)
    calibrate(args.laps, args.seed)


if __name__ == "__main__":
    import sys
    if len(sys.argv) > 1 and sys.argv[1] == "calibrate":
        calibrate_main(sys.argv[2:])
    else:
        main()
