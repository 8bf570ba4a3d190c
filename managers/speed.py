"""Speed manager: the route's speed profile and its single-speed sections (ARES §3.6.3).

The profile (managers/speed_profile.py, eqs. 16–17) is computed once from the route's curvature
and grade: the top speed on straights, sqrt(a_lat·R) in turns, slowing before them within the
comfortable deceleration. It is reduced to numbered single-speed sections — cruise, curve,
deceleration and acceleration — as the paper's Figure 17 shows them.

speed/sections carries the whole list, repeated at sections_rate_hz: it never changes, and a
reader that starts late (the black box, the API, a restarted controller) gets it within a
period. speed/limits follows the path manager's match: the section the vehicle is in, its
limit, and the next section's limit and the distance to it. While the match is stale nothing
is published on speed/limits: a reader must not act on an old position.

SpeedTable does the work without the bus (tests, `ares route profile`); SpeedManager is the
process around it.
"""
from __future__ import annotations

from bisect import bisect_right

import numpy as np

from ares.config import Params, VehicleProfile, param
from ares.messages import PathMatch, SpeedLimits, SpeedSection, SpeedSections
from ares.node import Input, Node, Output
from ares.route import Route, load_route
from managers.speed_profile import Section, SpeedProfileParams, speed_limits, speed_sections


class SpeedManagerParams(Params):
    """The speed limits along the route where the vehicle is (ARES §3.6.3)."""
    rate_hz: float = param(20.0, "loop rate, and the rate of speed/limits (as path/match's)", unit="Hz", gt=0)
    sections_rate_hz: float = param(0.5, "speed/sections is repeated this often: it never changes", unit="Hz", gt=0)
    match_timeout_s: float = param(1.0, "an older path match is not used: speed/limits goes quiet", unit="s", gt=0)


class SpeedTable:
    """A route's graded profile and its sections; the limits at any s."""

    def __init__(self, route: Route, params: SpeedProfileParams, vehicle: VehicleProfile):
        self.route = route
        self.profile: np.ndarray = speed_limits(route, params, vehicle, grade=True)
        self.sections: list[Section] = speed_sections(route, params, vehicle, self.profile)
        self._starts = [sec.s_start for sec in self.sections]

    def section_at(self, s: float) -> Section:
        """The section holding s (wrapped on a closed route; clamped to the ends of an open one)."""
        if self.route.closed:
            s %= self.route.length
        k = bisect_right(self._starts, s) - 1
        return self.sections[min(max(k, 0), len(self.sections) - 1)]

    def limits(self, now: float, s: float) -> SpeedLimits:
        here = self.section_at(s)
        k = here.index + 1
        if k < len(self.sections):
            ahead: Section | None = self.sections[k]
        else:
            ahead = self.sections[0] if self.route.closed else None
        if self.route.closed:
            s %= self.route.length
        distance = None if ahead is None else max(here.s_end - s, 0.0)
        return SpeedLimits(t=now, s=s, section=here.index, kind=here.kind, limit_mps=here.speed,
                           next_section=None if ahead is None else ahead.index,
                           next_limit_mps=None if ahead is None else ahead.speed, distance_to_next_m=distance)

    def message(self, now: float) -> SpeedSections:
        return SpeedSections(t=now, route=self.route.name, length_m=self.route.length, closed=self.route.closed,
                             sections=[SpeedSection(index=sec.index, s_start=sec.s_start, s_end=sec.s_end,
                                                    speed=sec.speed, kind=sec.kind) for sec in self.sections])


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
        self.log.info("route %s: %d speed sections, %.2f..%.2f m/s", route.name, len(self.table.sections),
                      min(sec.speed for sec in self.table.sections), max(sec.speed for sec in self.table.sections))

    def step(self, now: float) -> None:
        if now >= self._sections_due:
            self.section_list.put(self.table.message(now))
            self._sections_due = now + 1.0 / self.params.sections_rate_hz
        match: PathMatch | None = self.match.fresh(now)
        if match is not None:
            self.limits.put(self.table.limits(now, match.s))
