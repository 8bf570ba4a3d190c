"""The path manager's process: the fused pose in, path/match out (ARES §3.2).

The KD-tree match and the path ahead are `managers.path` (PathIndex, PathTracker); this node
loads the route, matches every fresh pose and says when the vehicle is lost or re-matched.
"""

from __future__ import annotations

from ares.core.messages import EventLevel
from ares.core.node import Input, Node, Output
from ares.core.route import load_route
from managers.path import PathManagerParams, PathTracker
from managers.speed import SpeedProfileParams, speed_limits


class PathManager(Node):
    """KD-tree match of the pose to the route; the path ahead with its speed limits."""

    name = "path_manager"
    Params = PathManagerParams
    sections = {"speed_profile": SpeedProfileParams}
    pose = Input("localization/pose", max_age="pose_timeout_s", doc="the fused pose: x, y, z, yaw and their variances")
    match = Output("path/match", rate="rate_hz", doc="silent while the pose is stale")

    def setup(self) -> None:
        route = load_route(self.core)
        # the speed limits belong to the speed manager once it exists; until then they are
        # computed here, once
        limits = speed_limits(route, self.shared["speed_profile"], self.vehicle)
        self.tracker = PathTracker(route, self.params, limits)
        self._lost = False
        self.log.info(
            "route %s: %d poses, %.1f m, %s", route.name, len(route), route.length, "closed" if route.closed else "open"
        )

    def step(self, now: float) -> None:
        pose = self.pose.fresh(now)
        if pose is None:
            return  # nothing fresh to match: stay silent, the controller must not act on old news
        previous = self.tracker.progress
        m, msg = self.tracker.update(now, pose.x, pose.y, pose.yaw, pose.var_yaw, pose.z, pose.var_z)
        if m is None:
            if not self._lost:  # say it once, not at every step
                self._lost = True
                self.event(
                    "path_lost",
                    f"no reachable path pose within {self.tracker.index.fallback_radius_m:g} m "
                    f"of ({pose.x:.1f}, {pose.y:.1f}) heading {pose.yaw:.2f} rad",
                    EventLevel.WARNING,
                    x=pose.x,
                    y=pose.y,
                    yaw=pose.yaw,
                )
            return
        self._lost = False
        if m.search == "wide":
            # at start-up this only means the vehicle was placed off its path; while tracking
            # it means the pose jumped or the vehicle left its path: worth a warning
            before = "no previous match" if previous is None else f"last progress {previous:.1f} m"
            self.event(
                "path_rematch",
                f"matched by the wide search at s={m.s:.1f} m ({before})",
                EventLevel.INFO if previous is None else EventLevel.WARNING,
                s=m.s,
                previous_progress=previous,
            )
        self.match.put(msg)
