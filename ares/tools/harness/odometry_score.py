"""The odometry-score experiment of docs/odometry_score.md (ARES eq. 6): drive the tour in the
closed loop, record the pose covariance with RTK corrections and inside the RTK-loss zones, and
place a, b, c between the two populations as the paper did "from experimental analysis".

    ares calibrate odometry [--laps N] [--seed S]
"""

from __future__ import annotations

import json
import math

import numpy as np


def choose_parameters(
    cov_rtk: np.ndarray, cov_lost: np.ndarray, margin_score: float = 0.02, low_q: float = 99.9, high_q: float = 0.1
) -> dict:
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
        raise ValueError(
            f"the populations overlap: RTK p{low_q} {rtk_hi:.3g} m² >= "
            f"RTK-loss p{high_q} {lost_lo:.3g} m²; tune the filter's process noise first"
        )
    c = math.sqrt(rtk_hi * lost_lo)
    b = math.log((1.0 - margin_score) / margin_score) / min(c - rtk_hi, lost_lo - c)
    return {"a": 1.0, "b": b, "c": c, "rtk_hi": rtk_hi, "lost_lo": lost_lo}


def _percentiles(values: np.ndarray) -> dict:
    qs = (0, 1, 5, 50, 95, 99, 99.9, 100)
    return {f"p{q:g}": float(np.percentile(values, q)) for q in qs} if len(values) else {}


def calibrate(
    laps: float = 1.0, seed: int | None = None, settle_s: float = 2.0, cfg: dict | None = None, verbose: bool = True
) -> dict:
    """Re-run the experiment of docs/odometry_score.md and return (and print) the recommended
    a, b, c with the covariance percentiles of both populations.

    RTK population: every pose sample with RTK available for at least `settle_s` (after the
    start and after each RTK-loss zone). RTK-loss population: every sample at least `settle_s`
    inside an RTK-loss zone — the time the score is allowed to take to drop.
    """
    from ares.tools.harness.closed_loop import run, settled_masks

    result = run(laps=laps, seed=seed, cfg=cfg)
    rtk, lost = settled_masks(result["t"], result["rtk_available"], settle_s)
    cov = result["cov"]
    params = choose_parameters(cov[rtk], cov[lost])
    report = {
        "a": params["a"],
        "b": float(f"{params['b']:.4g}"),
        "c": float(f"{params['c']:.4g}"),
        "samples_rtk": int(rtk.sum()),
        "samples_rtk_loss": int(lost.sum()),
        "cov_rtk": _percentiles(cov[rtk]),
        "cov_rtk_loss": _percentiles(cov[lost]),
        "laps": laps,
        "seed": seed,
        "wall_s": result["wall_s"],
    }
    if verbose:
        print(json.dumps(report, indent=1))
        print(f"odometry_manager: a: {report['a']:g}  b: {report['b']:g}  c: {report['c']:g}")
    return report
