"""Odometry manager (ARES §3.1.2): eq. 6, the choice of a, b, c, and the manager as a node on the
in-memory bus."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ares.core import config
from ares.core.clock import ManualClock
from ares.core.config import ConfigError
from ares.core.membus import MemoryNetwork
from ares.core.messages import Pose
from ares.tools.harness.odometry_score import choose_parameters
from managers.odometry import OdometryParams, OdometryScorer, pose_covariance, score
from managers.odometry_node import OdometryManager

PARAMS = OdometryParams()


def literal_eq6(cov, a, b, c):
    return 1.0 - a / (1.0 + math.exp(-b * (cov - c)))


def pose(t=0.0, cov_xx=1e-4, cov_xy=0.0, cov_yy=1e-4) -> Pose:
    eig = 0.5 * (cov_xx + cov_yy) + math.hypot(0.5 * (cov_xx - cov_yy), cov_xy)
    return Pose(
        t=t,
        x=1.0,
        y=2.0,
        z=0.0,
        yaw=0.1,
        v=2.0,
        yaw_rate=0.0,
        cov_xx=cov_xx,
        cov_xy=cov_xy,
        cov_yy=cov_yy,
        var_yaw=1e-6,
        var_v=1e-4,
        position_std_m=math.sqrt(eig),
        rtk=True,
        gnss_age_s=0.1,
    )


def test_eq6_values():
    a, b, c = 1.0, 1000.0, 1e-3
    assert score(c, a, b, c) == pytest.approx(0.5)
    assert score(c + math.log(9) / b, a, b, c) == pytest.approx(0.1)
    assert score(c - math.log(9) / b, a, b, c) == pytest.approx(0.9)
    assert score(0.0, a, b, c) == pytest.approx(1 - 1 / (1 + math.e))  # b·(0 − c) = −1
    for cov in (0.0, 5e-4, 2e-3, 0.01):
        assert score(cov, 0.8, b, c) == pytest.approx(literal_eq6(cov, 0.8, b, c))


def test_no_overflow_at_the_extremes():
    assert score(1e6, 1.0, 1e5, 1e-3) == 0.0
    assert score(0.0, 1.0, 1e9, 1.0) == 1.0


@settings(max_examples=300, deadline=None)
@given(
    a=st.floats(0.01, 1.0),
    b=st.floats(1.0, 1e6),
    c=st.floats(1e-6, 1.0),
    covs=st.lists(st.floats(0.0, 100.0), min_size=2, max_size=20),
)
def test_score_is_bounded_and_never_rises_with_the_covariance(a, b, c, covs):
    values = [score(cov, a, b, c) for cov in sorted(covs)]
    assert all(0.0 <= v <= 1.0 for v in values)
    assert all(later <= earlier + 1e-12 for earlier, later in zip(values, values[1:]))
    assert min(values) >= 1.0 - a - 1e-12  # a = 1 spans the whole range, a < 1 keeps a floor


def test_configured_parameters_separate_the_measured_populations():
    # docs/odometry_score.md: with RTK the covariance stays below ~4e-4 m² (max), 2 s into an
    # RTK-loss zone it is above 2.4e-3 m²
    s = OdometryScorer.from_params(PARAMS)
    assert s.a == 1.0
    assert s(4.1e-4) >= 0.95 and s(3.1e-4) >= 0.97
    assert s(2.39e-3) <= 0.01
    assert s(s.c) == pytest.approx(0.5)


def test_cov_is_the_largest_eigenvalue_and_ignores_the_axes():
    p = pose(cov_xx=3e-4, cov_xy=1e-4, cov_yy=1e-4)
    assert pose_covariance(p) == pytest.approx(np.linalg.eigvalsh([[3e-4, 1e-4], [1e-4, 1e-4]])[-1])
    assert pose_covariance(p) == pytest.approx(p.position_std_m**2)
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


@pytest.mark.parametrize("key, bad", [("a", 1.5), ("b", 0.0), ("c", -1e-3), ("stale_after_s", math.nan)])
def test_a_bad_odometry_section_is_refused_naming_the_key(key, bad):
    with pytest.raises(ConfigError, match=f"section 'odometry_manager'.*{key}"):
        config.section({"odometry_manager": {key: bad}}, "odometry_manager", OdometryParams)


def test_the_node_scores_with_its_sections_values(run_config):
    cfg = {**run_config, "odometry_manager": {"a": 0.8, "b": 2000.0, "c": 2e-3, "stale_after_s": 0.3}}
    clock, network = ManualClock(), MemoryNetwork()
    node = OdometryManager(cfg, clock=clock, bus=network.bus("odometry_manager", clock))
    node.setup()
    assert (node.scorer.a, node.scorer.b, node.scorer.c, node.scorer.stale_after_s) == (0.8, 2000.0, 2e-3, 0.3)


class OdometryManagerOnTheBus:
    PERIOD = 0.05  # the manager's 20 Hz

    def __init__(self, cfg, start: float = 0.0):
        self.clock = ManualClock(start)
        self.network = MemoryNetwork()
        self.node = OdometryManager(cfg, clock=self.clock, bus=self.network.bus("odometry_manager", self.clock))
        self.node.setup()
        self.bus = self.network.bus("test", self.clock)
        self.scores = self.bus.subscribe("odometry/score", queue=1000)
        self.t = start

    def run(self, seconds: float, cov: float | None = None) -> list:
        """Step for `seconds`, publishing a pose with this covariance before each step (none
        when cov is None); the scores published meanwhile."""
        for _ in range(round(seconds / self.PERIOD)):
            self.t = round(self.t + self.PERIOD, 9)
            self.clock.set(self.t)
            if cov is not None:
                self.bus.publish("localization/pose", pose(t=self.t, cov_xx=cov, cov_yy=cov))
            self.node.step_once(self.t)
        return [m for _, m in self.scores.drain()]


def test_odometry_manager_node_scores_poses_and_distrusts_stale_ones(run_config):
    manager = OdometryManagerOnTheBus(run_config, start=3.0)
    no_pose = manager.run(0.5)
    assert len(no_pose) == 10  # one score a step
    assert all(m.score == 0.0 and m.covariance == 0.0 for m in no_pose)
    # without any pose the age is the time since the manager started
    assert no_pose[-1].pose_age_s == pytest.approx(0.5)

    with_rtk = manager.run(1.0, cov=1e-4)
    latest = with_rtk[-1]
    assert latest.score == pytest.approx(score(1e-4, PARAMS.a, PARAMS.b, PARAMS.c), abs=1e-9)
    assert latest.covariance == pytest.approx(1e-4) and latest.pose_age_s == 0.0
    assert manager.run(1.0, cov=5e-3)[-1].score < 0.01  # covariance of a dead-reckoning pose
    assert manager.run(0.5, cov=1e-4)[-1].score > 0.95

    last_pose = manager.t
    silent = manager.run(PARAMS.stale_after_s + 0.5)  # the poses stop
    assert len(silent) == round((PARAMS.stale_after_s + 0.5) / manager.PERIOD)
    for m in silent:
        assert m.pose_age_s == pytest.approx(m.t - last_pose)
        assert m.covariance == pytest.approx(1e-4)  # the last pose's, for the record
    fresh = [m for m in silent if m.pose_age_s <= PARAMS.stale_after_s - 1e-9]
    stale = [m for m in silent if m.pose_age_s > PARAMS.stale_after_s + 1e-9]
    assert fresh and all(m.score > 0.95 for m in fresh)
    assert stale and all(m.score == 0.0 for m in stale)


def test_a_pose_delivered_late_is_as_old_as_its_stamp(run_config):
    manager = OdometryManagerOnTheBus(run_config, start=10.0)
    manager.run(0.1, cov=1e-4)
    manager.clock.set(10.5)
    manager.bus.publish("localization/pose", pose(t=8.0, cov_xx=1e-4, cov_yy=1e-4))  # produced 2.5 s ago
    manager.node.step_once(10.5)
    [late] = [m for _, m in manager.scores.drain()]
    assert late.pose_age_s == pytest.approx(2.5) and late.score == 0.0


def test_a_pose_without_rtk_says_why():
    from ares.core.messages import CorrectionsStatus
    from managers.odometry import no_rtk_cause

    down = CorrectionsStatus(t=99.5, source="ntrip", link="down", age_s=23.4, frames=3, detail="no 4G here")
    assert no_rtk_cause(down, 100.0) == "no RTK: corrections link down (no 4G here), the newest 23 s old"
    fresh = CorrectionsStatus(t=99.5, source="ntrip", link="streaming", age_s=0.3, frames=30)
    assert no_rtk_cause(fresh, 100.0).startswith("no RTK with fresh corrections")
    assert no_rtk_cause(fresh, 110.0) == "no RTK (the corrections' state unknown)"  # a stale state
    assert no_rtk_cause(None, 100.0) == "no RTK (the corrections' state unknown)"
