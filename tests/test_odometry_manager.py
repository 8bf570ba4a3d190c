"""Odometry manager (ARES §3.1.2): eq. 6, the choice of a, b, c, and the manager as a process."""
from __future__ import annotations

import math
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ares import config
from ares.bus import Bus
from ares.clock import Clock
from ares.messages import Pose
from managers.odometry import OdometryScorer, choose_parameters, pose_covariance, score

PARAMS = config.stack_defaults()["odometry_manager"]


def literal_eq6(cov, a, b, c):
    return 1.0 - a / (1.0 + math.exp(-b * (cov - c)))


def pose(t=0.0, cov_xx=1e-4, cov_xy=0.0, cov_yy=1e-4) -> Pose:
    eig = 0.5 * (cov_xx + cov_yy) + math.hypot(0.5 * (cov_xx - cov_yy), cov_xy)
    return Pose(t=t, x=1.0, y=2.0, z=0.0, yaw=0.1, v=2.0, yaw_rate=0.0, cov_xx=cov_xx, cov_xy=cov_xy,
                cov_yy=cov_yy, var_yaw=1e-6, var_v=1e-4, position_std_m=math.sqrt(eig), rtk=True, gnss_age_s=0.1)


def test_eq6_values():
    a, b, c = 1.0, 1000.0, 1e-3
    assert score(c, a, b, c) == pytest.approx(0.5)
    assert score(c + math.log(9) / b, a, b, c) == pytest.approx(0.1)
    assert score(c - math.log(9) / b, a, b, c) == pytest.approx(0.9)
    assert score(0.0, a, b, c) == pytest.approx(1 - 1 / (1 + math.e))      # b·(0 − c) = −1
    for cov in (0.0, 5e-4, 2e-3, 0.01):
        assert score(cov, 0.8, b, c) == pytest.approx(literal_eq6(cov, 0.8, b, c))


def test_no_overflow_at_the_extremes():
    assert score(1e6, 1.0, 1e5, 1e-3) == 0.0
    assert score(0.0, 1.0, 1e9, 1.0) == 1.0


@settings(max_examples=300, deadline=None)
@given(a=st.floats(0.01, 1.0), b=st.floats(1.0, 1e6), c=st.floats(1e-6, 1.0),
       covs=st.lists(st.floats(0.0, 100.0), min_size=2, max_size=20))
def test_score_is_bounded_and_never_rises_with_the_covariance(a, b, c, covs):
    values = [score(cov, a, b, c) for cov in sorted(covs)]
    assert all(0.0 <= v <= 1.0 for v in values)
    assert all(later <= earlier + 1e-12 for earlier, later in zip(values, values[1:]))
    assert min(values) >= 1.0 - a - 1e-12              # a = 1 spans the whole range, a < 1 keeps a floor


def test_configured_parameters_separate_the_measured_populations():
    # docs/odometry_score.md: with RTK the covariance stays below ~4e-4 m² (max), 2 s into an
    # RTK-loss zone it is above 2.4e-3 m²
    s = OdometryScorer.from_config(PARAMS)
    assert s.a == 1.0
    assert s(4.1e-4) >= 0.95 and s(3.1e-4) >= 0.97
    assert s(2.39e-3) <= 0.01
    assert s(s.c) == pytest.approx(0.5)


def test_cov_is_the_largest_eigenvalue_and_ignores_the_axes():
    p = pose(cov_xx=3e-4, cov_xy=1e-4, cov_yy=1e-4)
    assert pose_covariance(p) == pytest.approx(np.linalg.eigvalsh([[3e-4, 1e-4], [1e-4, 1e-4]])[-1])
    assert pose_covariance(p) == pytest.approx(p.position_std_m ** 2)
    # the same ellipse rotated by 30 degrees
    rot = np.array([[math.cos(0.52), -math.sin(0.52)], [math.sin(0.52), math.cos(0.52)]])
    m = rot @ np.array([[3e-4, 1e-4], [1e-4, 1e-4]]) @ rot.T
    assert pose_covariance(pose(cov_xx=m[0, 0], cov_xy=m[0, 1], cov_yy=m[1, 1])) == pytest.approx(pose_covariance(p))


def test_stale_or_missing_pose_means_no_trust():
    s = OdometryScorer(1.0, 7000.0, 8.6e-4, stale_after_s=0.5)
    assert s.assess(None, 0.0) == (0.0, 0.0)
    fresh, cov = s.assess(pose(cov_xx=1e-4, cov_yy=1e-4), 0.1)
    assert fresh > 0.99 and cov == pytest.approx(1e-4)
    stale, cov = s.assess(pose(cov_xx=1e-4, cov_yy=1e-4), 0.51)
    assert stale == 0.0 and cov == pytest.approx(1e-4)


def test_choose_parameters_puts_c_between_the_populations():
    rng = np.random.default_rng(0)
    rtk = rng.uniform(4e-5, 3e-4, 5000)
    lost = rng.uniform(2.5e-3, 6e-2, 800)
    p = choose_parameters(rtk, lost)
    assert p["a"] == 1.0
    assert rtk.max() < p["c"] < lost.min()
    assert p["c"] == pytest.approx(math.sqrt(p["rtk_hi"] * p["lost_lo"]))
    assert score(p["rtk_hi"], 1.0, p["b"], p["c"]) >= 0.98 - 1e-9
    assert score(p["lost_lo"], 1.0, p["b"], p["c"]) <= 0.02 + 1e-9
    with pytest.raises(ValueError, match="overlap"):
        choose_parameters(lost, rtk)


@pytest.mark.stack
def test_odometry_manager_process_scores_poses_and_distrusts_stale_ones(router, spawn_node):
    clock = Clock()
    bus = Bus(router, "test", clock)
    scores = bus.subscribe("odometry/score", queue=1000)
    spawn_node("managers.odometry", "odometry_manager", **clock.env())
    deadline = time.monotonic() + 20.0
    while scores.latest is None and time.monotonic() < deadline:
        time.sleep(0.05)
    assert scores.latest is not None and scores.latest.score == 0.0      # no pose yet

    def publish_for(seconds, cov):
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            bus.publish("localization/pose", pose(t=clock.now(), cov_xx=cov, cov_yy=cov))
            time.sleep(0.02)

    publish_for(1.0, 1e-4)
    latest = scores.latest
    assert latest.score == pytest.approx(score(1e-4, PARAMS["a"], PARAMS["b"], PARAMS["c"]), abs=1e-9)
    assert latest.covariance == pytest.approx(1e-4) and latest.pose_age_s < 0.5
    publish_for(1.0, 5e-3)                                 # covariance of a dead-reckoning pose
    assert scores.latest.score < 0.01
    publish_for(0.5, 1e-4)
    assert scores.latest.score > 0.95
    time.sleep(PARAMS["stale_after_s"] + 0.5)              # the poses stop: stale after stale_after_s
    stale = [m for _, m in scores.drain() if m.pose_age_s > PARAMS["stale_after_s"] + 0.05]
    assert stale and all(m.score == 0.0 for m in stale)
    assert 20.0 * 0.8 <= scores.rate_hz(1.0)               # published at its configured rate
    bus.close()
