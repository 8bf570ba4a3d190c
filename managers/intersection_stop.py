"""FULL_STOP at the intersections a tour marks (ARES §3.3: the mission hands the stop to the
movement manager there), without a bus.

A tour's intersection zone with `full_stop: true` has a stop line at its start. Each stop line is
in one of three states, moved on every step by where the shuttle is (its arc length s on the
route, None while unknown) and whether it stands:

| state    | the mission's limit from it                  | goes to                                         |
|----------|----------------------------------------------|-------------------------------------------------|
| ARMED    | sqrt(2 · approach_decel · (d − reach / 2))   | STANDING: standing at the line                  |
| STANDING | 0                                            | CLEARED: stood full_stop_s without rolling      |
|          |                                              | (rolling at the line starts the count again)    |
| CLEARED  | none                                         | ARMED: once the shuttle has left the line's     |
|          |                                              | region (the next pass, the next lap)            |

d is the distance along the route to the line; "at the line" is the region from reach_m before
it to the zone's end, so that a shuttle that stopped a little past the line still stands its
time before it crosses. The limit goes out in the mission's status, which the movement gate
applies with every other manager's: the mission asks, the gate stops the shuttle. An unknown s
is a limit of 0 at every armed line: where the line is cannot be told.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

from ares.core.route import Route


class LineState(str, Enum):
    ARMED = "ARMED"
    STANDING = "STANDING"
    CLEARED = "CLEARED"


@dataclass
class StopLine:
    s: float  # the line: the intersection's start
    s_end: float  # the intersection's end
    state: LineState = LineState.ARMED
    standing_since: float | None = None


@dataclass(frozen=True)
class LineChange:
    line: float  # the line's s
    state: LineState  # the state it went to


class IntersectionStops:
    """Every full_stop line of a route, stepped with the shuttle's s and whether it stands."""

    def __init__(self, route: Route, full_stop_s: float, reach_m: float, approach_decel_mps2: float):
        self.lines = [StopLine(z.s_start, z.s_end) for z in route.zones if z.kind == "intersection" and z.full_stop]
        self.closed, self.length = route.closed, route.length
        self.full_stop_s, self.reach_m, self.decel = full_stop_s, reach_m, approach_decel_mps2

    def step(self, now: float, s: float | None, standing: bool) -> tuple[float, list[LineChange]]:
        """(the limit from the lines, m/s: inf when none holds; the lines that changed state)."""
        limit, changes = math.inf, []
        for line in self.lines:
            before = line.state
            line_limit = self._step_line(line, now, s, standing)
            limit = min(limit, line_limit)
            if line.state is not before:
                changes.append(LineChange(line.s, line.state))
        return limit, changes

    def _step_line(self, line: StopLine, now: float, s: float | None, standing: bool) -> float:
        if s is None:
            return math.inf if line.state is LineState.CLEARED else 0.0
        ahead = self._ahead(line, s)  # along the route to the line: < 0 past it
        at_line = -(line.s_end - line.s) <= ahead <= self.reach_m
        if line.state is LineState.CLEARED:
            if not at_line:
                line.state = LineState.ARMED
            return math.inf
        if not at_line:
            line.state, line.standing_since = LineState.ARMED, None
            return self._approach(ahead) if ahead > 0.0 else math.inf
        # at the line: stand, then cross
        if not standing:
            line.standing_since = None
            return 0.0
        if line.standing_since is None:
            line.state, line.standing_since = LineState.STANDING, now
        if now - line.standing_since >= self.full_stop_s:
            line.state, line.standing_since = LineState.CLEARED, None
            return math.inf
        return 0.0

    def _ahead(self, line: StopLine, s: float) -> float:
        """The distance along the route from s to the line (the short way round a closed route)."""
        step = line.s - s
        if self.closed:
            step = (step + 0.5 * self.length) % self.length - 0.5 * self.length
        return step

    def _approach(self, ahead: float) -> float:
        return math.sqrt(2.0 * self.decel * max(ahead - self.reach_m / 2, 0.0))
