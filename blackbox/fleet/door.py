"""What the fleet's black box takes from a vehicle: stamps inside a sane window of the fleet's wall.

A vehicle's clock is disciplined (GNSS, NTP), so its records' seconds and its events' times lie
near the fleet server's wall: at most `future_tolerance_s` ahead of it, and no older than the
store keeps (`oldest_s`; the store would purge anything older at once). A stamp outside that
window (a clock set to 2100, an event's stack time of 1e15, NaN, a second before 1970) is
refused before it reaches the ledger or the store: one vehicle's absurd stamp must neither stall
the gap bookkeeping nor raise inside the fleet's loop. Refusals are counted per vehicle and cause
and reported as an event at most once per `report_every_s`, so a vehicle that sends nothing but
refusals cannot flood the fleet's own black box either. Nothing here does I/O.
"""

from __future__ import annotations

import collections
import math
from dataclasses import dataclass
from datetime import UTC, datetime


@dataclass
class StampWindow:
    oldest_s: float  # how far behind the wall a stamp may be
    future_tolerance_s: float  # how far ahead of it

    def why_refused(self, epoch_s: float, wall: float, any_age: bool = False) -> str | None:
        """None if `epoch_s` (UTC epoch seconds) is inside the window around `wall` (with
        `any_age`, only its future bound: an answer to a range the fleet asked for), else why not."""
        if not math.isfinite(epoch_s):
            return f"a time that is no number ({epoch_s})"
        if epoch_s > wall + self.future_tolerance_s:
            return f"a time {epoch_s - wall:.0f} s ahead of the fleet's clock"
        if not any_age and epoch_s < wall - self.oldest_s:
            return f"a time {wall - epoch_s:.0f} s behind the fleet's clock (older than the store keeps)"
        return None


def epoch_or_none(value: datetime) -> float | None:
    """A record's time as UTC epoch seconds (naive: UTC), or None when it has none (out of range)."""
    try:
        return (value if value.tzinfo is not None else value.replace(tzinfo=UTC)).timestamp()
    except (OverflowError, ValueError, OSError):
        return None


@dataclass
class _Tally:
    count: int = 0
    example: str = ""
    reported_wall: float = -math.inf


class Refusals:
    """Refused messages per (vehicle, cause), to report as events without flooding."""

    def __init__(self, report_every_s: float):
        self.report_every_s = report_every_s
        self.tallies: dict[tuple[str, str], _Tally] = {}
        self.totals: collections.Counter[tuple[str, str]] = collections.Counter()  # since the start

    def note(self, vehicle_id: str, cause: str, example: str) -> None:
        tally = self.tallies.setdefault((vehicle_id, cause), _Tally())
        tally.count += 1
        tally.example = example
        self.totals[vehicle_id, cause] += 1

    def due(self, wall: float) -> list[tuple[str, str, int, str]]:
        """(vehicle, cause, refused since the last report, the latest example) whose report is due."""
        out = []
        for (vehicle_id, cause), tally in self.tallies.items():
            if tally.count and wall - tally.reported_wall >= self.report_every_s:
                out.append((vehicle_id, cause, tally.count, tally.example))
                tally.count, tally.reported_wall = 0, wall
        return out
