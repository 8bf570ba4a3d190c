"""The MPC as a process: the fused pose and the path manager's path ahead in, a candidate out.

Each cycle solves control/mpc.py's problem from the pose (the wheel angle from the drive-by-wire
bridge's report) along the path ahead with its speed limits, and publishes the first input as
the MPC's candidate with the predicted trajectory beside it. A late or failed solve is answered
with the previous solution shifted (`fresh: false`) and, after `max_reused` of them, with a
hand-over request: the control manager then forwards its fallback.

At start-up the heading is the magnetometer's guess until the vehicle has moved a few metres
(see control/pure_pursuit.py): an MPC steering from it would turn a phantom heading error into a
real one. While the heading's sigma is above max_heading_sigma_rad the candidate follows the
path's own curvature at no more than creep_speed_mps, as pure pursuit does.

A standing shuttle off the path (road reactive control left it 0.56 m aside and turned away, and
then stopped) was the MPC's local minimum while its references were the path itself: any start
first adds to the cross-track error, so the best plan was to stay. Seen after the 6-minute GNSS
outage: the MPC in charge, everything allowing motion, and `v = 0` for a minute. The MPC's
references are now a way back from such an offset (control/mpc.py, `_Polyline.rejoin`); as a
second line, a plan that keeps the shuttle standing while the path asks it to move, for
`stall_handover_s`, asks for a hand-over: pure pursuit stands in, starts from any offset, and the
MPC takes over again once moving (`StallGuard`).

Without a fresh pose and path there is no candidate: the control manager must never forward a
command computed from stale data.
"""

from __future__ import annotations

import math

from ares.core.config import param
from ares.core.messages import ControlCandidate, PredictedTrajectory
from ares.core.node import Input, Node, Output
from control.mpc import Mpc, MpcParams, VehicleState


class MpcNodeParams(MpcParams):
    input_timeout_s: float = param(1.0, "an older pose or path match: no candidate", unit="s", gt=0)
    max_heading_sigma_rad: float = param(
        0.05, "above this (start-up: the magnetometer's guess) follow the path's curvature ...", unit="rad", gt=0
    )
    creep_speed_mps: float = param(
        1.0, "... no faster than this, until yaw from poses has fixed the heading", unit="m/s", gt=0
    )
    stall_handover_s: float = param(
        2.0,
        "a plan that keeps the standing shuttle standing while the path asks it "
        "to move this long: hand over (pure pursuit starts it)",
        unit="s",
        gt=0,
    )
    pipeline_latency_s: float = param(
        0.1,
        "from this process's step to the wheels' actuators, beyond the pose's "
        "age: the control manager's step (20 Hz) and the bridge's (10 Hz); the MPC "
        "solves from the state predicted that far ahead",
        unit="s",
        ge=0,
    )


class StallGuard:
    """Whether the MPC's plan keeps a standing shuttle standing although the path asks it to move
    (`move_mps` or more ahead) for `after_s`: then it should hand over."""

    def __init__(self, after_s: float, standing_mps: float = 0.1, move_mps: float = 0.5):
        self.after_s, self.standing_mps, self.move_mps = after_s, standing_mps, move_mps
        self.since: float | None = None

    def stalled(self, now: float, v_command: float, v_now: float, v_path: float) -> bool:
        if v_command < self.standing_mps and abs(v_now) < self.standing_mps and v_path >= self.move_mps:
            self.since = now if self.since is None else self.since
            return now - self.since >= self.after_s
        self.since = None
        return False


class MpcNode(Node):
    """Model predictive control (ARES eqs. 11-13) on the path ahead: a candidate for the control manager."""

    name = "mpc"
    Params = MpcNodeParams
    pose = Input("localization/pose", max_age="input_timeout_s", doc="x, y, yaw, v of the rear axle")
    path = Input("path/match", max_age="input_timeout_s", doc="the poses ahead with their speed limits")
    car = Input("dbw/car_state", max_age="input_timeout_s", doc="the steering wheel's angle: where the wheels are")
    candidate = Output("control/candidate/mpc", rate="rate_hz", doc="(v, kappa); silent without fresh inputs")
    trajectory = Output("control/mpc/trajectory", rate="rate_hz", doc="the horizon's predicted poses")

    def setup(self) -> None:
        self.mpc = Mpc(self.vehicle, MpcParams(**{k: getattr(self.params, k) for k in MpcParams.model_fields}))
        self.max_kappa = self.vehicle.max_curvature
        self._accel = 0.0
        self.stall = StallGuard(self.params.stall_handover_s)

    def step(self, now: float) -> None:
        pose, match, car = self.pose.fresh(now), self.path.fresh(now), self.car.fresh(now)
        if pose is None or match is None or not match.ahead_x:
            return
        if math.sqrt(max(pose.var_yaw, 0.0)) > self.params.max_heading_sigma_rad:
            kappa = max(
                -self.max_kappa, min(self.max_kappa, match.ahead_curvature[0] if match.ahead_curvature else 0.0)
            )
            self.candidate.put(
                ControlCandidate(
                    t=now,
                    controller="mpc",
                    v=min(match.ahead_speed[0], self.params.creep_speed_mps),
                    kappa=kappa,
                    cross_track_m=match.xte,
                    heading_error_rad=match.heading_error,
                    note="creeping: heading uncertain",
                )
            )
            return
        delta = self.vehicle.road_wheel_angle(car.steering_wheel_deg) if car is not None else 0.0
        state = VehicleState(pose.x, pose.y, pose.yaw, pose.v, delta, self._accel)
        cmd = self.mpc.solve(
            state,
            match.ahead_x,
            match.ahead_y,
            match.ahead_speed,
            latency_s=max(now - pose.t, 0.0) + self.params.pipeline_latency_s,
            delta_age_s=max(pose.t - car.t, 0.0) if car is not None else 0.0,
        )
        self._accel = cmd.accel
        stalled = self.stall.stalled(now, cmd.v, pose.v, max(match.ahead_speed[:20], default=0.0))
        self.candidate.put(
            ControlCandidate(
                t=now,
                controller="mpc",
                v=cmd.v,
                kappa=cmd.kappa,
                fresh=cmd.ok,
                handover=cmd.handover or stalled,
                solve_ms=round(cmd.solve_ms, 3),
                cross_track_m=-cmd.cte if math.isfinite(cmd.cte) else match.xte,
                heading_error_rad=cmd.epsi if math.isfinite(cmd.epsi) else match.heading_error,
                note="stalled: standing although the path asks to move" if stalled else cmd.status,
            )
        )
        if len(cmd.predicted_x):
            self.trajectory.put(
                PredictedTrajectory(
                    t=now,
                    controller="mpc",
                    x=cmd.predicted_x.tolist(),
                    y=cmd.predicted_y.tolist(),
                    step_s=self.params.step_s,
                )
            )
