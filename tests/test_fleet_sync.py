"""The fleet's black box (blackbox/fleet/sync.py, blackbox/fleet/sync_node.py): two vehicles'
real recorders and the fleet's sync node on one in-memory network and a manual clock, each with
a store of its own; a link cut for 60 s; every second each vehicle stored reaches the fleet's
store, none twice. The ledger alone: every state of a gap, and a hypothesis property."""

from __future__ import annotations

import time
from datetime import UTC, datetime

from hypothesis import given, settings
from hypothesis import strategies as st

from ares.app import run_config
from ares.core import config
from ares.core.clock import ManualClock
from ares.core.membus import MemoryNetwork
from ares.core.messages import EventLevel, StoredEvent
from blackbox.fleet.sync import FleetLedger, FleetSyncParams, epoch_of
from blackbox.fleet.sync_node import FleetSync
from blackbox.register.recorder import spool_path
from blackbox.register.recorder_node import Recorder
from blackbox.register.spool import Spool
from blackbox.register.store.record_store import StoreSettings
from blackbox.register.store.sqlite_store import SqliteStore
from tests.helpers.stack import NO_LIDARS, wait_until

UTC_EPOCH = float(int(time.time()) // 3600 * 3600)  # within the stores' 7-day retention
VEHICLES = ("shuttle01", "shuttle02")
PAST, FUTURE = datetime(2000, 1, 1, tzinfo=UTC), datetime(2100, 1, 1, tzinfo=UTC)


class FleetNetwork(MemoryNetwork):
    """One network for the vehicles and the fleet; a vehicle's link to the fleet can be cut: the
    fleet's subscriptions (`ares/*/...`) hear nothing of it and its services are out of reach."""

    def __init__(self):
        super().__init__("fleet")
        self.cut: set[str] = set()

    def delivers(self, key: str, pattern: str) -> bool:
        return key.split("/")[1] not in self.cut or not pattern.startswith("ares/*/")

    def serves(self, key: str) -> bool:
        return key.split("/")[1] not in self.cut

    def cut_link(self, vehicle: str) -> None:
        self.cut.add(vehicle)

    def heal(self, vehicle: str) -> None:
        self.cut.discard(vehicle)


def _cfg(vehicle_id: str, store) -> dict:
    return run_config.build(
        (str(NO_LIDARS),), config.deep_merge({"vehicle_id": vehicle_id}, {"blackbox_store": {"uri": str(store)}})
    )


def _seconds(path, vehicle_id: str) -> list[int]:
    store = SqliteStore(str(path))
    try:
        rows = store.records(vehicle_id, PAST, FUTURE, limit=100_000)
    finally:
        store.close()
    return [int(epoch_of(r["time"])) for r in rows]


def _events(path, vehicle_id: str) -> list[dict]:
    store = SqliteStore(str(path))
    try:
        return store.events(vehicle_id, PAST, FUTURE, limit=100_000)
    finally:
        store.close()


def test_a_link_cut_for_60_s_loses_no_second_and_the_fleet_marks_the_vehicle_unreachable(tmp_path):
    clock = ManualClock(utc_epoch=UTC_EPOCH)
    network = FleetNetwork()
    recorders = {
        v: Recorder(_cfg(v, tmp_path / f"{v}.sqlite"), clock=clock, bus=network.bus("blackbox", clock, vehicle_id=v))
        for v in VEHICLES
    }
    fleet_store = tmp_path / "fleet.sqlite"
    sync = FleetSync(_cfg("fleet", fleet_store), clock=clock, bus=network.bus("fleet_sync", clock, vehicle_id="fleet"))
    for node in (*recorders.values(), sync):
        node.setup()
    sync.wall = lambda: UTC_EPOCH + clock.now()  # the wall as the vehicles' clock: one time line here
    ledger = sync.ledger

    def drive(until: float) -> None:
        while clock.now() < until - 1e-9:
            clock.advance(0.2)
            for node in (*recorders.values(), sync):
                node.step_once(clock.now())

    drive(20.0)
    assert all(ledger.vehicle(v).reachable for v in VEHICLES)
    network.cut_link("shuttle01")
    cut_at = clock.now()
    unreachable_at = None
    while clock.now() < cut_at + 60.0:
        drive(clock.now() + 0.2)
        if unreachable_at is None and not ledger.vehicle("shuttle01").reachable:
            unreachable_at = clock.now()
    assert unreachable_at is not None and unreachable_at - cut_at <= 5.0
    assert ledger.vehicle("shuttle02").reachable  # the other vehicle's link is not this one's
    network.heal("shuttle01")
    drive(clock.now() + 3.0)
    assert ledger.vehicle("shuttle01").reachable

    def filled() -> bool:
        drive(clock.now() + 0.2)
        return ledger.open_seconds("shuttle01") == 0 and ledger.vehicle("shuttle01").in_flight is None

    wait_until(filled, 30, "the gap filled from the recorder's memory", interval_s=0.01)
    for node in (*recorders.values(), sync):
        node.teardown()
        node.bus.close()

    for v in VEHICLES:
        on_vehicle, at_fleet = _seconds(tmp_path / f"{v}.sqlite", v), _seconds(fleet_store, v)
        assert len(on_vehicle) >= 80 and len(set(at_fleet)) == len(at_fleet)  # none twice
        assert set(on_vehicle) <= set(at_fleet), f"{v}: {sorted(set(on_vehicle) - set(at_fleet))[:10]} lost"
    assert ledger.vehicle("shuttle01").filled >= 55 and ledger.vehicle("shuttle01").left_on_vehicle == 0
    kinds = [e["kind"] for e in _events(fleet_store, "shuttle01")]
    assert kinds.count("vehicle_unreachable") == 1 and kinds.count("vehicle_reachable") == 2  # first heard, back


def test_the_fleets_teardown_publishes_what_its_writer_said_last(tmp_path):
    """The writer's last notices (here: a spool left by an earlier run, flushed at start) reach
    the events even when the node stops before another step would have published them."""
    clock = ManualClock(utc_epoch=UTC_EPOCH)
    network = MemoryNetwork("fleet")
    cfg = _cfg("fleet", tmp_path / "fleet.sqlite")
    left = Spool(spool_path(FleetSyncParams(), config.section(cfg, "blackbox_store", StoreSettings), "fleet"), 10)
    left.append(
        [
            StoredEvent(
                vehicle_id="shuttle01",
                time=datetime.fromtimestamp(UTC_EPOCH, UTC),
                t=0.0,
                source="blackbox",
                kind="left_over",
                level=EventLevel.INFO,
                message="from before",
            )
        ]
    )
    left.close()
    listener = network.bus("test", clock, vehicle_id="fleet")
    published = listener.subscribe("events", queue=10)
    sync = FleetSync(cfg, clock=clock, bus=network.bus("fleet_sync", clock, vehicle_id="fleet"))
    sync.setup()
    try:
        wait_until(lambda: not sync.writer.notices.empty(), 10, "the writer to flush the leftover spool")
    finally:
        sync.teardown()  # no step in between: only teardown can publish the notice
        sync.bus.close()
    assert [(e.source, e.kind, e.data["flushed"]) for _, e in published.drain()] == [
        ("fleet_sync", "blackbox_spool_flushed", 1)
    ]
    assert [e["kind"] for e in _events(tmp_path / "fleet.sqlite", "shuttle01")] == ["left_over"]


def test_the_answer_of_a_recorder_that_no_longer_holds_a_second_leaves_it_on_the_vehicle():
    ledger = FleetLedger(FleetSyncParams())
    ledger.heard("v", 0.0)
    ledger.record("v", 100, 0.0)
    ledger.record("v", 110, 10.0)  # 101..109 missing
    assert ledger.vehicle("v").gaps == [[101, 110]]
    assert ledger.requests(1.0) == [("v", 101, 110)]
    assert ledger.requests(1.5) == []  # one in flight
    ledger.answered("v", {104, 105, 106, 108, 109}, oldest_held=104)
    v = ledger.vehicle("v")
    assert (v.filled, v.left_on_vehicle, v.never_recorded, v.gaps) == (5, 3, 1, [])


def test_an_unanswered_request_is_asked_again_after_the_retry_and_not_while_unreachable():
    p = FleetSyncParams(unreachable_after_s=3.0, backfill_retry_s=2.0)
    ledger = FleetLedger(p)
    ledger.heard("v", 0.0)
    ledger.record("v", 1, 0.0)
    ledger.record("v", 5, 4.0)
    assert ledger.requests(0.0) == [("v", 2, 5)]
    ledger.failed("v")
    assert ledger.requests(1.0) == []  # before the retry
    assert ledger.requests(2.5) == [("v", 2, 5)]
    ledger.failed("v")
    assert [r.reachable for r in ledger.silent(10.0)] == [False]
    assert ledger.requests(20.0) == []  # unreachable: nobody to ask
    assert ledger.heard("v", 21.0).reachable
    assert ledger.requests(21.0) == [("v", 2, 5)]


def test_a_long_gap_is_asked_for_in_pieces():
    ledger = FleetLedger(FleetSyncParams(backfill_max_s=10))
    ledger.heard("v", 0.0)
    ledger.record("v", 0, 0.0)
    ledger.record("v", 26, 26.0)
    asked = []
    for wall in range(10):
        for _, start, end in ledger.requests(float(wall)):
            asked.append((start, end))
            ledger.answered("v", set(range(start, end)), oldest_held=0)
    assert asked == [(1, 11), (11, 21), (21, 26)] and ledger.open_seconds("v") == 0


@settings(max_examples=200, deadline=None)
@given(
    arrivals=st.lists(st.integers(0, 60), min_size=1, max_size=60),
    held_from=st.integers(0, 60),
    missing=st.sets(st.integers(0, 60)),
)
def test_every_second_up_to_the_newest_is_stored_left_on_the_vehicle_or_never_recorded(arrivals, held_from, missing):
    """Whatever arrives live, in whatever order, and whatever the recorder still holds: once the
    gaps are answered, each second from the first to the newest is counted exactly once."""
    ledger = FleetLedger(FleetSyncParams(backfill_max_s=7))
    ledger.heard("v", 0.0)
    live: set[int] = set()
    first = arrivals[0]
    for k in arrivals:
        ledger.record("v", k, float(k))
        live.add(k)
        # after each arrival the open gaps are the seconds from the first to the newest heard so
        # far that have not arrived, nothing more (nothing asked for twice) and nothing less
        open_seconds = {s for start, end in ledger.vehicle("v").gaps for s in range(start, end)}
        assert open_seconds == set(range(first, max(live) + 1)) - live
    newest = max(arrivals)
    stored = {k for k in live if k >= first}
    wall = 0.0
    while ledger.open_seconds("v"):
        wall += 10.0
        for _, start, end in ledger.requests(wall):
            sent = {k for k in range(start, end) if k >= held_from and k not in missing}
            stored |= sent
            ledger.answered("v", sent, oldest_held=held_from)
    v = ledger.vehicle("v")
    assert v.newest == newest
    assert len({k for k in stored if first <= k <= newest}) + v.left_on_vehicle + v.never_recorded == newest - first + 1
