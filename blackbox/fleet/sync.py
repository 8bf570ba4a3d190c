"""What the fleet's store still lacks of each vehicle, and whether each vehicle is heard.

The fleet server keeps every vehicle's black box in its own store (blackbox/fleet/sync_node.py).
Records arrive live, one per second of each vehicle (`blackbox/record`); a link that is cut, or
a fleet server that is down, leaves a gap. `FleetLedger` keeps, per vehicle, the newest second
stored and the gaps behind it, and says which range to ask the vehicle's recorder for
(`blackbox/records`); an answer fills what it holds, from the recorder's memory or its store, and
says up to where it is complete: a second before that which it did not send was never recorded
(`never_recorded`), one after it stays open and is asked for again, however old, until the
vehicle answers it. Only a recorder from before such answers (memory only) leaves a second older
than its memory as `left_on_vehicle`.

Acknowledgements (`blackbox/acknowledge`) let a vehicle that keeps its records until the fleet
holds them (`keep_until_acknowledged`) purge: the ledger learns each vehicle's mark first (what
the fleet acknowledged before, kept in the vehicle's store) and opens as a gap every second
after it that this run has not seen arrive, then acknowledges, at most every
`acknowledge_every_s`, up to the last second with nothing open before it. The node sends an
acknowledgement only once its writer has put every record behind it into the store, and opens
the range again if the writer lost any item meanwhile (sync_node.py).

Reachability is judged on the wall clock: a vehicle from which nothing arrived for
`unreachable_after_s` is unreachable until the next message. Nothing here does I/O.
"""

from __future__ import annotations

from bisect import bisect_left, bisect_right
from dataclasses import dataclass, field
from datetime import UTC, datetime

from ares.core.config import param
from ares.core.messages import SNAPSHOT_PART_MAX_BYTES
from blackbox.register.recorder import StoreWriterParams
from blackbox.register.store.record_store import RETENTION


class FleetSyncParams(StoreWriterParams):
    """The fleet's black box: its store writer, and how it fills gaps and judges reachability."""

    rate_hz: float = param(5.0, "loop: store what arrived, ask for gaps, judge reachability", unit="Hz", gt=0)
    unreachable_after_s: float = param(
        3.0, "a vehicle silent this long (wall) is marked unreachable (an event in its black box)", unit="s", gt=0
    )
    backfill_retry_s: float = param(2.0, "a gap still open is asked for again after this (wall)", unit="s", gt=0)
    backfill_timeout_s: float = param(3.0, "a gap's request waits this long for the recorder's answer", unit="s", gt=0)
    backfill_max_s: int = param(600, "seconds asked for in one request", ge=1)
    future_tolerance_s: float = param(
        300.0, "a vehicle's record or event stamped further ahead of the fleet's wall is refused", unit="s", gt=0
    )
    oldest_accepted_s: float = param(
        RETENTION.total_seconds(),
        "a record or event stamped further behind the fleet's wall is refused (the store keeps no older)",
        unit="s",
        gt=0,
    )
    acknowledge_every_s: float = param(
        10.0,
        "each vehicle is told up to where the fleet's store holds all its records at most this often (wall)",
        unit="s",
        gt=0,
    )
    refusal_report_s: float = param(
        60.0, "refused messages of one vehicle and cause are reported as one event at most this often", unit="s", gt=0
    )
    snapshot_copy: bool = param(True, "copy each vehicle's incident snapshots into the fleet's snapshots folder")
    snapshot_bytes_per_s: float = param(
        1.0e6, "the copies' average bandwidth, all vehicles together (1 MB/s: 8 Mbit/s)", unit="B/s", gt=0
    )
    snapshot_part_bytes: int = param(
        256 * 1024, "bytes asked for in one piece of a copy", unit="B", gt=0, le=SNAPSHOT_PART_MAX_BYTES
    )
    snapshot_list_every_s: float = param(
        30.0, "each reachable vehicle is asked which snapshots it keeps this often (wall)", unit="s", gt=0
    )
    snapshot_retry_s: float = param(5.0, "a copy the link stopped is tried again after this (wall)", unit="s", gt=0)


@dataclass
class VehicleLedger:
    newest: int | None = None  # the newest second accounted for: stored, or open in a gap (UTC epoch s)
    gaps: list[list[int]] = field(default_factory=list)  # [start, end) ranges, oldest first
    heard_wall: float = 0.0
    reachable: bool = False
    asked_wall: float = -1e18  # when a gap was last asked for
    in_flight: tuple[int, int] | None = None
    utc_offset_s: float | None = None  # epoch s - stack s of the vehicle's clock (its records say)
    filled: int = 0
    left_on_vehicle: int = 0
    never_recorded: int = 0
    mark_known: bool = False  # the vehicle said what the fleet acknowledged before
    acknowledged: int | None = None  # the vehicle's mark, as it last said it
    accountable_from: int | None = None  # the first second after the mark when it was learned
    acknowledge_wall: float = -1e18  # when an acknowledgement was last due
    acknowledging: bool = False  # one waits for the writer or for the vehicle's reply


@dataclass
class Reachability:
    vehicle_id: str
    reachable: bool
    silent_s: float


class FleetLedger:
    def __init__(self, params: FleetSyncParams):
        self.p = params
        self.vehicles: dict[str, VehicleLedger] = {}

    def vehicle(self, vehicle_id: str) -> VehicleLedger:
        return self.vehicles.setdefault(vehicle_id, VehicleLedger())

    def known(self, vehicle_id: str, newest_stored: int | None) -> None:
        """What the store already held of a vehicle when the fleet server started."""
        self.vehicle(vehicle_id).newest = newest_stored

    def heard(self, vehicle_id: str, wall: float) -> Reachability | None:
        """Anything arrived from the vehicle; a Reachability if it was unreachable (or new)."""
        ledger = self.vehicle(vehicle_id)
        ledger.heard_wall = wall
        if ledger.reachable:
            return None
        ledger.reachable = True
        return Reachability(vehicle_id, True, 0.0)

    def record(self, vehicle_id: str, epoch_s: int, stack_t: float) -> None:
        """A live record: a jump past the newest second opens a gap."""
        ledger = self.vehicle(vehicle_id)
        ledger.utc_offset_s = epoch_s - stack_t
        if ledger.newest is not None and epoch_s > ledger.newest + 1:
            ledger.gaps.append([ledger.newest + 1, epoch_s])
        if ledger.newest is None or epoch_s > ledger.newest:
            ledger.newest = epoch_s
        else:  # an older second live (a gap's second, or one stored again): it closes what it covers
            self._fill(ledger, {epoch_s})

    def silent(self, wall: float) -> list[Reachability]:
        """The vehicles that have just become unreachable."""
        out = []
        for vehicle_id, ledger in self.vehicles.items():
            silent_s = wall - ledger.heard_wall
            if ledger.reachable and silent_s > self.p.unreachable_after_s:
                ledger.reachable = False
                out.append(Reachability(vehicle_id, False, silent_s))
        return out

    def requests(self, wall: float) -> list[tuple[str, int, int]]:
        """(vehicle, start, end) to ask for now: the oldest open gap of each reachable vehicle with
        none in flight, at most backfill_max_s of it, once per backfill_retry_s."""
        out = []
        for vehicle_id, ledger in self.vehicles.items():
            if not ledger.gaps or not ledger.reachable or ledger.in_flight is not None:
                continue
            if wall - ledger.asked_wall < self.p.backfill_retry_s:
                continue
            start, end = ledger.gaps[0]
            end = min(end, start + self.p.backfill_max_s)
            ledger.in_flight, ledger.asked_wall = (start, end), wall
            out.append((vehicle_id, start, end))
        return out

    def answered(
        self, vehicle_id: str, seconds: set[int], oldest_held: int | None, complete_to: int | None = None
    ) -> None:
        """The recorder's answer to the request in flight: the seconds it sent are stored. One that
        says up to where it is complete (`complete_to`: it reads its store) closes the rest of the
        range before that as never recorded; what lies after stays open, asked again (at once if
        the answer made progress, else after backfill_retry_s). An older recorder's (memory only):
        of the rest, those older than what it holds stay on the vehicle, the others it never
        recorded."""
        ledger = self.vehicle(vehicle_id)
        if ledger.in_flight is None:
            return
        start, end = ledger.in_flight
        ledger.in_flight = None
        seconds = {k for k in seconds if start <= k < end}  # what was asked for, nothing more
        self._fill(ledger, seconds)
        if complete_to is not None:
            done = min(max(complete_to, start), end)
            rest = {k for k in range(start, done) if k not in seconds}
            ledger.never_recorded += len(rest)
            self._fill(ledger, rest, count=False)
            if done > start or seconds:
                ledger.asked_wall = -1e18  # progress: the next piece at once
            return
        rest = {k for k in range(start, end) if k not in seconds}
        before_memory = {k for k in rest if oldest_held is None or k < oldest_held}
        ledger.left_on_vehicle += len(before_memory)
        ledger.never_recorded += len(rest - before_memory)
        self._fill(ledger, rest, count=False)
        ledger.asked_wall = -1e18  # the next gap at once

    def acknowledgements(self, wall: float) -> list[tuple[str, int | None]]:
        """(vehicle, up to) to acknowledge now, once per acknowledge_every_s per reachable
        vehicle with none pending: the last second with nothing open at or before it, when it
        is past the vehicle's mark; None while the mark is not known (the question comes first)."""
        out: list[tuple[str, int | None]] = []
        for vehicle_id, ledger in self.vehicles.items():
            if not ledger.reachable or ledger.acknowledging:
                continue
            if wall - ledger.acknowledge_wall < self.p.acknowledge_every_s:
                continue
            upto = self.complete_to(vehicle_id) if ledger.mark_known else None
            behind_mark = upto is not None and ledger.acknowledged is not None and upto <= ledger.acknowledged
            if ledger.mark_known and (upto is None or behind_mark):
                continue
            ledger.acknowledging, ledger.acknowledge_wall = True, wall
            out.append((vehicle_id, upto))
        return out

    def complete_to(self, vehicle_id: str) -> int | None:
        """The newest second with nothing open at or before it (None: nothing accounted for)."""
        ledger = self.vehicle(vehicle_id)
        if ledger.gaps:
            return ledger.gaps[0][0] - 1
        return ledger.newest

    def acknowledged(self, vehicle_id: str, mark: int | None, oldest_held: int | None) -> None:
        """The vehicle's reply: its mark now, and the oldest second it holds. The first reply
        of this run opens every second after the mark (from the oldest held, when none) up to
        the newest accounted for: what this run did not see arrive is asked for again."""
        ledger = self.vehicle(vehicle_id)
        ledger.acknowledging = False
        if not ledger.mark_known:
            ledger.mark_known = True
            start = oldest_held if mark is None else max(mark + 1, oldest_held if oldest_held is not None else 0)
            ledger.accountable_from = start
            if start is not None:
                self.reopen(vehicle_id, start, None if ledger.newest is None else ledger.newest + 1)
        ledger.acknowledged = mark

    def lost_before(self, vehicle_id: str, upto: int) -> int:
        """The writer lost items before an acknowledgement up to `upto` was sent: every second
        after the mark up to it is open again (the first second asked for is returned)."""
        ledger = self.vehicle(vehicle_id)
        ledger.acknowledging = False
        if ledger.acknowledged is not None:
            start = ledger.acknowledged + 1
        else:
            start = ledger.accountable_from if ledger.accountable_from is not None else upto + 1
        self.reopen(vehicle_id, start, upto + 1)
        return start

    def acknowledgement_failed(self, vehicle_id: str) -> None:
        """Unanswered or not taken: due again after acknowledge_every_s."""
        self.vehicle(vehicle_id).acknowledging = False

    def reopen(self, vehicle_id: str, start: int, end: int | None) -> None:
        """Seconds [start, end) are open again (asked for from the vehicle); end None: nothing
        accounted for yet, the first record opens the gap from `start`."""
        ledger = self.vehicle(vehicle_id)
        if end is None:
            ledger.newest = start - 1 if ledger.newest is None else ledger.newest
            return
        if end <= start:
            return
        merged: list[list[int]] = []
        for gap in sorted([*ledger.gaps, [start, end]], key=_start):
            if merged and gap[0] <= merged[-1][1]:
                merged[-1][1] = max(merged[-1][1], gap[1])
            else:
                merged.append(list(gap))
        ledger.gaps = merged

    def failed(self, vehicle_id: str) -> None:
        """The request in flight went unanswered: asked again after backfill_retry_s."""
        self.vehicle(vehicle_id).in_flight = None

    def open_seconds(self, vehicle_id: str) -> int:
        return sum(end - start for start, end in self.vehicle(vehicle_id).gaps)

    @staticmethod
    def _fill(ledger: VehicleLedger, seconds: set[int], count: bool = True) -> None:
        """Close the seconds given in the gaps that hold them. The work is the gaps they touch
        and the seconds given, never the seconds a gap spans: a gap may be days long."""
        if not seconds:
            return
        ordered = sorted(seconds)
        # the gaps that may hold one: from the last starting at or before the lowest to the last
        # starting at or before the highest (the gaps are disjoint, oldest first)
        first = max(bisect_right(ledger.gaps, ordered[0], key=_start) - 1, 0)
        last = bisect_right(ledger.gaps, ordered[-1], key=_start)
        kept: list[list[int]] = []
        for start, end in ledger.gaps[first:last]:
            cursor = start
            for k in ordered[bisect_left(ordered, start) : bisect_left(ordered, end)]:
                if count:
                    ledger.filled += 1
                if k > cursor:
                    kept.append([cursor, k])
                cursor = k + 1
            if cursor < end:
                kept.append([cursor, end])
        ledger.gaps[first:last] = kept


def _start(gap: list[int]) -> int:
    return gap[0]


def epoch_of(value: datetime | str) -> float:
    """A stored record's or event's time (a datetime, or RFC 3339 text) as UTC epoch seconds."""
    if isinstance(value, str):
        value = datetime.fromisoformat(value.replace("Z", "+00:00"))
    if value.tzinfo is None:
        value = value.replace(tzinfo=UTC)
    return value.timestamp()
