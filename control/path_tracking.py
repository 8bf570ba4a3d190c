"""What the two geometric path trackers (pure pursuit, Stanley) share: the settings beside their
laws, and how their processes turn a fresh pose and path match into the law's command."""

from __future__ import annotations

import math
from typing import Any, Protocol

from ares.core.config import Params, param
from ares.core.messages import PathMatch, Pose


class TrackerParams(Params):
    rate_hz: float = param(20.0, "loop and setpoint rate", unit="Hz", gt=0)
    max_heading_sigma_rad: float = param(
        0.05, "above this (start-up: the magnetometer's guess) follow the path's curvature ...", unit="rad", gt=0
    )
    creep_speed_mps: float = param(
        1.0, "... no faster than this, until yaw from poses has fixed the heading", unit="m/s", gt=0
    )
    input_timeout_s: float = param(
        1.0,
        "an older pose or path match: no setpoint (the bridge's watchdog stops). At "
        "--speed 5, 1 s of vehicle time is 0.2 s of wall time: less would read a "
        "busy machine as a dead localization",
        unit="s",
        gt=0,
    )
    finish_distance_m: float = param(0.5, "an open route is finished this close to its end", unit="m", gt=0)


class Law(Protocol):
    max_heading_sigma: float

    def command(self, x: float, y: float, yaw: float, v: float, *args: Any, **kwargs: Any) -> Any: ...


def track(law: Law, pose: Pose, match: PathMatch) -> tuple[Any, bool]:
    """(the law's command for this pose on the path ahead, whether it creeps: heading uncertain)."""
    heading_sigma = math.sqrt(max(pose.var_yaw, 0.0))
    cmd = law.command(
        pose.x,
        pose.y,
        pose.yaw,
        pose.v,
        match.ahead_x,
        match.ahead_y,
        match.ahead_speed,
        match.distance_to_end_m,
        heading_sigma=heading_sigma,
        ahead_curvature=match.ahead_curvature,
    )
    return cmd, heading_sigma > law.max_heading_sigma
