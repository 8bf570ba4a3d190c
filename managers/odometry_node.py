"""The odometry manager's process: the fused pose in, the odometry score (ARES eq. 6) out.

The score and its staleness rule are `managers.odometry`; this node reads the pose's age from its
own stamp and publishes the score every loop. A pose without RTK comes with its cause, from the
corrections' state (gnss/corrections): a link that is down, corrections too old, or fresh ones the
receiver cannot use (the sky blocked); the score itself is the covariance's alone.
"""

from __future__ import annotations

from ares.core.messages import OdometryScore
from ares.core.node import Input, Node, Output
from managers.odometry import OdometryParams, OdometryScorer, no_rtk_cause


class OdometryManager(Node):
    """Scores the fused pose's covariance: the odometry score of ARES eq. 6."""

    name = "odometry_manager"
    Params = OdometryParams
    pose = Input("localization/pose", doc="the fused pose and its covariance")
    corrections = Input("gnss/corrections", doc="the RTK corrections' link and age: why a pose has no RTK")
    score = Output("odometry/score", rate="rate_hz", doc="eq. 6; 0 when the pose is stale or missing")

    def setup(self) -> None:
        self.scorer = OdometryScorer.from_params(self.params)
        self.started = self.clock.now()

    def step(self, now: float) -> None:
        pose = self.pose.latest
        # age from the pose's own stamp: a pose delivered late is as old as it says
        age = max(self.pose.age(now) if pose is not None else now - self.started, 0.0)
        value, cov = self.scorer.assess(pose, age)
        cause = None if pose is None or pose.rtk else no_rtk_cause(self.corrections.latest, now)
        self.score.put(OdometryScore(t=now, score=value, covariance=cov, pose_age_s=age, cause=cause))
