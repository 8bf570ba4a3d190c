"""Pure pursuit as a process: the fused pose and the path manager's path ahead in, a candidate out.

The controller is `control.pure_pursuit.PurePursuit`; without a fresh pose and path match this
node stays silent, so the control manager never forwards a command made from stale data.
"""

from __future__ import annotations

from ares.core.messages import ControlCandidate
from ares.core.node import Input, Node, Output
from control.path_tracking import track
from control.pure_pursuit import ControllerParams, PurePursuit


class PurePursuitNode(Node):
    """Pure pursuit on the path manager's path ahead, at the speed limits it carries: a candidate
    for the control manager (with odometry_controller: pure_pursuit, the one it trusts)."""

    name = "pure_pursuit"
    Params = ControllerParams
    pose = Input("localization/pose", max_age="input_timeout_s", doc="x, y, yaw, v of the rear axle")
    path = Input("path/match", max_age="input_timeout_s", doc="the match and the poses ahead with speed limits")
    candidate = Output("control/candidate/pure_pursuit", rate="rate_hz", doc="(v, kappa); silent without fresh inputs")

    def setup(self) -> None:
        self.pursuit = PurePursuit(self.params, self.vehicle)

    def step(self, now: float) -> None:
        pose, match = self.pose.fresh(now), self.path.fresh(now)
        if pose is None or match is None:
            return  # stay silent: the control manager must not forward a command from stale data
        cmd, creeping = track(self.pursuit, pose, match)
        self.candidate.put(
            ControlCandidate(
                t=now,
                controller="pure_pursuit",
                v=cmd.v,
                kappa=cmd.kappa,
                cross_track_m=match.xte,
                heading_error_rad=match.heading_error,
                note="creeping: heading uncertain" if creeping else f"lookahead {cmd.lookahead_m:.2f} m",
            )
        )
