"""Speed manager: the route's speed profile and its single-speed sections (ARES §3.6.3).

The profile (managers/speed.py, eqs. 16–17) is computed once from the route's curvature
and grade: the top speed on straights, sqrt(a_lat·R) in turns, slowing before them within the
comfortable deceleration. It is reduced to numbered single-speed sections — cruise, curve,
deceleration and acceleration — as the paper's Figure 17 shows them.

speed/sections carries the whole list, repeated at sections_rate_hz: it never changes, and a
reader that starts late (the black box, the API, a restarted controller) gets it within a
period. speed/limits follows the path manager's match: the section the vehicle is in, its
limit, and the next section's limit and the distance to it. While the match is stale nothing
is published on speed/limits: a reader must not act on an old position.

SpeedTable (managers.speed) does the work without the bus (tests, `ares route profile`);
SpeedManager is the process around it.
"""

from __future__ import annotations

from ares.core.config import Params, param
from ares.core.messages import PathMatch
from ares.core.node import Input, Node, Output
from ares.core.route import load_route
from managers.speed import SpeedProfileParams, SpeedTable


class SpeedManagerParams(Params):
    """The speed limits along the route where the vehicle is (ARES §3.6.3)."""

    rate_hz: float = param(20.0, "loop rate, and the rate of speed/limits (as path/match's)", unit="Hz", gt=0)
    sections_rate_hz: float = param(0.5, "speed/sections is repeated this often: it never changes", unit="Hz", gt=0)
    match_timeout_s: float = param(1.0, "an older path match is not used: speed/limits goes quiet", unit="s", gt=0)


class SpeedManager(Node):
    """The route's speed sections, and the limits where the vehicle is."""

    name = "speed_manager"
    Params = SpeedManagerParams
    sections = {"speed_profile": SpeedProfileParams}
    match = Input("path/match", max_age="match_timeout_s", doc="where the vehicle is on its route (s)")
    limits = Output("speed/limits", rate="rate_hz", doc="silent while the match is stale")
    section_list = Output("speed/sections", rate="sections_rate_hz", doc="the route's sections, repeated")

    def setup(self) -> None:
        route = load_route(self.core)
        self.table = SpeedTable(route, self.shared["speed_profile"], self.vehicle)
        self._sections_due = -float("inf")
        self.log.info(
            "route %s: %d speed sections, %.2f..%.2f m/s",
            route.name,
            len(self.table.sections),
            min(sec.speed for sec in self.table.sections),
            max(sec.speed for sec in self.table.sections),
        )

    def step(self, now: float) -> None:
        if now >= self._sections_due:
            self.section_list.put(self.table.message(now))
            self._sections_due = now + 1.0 / self.params.sections_rate_hz
        match: PathMatch | None = self.match.fresh(now)
        if match is not None:
            self.limits.put(self.table.limits(now, match.s))
