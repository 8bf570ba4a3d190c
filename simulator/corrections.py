"""Where the simulated receiver's RTK corrections come from, and what their age does to its fix.

A real receiver is RTK fixed only while differential corrections reach it; as they age it falls
back to an RTK float, then a DGPS, then an autonomous (single) fix, and once they come back it
needs a few seconds of float before it is fixed again. The ARES shuttle gets its corrections from
an NTRIP caster over 4G (ARES §3.1): where the 4G is lost, so are they, and that is the papers'
main cause of RTK loss. Two causes are kept apart on a tour:

- `no_4g` zones: no corrections arrive (the link is down); the fix degrades with their age;
- `rtk_loss` zones: the sky is blocked (trees, a cutting): no RTK whatever the corrections.

`CorrectionsLink` is the 4G link of plain simulation: a correction every 1 / `rate_hz` outside the
`no_4g` zones and the scenario's `gnss_no_corrections` faults. With `--wire` the corrections are
real RTCM 3 frames that reach the simulated receiver's port through an NTRIP caster and the GNSS
driver (simulator/base_station.py); `ReceiverCorrections.received(t)` is told when they do.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from ares.core.route import Route
from simulator.params import SimCorrectionsParams
from simulator.scenario import ScenarioFault


@dataclass(frozen=True)
class FixKind:
    name: str  # "fixed", "float", "dgps", "single"
    quality: int  # GGA fix quality
    age_s: float | None  # of the newest correction; None: none ever


class ReceiverCorrections:
    """The receiver's side: the newest correction's arrival, and the fix kind it allows at t."""

    def __init__(self, params: SimCorrectionsParams):
        self.p = params
        self.last: float | None = None
        self.frames = 0
        self._back_at: float | None = None  # corrections came back (or first came) at this time

    def received(self, t: float, frames: int = 1) -> None:
        if self.last is None:
            # the first: the shuttle was parked with its corrections flowing before the stack started
            self._back_at = t - self.p.refix_s - 1.0
        elif t - self.last > self.p.fixed_max_age_s:
            self._back_at = t  # back after a loss: a float until refix_s has passed
        self.last = t
        self.frames += frames

    def age(self, t: float) -> float | None:
        return None if self.last is None else max(t - self.last, 0.0)

    def kind(self, t: float) -> FixKind:
        age = self.age(t)
        p = self.p
        if age is None or age > p.dgps_max_age_s:
            return FixKind("single", 1, age)
        if age > p.float_max_age_s:
            return FixKind("dgps", 2, age)
        refixing = self._back_at is not None and t - self._back_at < p.refix_s
        if age > p.fixed_max_age_s or refixing:
            return FixKind("float", 5, age)
        return FixKind("fixed", 4, age)


class CorrectionsLink:
    """Plain simulation's 4G link: whether a correction can reach the vehicle where it is."""

    faults: Sequence[ScenarioFault] = ()

    def __init__(self, route: Route, params: SimCorrectionsParams):
        self.route = route
        self.period_s = 1.0 / params.rate_hz
        self._next = -float("inf")

    def up(self, s: float, t: float) -> bool:
        if self.route.in_zone(s, "no_4g"):
            return False
        return not any(f.kind in ("gnss_no_corrections", "gnss_outage") and f.active(t, s) for f in self.faults)

    def due(self, s: float, t: float) -> bool:
        """A correction arrives at t (the base's rate, while the link is up)."""
        if t + 1e-9 < self._next or not self.up(s, t):
            return False
        self._next = t + self.period_s
        return True
