"""The Stanley controller as a process: the fused pose and the path manager's path ahead in, a
candidate out. It runs only when chosen (`control_manager.odometry_controller: stanley`, or
`ares run --controller stanley`, as `ares compare` does).

The law is `control.stanley.Stanley`; without a fresh pose and path match this node stays silent,
so the control manager never forwards a command made from stale data.
"""

from __future__ import annotations

from ares.core.messages import ControlCandidate
from ares.core.node import Input, Node, Output
from control.path_tracking import track
from control.stanley import Stanley, StanleyParams


class StanleyNode(Node):
    """The Stanley law (heading error + atan of the front axle's offset) on the path ahead, at the
    speed limits it carries: a candidate for the control manager."""

    name = "stanley"
    Params = StanleyParams
    pose = Input("localization/pose", max_age="input_timeout_s", doc="x, y, yaw, v of the rear axle")
    path = Input("path/match", max_age="input_timeout_s", doc="the match and the poses ahead with speed limits")
    candidate = Output("control/candidate/stanley", rate="rate_hz", doc="(v, kappa); silent without fresh inputs")

    def setup(self) -> None:
        self.law = Stanley(self.params, self.vehicle)

    def step(self, now: float) -> None:
        pose, match = self.pose.fresh(now), self.path.fresh(now)
        if pose is None or match is None:
            return  # stay silent: the control manager must not forward a command from stale data
        cmd, creeping = track(self.law, pose, match)
        self.candidate.put(
            ControlCandidate(
                t=now,
                controller="stanley",
                v=cmd.v,
                kappa=cmd.kappa,
                cross_track_m=match.xte,
                heading_error_rad=match.heading_error,
                note="creeping: heading uncertain" if creeping else f"front axle offset {cmd.front_offset_m:+.2f} m",
            )
        )
