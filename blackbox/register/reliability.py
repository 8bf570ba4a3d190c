"""Reliability figures of the DBW paper (§5.4) from the black box's own records.

    MTBF = operating hours / failures            (eq. 21; 788 h / 29 = 27.17 h there)
    λ    = 1 / MTBF                              (eq. 22, failures per hour)
    R(t) = exp(−λ·t)                             (eq. 23, probability of t hours without failure)
    MTTR = repair hours / failures               (eq. 24; 24 h / 29 = 0.8276 h there)
    A    = MTBF / (MTBF + MTTR)                  (eq. 25; 97.04 % there, as a fraction here)

What the words mean on this vehicle (the black box writes one VehicleRecord per second):

- *up* (in operation): a record whose mode is AUTOMATIC and whose processes are all RUNNING
  (no process dead, restarting or still starting). Operating hours = up records · 1 s / 3600.
  MANUAL and READY are not failures: a human drives or the vehicle waits, so that time is
  neither operating nor repairing.
- *failure*: a FAULT-level event that arrives while the vehicle is in operation: a record at
  most `max_gap_s` (2 s) before the event is up. (The record of the second in which the fault
  happened may already show its consequence, e.g. MANUAL, so the one before counts too.)
  Further FAULT events before the
  vehicle is up again belong to the same outage (a watchdog trip and the process restart it
  causes are one failure, not two); a FAULT while the vehicle is not in operation (parked in
  MANUAL, already down) starts no failure.
- *repair time* of a failure: from its FAULT event to the first later record that is up again.
  A failure still unrepaired when the window closes is counted up to the window's end
  (`until`) and reported in `open_failures`, so MTTR is then a lower bound.

Edge cases, in the returned figures (None is JSON null):

- no failure: MTBF and MTTR are None (unbounded / undefined), λ = 0, R(t) = 1, A = 1 when
  there was operating time, else None;
- failures but no operating time: MTBF = 0, λ None (infinite), R(t) = 0, A = 0 unless MTTR is
  0 as well (then None: 0/0);
- no operating time and no failure: only the counts; every figure is None.

Everything here is pure: the caller fetches records and events (in any batch size) and feeds
them in time order.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import asdict, dataclass
from datetime import datetime, timedelta

RUNNING_MODE = "AUTOMATIC"
PROCESS_RUNNING = "running"
RECORD_PERIOD_S = 1.0  # the black box writes one record per second of vehicle time


@dataclass(frozen=True)
class ReliabilityFigures:
    operating_hours: float
    failures: int
    repair_hours: float
    mtbf_hours: float | None
    failure_rate_per_hour: float | None
    t_hours: float
    reliability: float | None  # R(t_hours)
    mttr_hours: float | None
    availability: float | None  # fraction: 0.9704 is the paper's 97.04 %

    def as_dict(self) -> dict:
        return asdict(self)


def figures(operating_hours: float, failures: int, repair_hours: float, t_hours: float = 1.0) -> ReliabilityFigures:
    """DBW eqs. 21-25 from the three counts, with the edge cases of the module docstring."""
    if operating_hours < 0 or repair_hours < 0 or failures < 0 or t_hours < 0:
        raise ValueError("hours, failures and t must not be negative")
    mtbf = rate = reliability = mttr = availability = None
    if failures > 0:
        mtbf = operating_hours / failures
        mttr = repair_hours / failures
        if mtbf > 0:
            rate = 1.0 / mtbf
            reliability = math.exp(-rate * t_hours)
        else:
            reliability = 0.0 if t_hours > 0 else 1.0
        if mtbf + mttr > 0:
            availability = mtbf / (mtbf + mttr)
    elif operating_hours > 0:
        rate, reliability, availability = 0.0, 1.0, 1.0
    return ReliabilityFigures(
        operating_hours=operating_hours,
        failures=failures,
        repair_hours=repair_hours,
        mtbf_hours=mtbf,
        failure_rate_per_hour=rate,
        t_hours=t_hours,
        reliability=reliability,
        mttr_hours=mttr,
        availability=availability,
    )


def _text(value) -> str | None:
    """Enum members and plain strings alike (stores hand back plain values)."""
    return getattr(value, "value", value)


def is_up(record: dict) -> bool:
    """In operation: AUTOMATIC with every process RUNNING (see the module docstring)."""
    if _text(record.get("mode")) != RUNNING_MODE:
        return False
    for health in (record.get("processes") or {}).values():
        state = health.get("state") if isinstance(health, dict) else getattr(health, "state", None)
        if _text(state) != PROCESS_RUNNING:
            return False
    return True


class Tally:
    """Operating seconds, failures and repair seconds of one window, fed in time order.

    Feed records with `record(time, up)` and FAULT events with `fault(time)`, interleaved in
    time order (an event at the very time of a record goes before it); then `close(until)`.
    """

    def __init__(self, record_period_s: float = RECORD_PERIOD_S, max_gap_s: float = 2.0):
        self.period_s = record_period_s
        self.max_gap = timedelta(seconds=max_gap_s)
        self.operating_s = 0.0
        self.failures = 0
        self.repair_s = 0.0
        self.open_failures = 0
        self._last_up_time: datetime | None = None
        self._down_since: datetime | None = None

    def record(self, time: datetime, up: bool) -> None:
        if up:
            self.operating_s += self.period_s
            if self._down_since is not None:
                self.repair_s += max(0.0, (time - self._down_since).total_seconds())
                self._down_since = None
            self._last_up_time = time

    def fault(self, time: datetime) -> None:
        if self._down_since is not None:
            return  # same outage
        if self._last_up_time is not None and time - self._last_up_time <= self.max_gap:
            self.failures += 1
            self._down_since = time

    def close(self, until: datetime) -> None:
        if self._down_since is not None:
            self.repair_s += max(0.0, (until - self._down_since).total_seconds())
            self.open_failures = 1
            self._down_since = None

    def figures(self, t_hours: float = 1.0) -> ReliabilityFigures:
        return figures(self.operating_s / 3600.0, self.failures, self.repair_s / 3600.0, t_hours)


def tally_window(
    records: Iterable[dict],
    fault_times: Iterable[datetime],
    until: datetime,
    record_period_s: float = RECORD_PERIOD_S,
    max_gap_s: float = 2.0,
) -> Tally:
    """Merge records (dicts with `time`, `mode`, `processes`, oldest first) and FAULT event times
    (oldest first) into a closed Tally."""
    tally = Tally(record_period_s, max_gap_s)
    faults = iter(sorted(fault_times))
    pending = next(faults, None)
    for rec in records:
        time = rec["time"]
        while pending is not None and pending <= time:
            tally.fault(pending)
            pending = next(faults, None)
        tally.record(time, is_up(rec))
    while pending is not None:
        if pending <= until:
            tally.fault(pending)
        pending = next(faults, None)
    tally.close(until)
    return tally


# ---- a window from pieces --------------------------------------------------------------------------
#
# A week's report reads ~600 000 records; the API keeps each finished day's Segment instead and
# chains them. A Segment is its records and faults tallied from a neutral start (nothing up
# before it, no outage open); what the real entry state would change is only what happens
# before the segment's first up record, which the segment keeps: that record's time and its
# first FAULT before it.


@dataclass(frozen=True)
class Segment:
    records: int
    operating_s: float
    failures: int
    repair_s: float
    first_up: datetime | None  # its first up record
    first_fault_before_up: datetime | None  # its first FAULT before that (or at all, with no up record)
    last_up: datetime | None  # the neutral tally's state at its end ...
    down_since: datetime | None  # ... (an outage still open)


def segment(
    records: Iterable[dict],
    fault_times: Iterable[datetime],
    record_period_s: float = RECORD_PERIOD_S,
    max_gap_s: float = 2.0,
) -> Segment:
    """Records (oldest first) and the FAULT times of the same span, tallied from a neutral start
    (no close: the span is a piece of a window)."""
    tally = Tally(record_period_s, max_gap_s)
    faults = iter(sorted(fault_times))
    pending = next(faults, None)
    count = 0
    first_up: datetime | None = None
    first_fault: datetime | None = None

    def take_fault(time: datetime) -> None:
        nonlocal first_fault
        if first_up is None and first_fault is None:
            first_fault = time
        tally.fault(time)

    for rec in records:
        time = rec["time"]
        while pending is not None and pending <= time:
            take_fault(pending)
            pending = next(faults, None)
        up = is_up(rec)
        if up and first_up is None:
            first_up = time
        tally.record(time, up)
        count += 1
    while pending is not None:
        take_fault(pending)
        pending = next(faults, None)
    return Segment(
        records=count,
        operating_s=tally.operating_s,
        failures=tally.failures,
        repair_s=tally.repair_s,
        first_up=first_up,
        first_fault_before_up=first_fault,
        last_up=tally._last_up_time,
        down_since=tally._down_since,
    )


def chain(
    segments: Iterable[Segment], until: datetime, record_period_s: float = RECORD_PERIOD_S, max_gap_s: float = 2.0
) -> tuple[Tally, int]:
    """The closed Tally of consecutive segments (oldest first), as tally_window would make it
    from all their records and faults at once; and the number of records."""
    tally = Tally(record_period_s, max_gap_s)
    records = 0
    for seg in segments:
        records += seg.records
        down_since, last_up = tally._down_since, tally._last_up_time
        entry_failure = (
            down_since is None
            and last_up is not None
            and seg.first_fault_before_up is not None
            and seg.first_fault_before_up - last_up <= tally.max_gap
        )
        if entry_failure:
            tally.failures += 1
            down_since = seg.first_fault_before_up
        if seg.first_up is None:  # nothing up: the neutral tally counted nothing, the entry state goes on
            tally._down_since = down_since
            continue
        if down_since is not None:
            tally.repair_s += max(0.0, (seg.first_up - down_since).total_seconds())
        tally.operating_s += seg.operating_s
        tally.failures += seg.failures
        tally.repair_s += seg.repair_s
        tally._last_up_time, tally._down_since = seg.last_up, seg.down_since
    tally.close(until)
    return tally, records
