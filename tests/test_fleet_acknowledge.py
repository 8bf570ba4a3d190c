"""The fleet acknowledges what its store holds, and a vehicle that waits for it deletes nothing
else (issue 42, item 3): real recorders keeping their records until acknowledged, the fleet's
sync node and its real writer, one in-memory network and a manual clock. Through a 30 s link
cut, a restart of the fleet's sync and a full disk under the fleet's store (a real 3 MB tmpfs)
the vehicle's mark never covers a second the fleet's store lacks; the ledger's part alone: every
state of an acknowledgement, and a hypothesis property."""

from __future__ import annotations

import os
import subprocess
from datetime import UTC, datetime

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ares.app import run_config
from ares.core import config
from ares.core.clock import ManualClock
from ares.core.membus import MemoryNetwork
from ares.core.messages import VehicleRecord
from blackbox.fleet.sync import FleetLedger, FleetSyncParams
from blackbox.fleet.sync_node import FleetSync
from blackbox.register.recorder_node import Recorder
from blackbox.register.store.sqlite_store import SqliteStore
from tests.helpers.stack import NO_LIDARS, wait_until
from tests.test_fleet_sync import UTC_EPOCH, VEHICLES, FleetNetwork, _seconds
from tests.test_recorder_trust import fill

FAST_WRITER = {"batch_wait_s": 0.05, "retry_min_s": 0.05, "retry_max_s": 0.2}


def _cfg(vehicle_id: str, store, **sections) -> dict:
    return run_config.build((str(NO_LIDARS),), config.deep_merge({"vehicle_id": vehicle_id}, sections))


def _mark(path, vehicle_id: str) -> int | None:
    store = SqliteStore(str(path))
    try:
        return store.acknowledged(vehicle_id)
    finally:
        store.close()


class Rig:
    """Two vehicles whose recorders keep every record until acknowledged, and the fleet."""

    def __init__(self, tmp_path, fleet_folder=None, fleet_memory: int = 7200):
        self.tmp = tmp_path
        self.clock = ManualClock(utc_epoch=UTC_EPOCH)
        self.network = FleetNetwork()
        self.recorders = {
            v: Recorder(
                _cfg(
                    v,
                    None,
                    blackbox_store={"uri": str(tmp_path / f"{v}.sqlite"), "keep_until_acknowledged": True},
                ),
                clock=self.clock,
                bus=self.network.bus("blackbox", self.clock, vehicle_id=v),
            )
            for v in VEHICLES
        }
        for recorder in self.recorders.values():
            recorder.setup()
        self.fleet_store = (fleet_folder or tmp_path) / "fleet.sqlite"
        self.fleet_memory = fleet_memory
        self.sync = self.start_fleet()

    def start_fleet(self) -> FleetSync:
        cfg = _cfg(
            "fleet",
            None,
            blackbox_store={"uri": str(self.fleet_store), "synchronous": "OFF"},
            fleet_sync={"acknowledge_every_s": 2.0, "memory_max_entries": self.fleet_memory, **FAST_WRITER},
        )
        sync = FleetSync(cfg, clock=self.clock, bus=self.network.bus("fleet_sync", self.clock, vehicle_id="fleet"))
        sync.setup()
        sync.wall = lambda: UTC_EPOCH + self.clock.now()
        return sync

    def stop_fleet(self) -> None:
        self.sync.teardown()
        self.sync.bus.close()

    def drive(self, seconds: float) -> None:
        until = self.clock.now() + seconds
        while self.clock.now() < until - 1e-9:
            self.clock.advance(0.2)
            for node in (*self.recorders.values(), self.sync):
                node.step_once(self.clock.now())

    def mark(self, vehicle_id: str) -> int | None:
        return _mark(self.tmp / f"{vehicle_id}.sqlite", vehicle_id)

    def newest(self, vehicle_id: str) -> int:
        return self.recorders[vehicle_id].newest_recorded

    def caught_up(self, vehicle_id: str, within_s: int = 6) -> bool:
        """The vehicle's mark is within `within_s` of its newest record (driving on meanwhile;
        the manual clock runs ahead of the writer's real thread, so callers wait for this)."""
        self.drive(0.2)
        mark = self.mark(vehicle_id)
        return mark is not None and mark >= self.newest(vehicle_id) - within_s

    def assert_marks_hold(self) -> None:
        """Every second a vehicle recorded up to its mark is in the fleet's store."""
        for v in VEHICLES:
            mark = self.mark(v)
            if mark is None:
                continue
            on_vehicle = {k for k in _seconds(self.tmp / f"{v}.sqlite", v) if k <= mark}
            missing = sorted(on_vehicle - set(_seconds(self.fleet_store, v)))
            assert not missing, f"{v}: acknowledged up to {mark}, the fleet lacks {missing[:10]}"

    def close(self) -> None:
        for node in (*self.recorders.values(), self.sync):
            node.teardown()
            node.bus.close()


def test_through_a_link_cut_and_a_restart_of_the_fleet_the_marks_cover_only_what_the_fleet_holds(tmp_path):
    rig = Rig(tmp_path)
    try:
        for v in VEHICLES:
            wait_until(lambda v=v: rig.caught_up(v), 30, f"{v}'s first acknowledgement", interval_s=0.01)
        rig.assert_marks_hold()

        rig.network.cut_link("shuttle01")
        cut_at = rig.newest("shuttle01")
        rig.drive(30.0)
        assert rig.mark("shuttle01") <= cut_at  # nothing of the cut is acknowledged
        wait_until(lambda: rig.caught_up("shuttle02"), 30, "the other vehicle's marks going on", interval_s=0.01)
        assert rig.mark("shuttle01") <= cut_at
        rig.network.heal("shuttle01")
        wait_until(lambda: rig.caught_up("shuttle01"), 30, "the cut filled and acknowledged", interval_s=0.01)
        assert rig.mark("shuttle01") > cut_at + 25
        rig.assert_marks_hold()

        rig.stop_fleet()  # the fleet's sync restarts: it learns each mark and asks what follows it again
        before = {v: rig.mark(v) for v in VEHICLES}
        rig.drive(10.0)  # the vehicles go on recording while the fleet is away
        rig.sync = rig.start_fleet()
        for v in VEHICLES:
            wait_until(lambda v=v: rig.caught_up(v), 30, f"{v} acknowledged after the restart", interval_s=0.01)
            assert rig.sync.ledger.vehicle(v).mark_known and rig.mark(v) > before[v] + 10
        rig.assert_marks_hold()
    finally:
        rig.close()
    rig.assert_marks_hold()


@pytest.fixture
def small_disk(tmp_path):
    """A 3 MB filesystem of its own for the fleet's store and spool, unmounted after the test."""
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    mount = tmp_path / "fleet-disk"
    mount.mkdir()
    subprocess.run(["mount", "-t", "tmpfs", "-o", "size=3m", "tmpfs", str(mount)], check=True)
    try:
        yield mount
    finally:
        subprocess.run(["umount", "-l", str(mount)], check=False)


def test_records_the_fleets_full_disk_dropped_are_asked_for_again_never_acknowledged(tmp_path, small_disk):
    rig = Rig(tmp_path, fleet_folder=small_disk, fleet_memory=20)
    try:
        for v in VEHICLES:
            wait_until(lambda v=v: rig.caught_up(v), 30, f"{v}'s first acknowledgement", interval_s=0.01)
        filler = fill(small_disk)
        full_at = {v: rig.newest(v) for v in VEHICLES}
        wait_until(
            lambda: rig.drive(1.0) or rig.sync.writer.losses > 0, 60, "the fleet's writer dropping", interval_s=0.01
        )
        wait_until(
            lambda: rig.drive(0.2) or rig.sync.acknowledgements_withheld > 0,
            60,
            "an acknowledgement withheld for the loss",
            interval_s=0.01,
        )
        for v in VEHICLES:  # nothing the writer could not store is acknowledged
            assert rig.mark(v) <= full_at[v] + 2
        rig.assert_marks_hold()

        os.unlink(filler)
        for v in VEHICLES:
            wait_until(lambda v=v: rig.caught_up(v), 60, f"{v}'s dropped seconds asked again", interval_s=0.01)
            assert rig.mark(v) > full_at[v] + 10
        rig.assert_marks_hold()
    finally:
        rig.close()
    rig.assert_marks_hold()


# ---- the ledger alone ------------------------------------------------------------------------

V = "shuttle01"


def _ledger(every_s: float = 10.0) -> FleetLedger:
    ledger = FleetLedger(FleetSyncParams(acknowledge_every_s=every_s))
    ledger.heard(V, 0.0)
    return ledger


def test_the_mark_is_asked_for_first_and_what_follows_it_is_asked_again():
    ledger = _ledger()
    ledger.known(V, 1000)  # the fleet's store held up to 1000 at its start
    assert ledger.acknowledgements(0.0) == [(V, None)]
    assert ledger.acknowledgements(100.0) == []  # one at a time
    ledger.acknowledged(V, 900, oldest_held=100)
    assert ledger.vehicle(V).gaps == [[901, 1001]]  # unseen by this run: asked for again
    assert ledger.complete_to(V) == 900 and ledger.acknowledgements(100.0) == []  # nothing new yet
    ledger.requests(100.0)
    ledger.answered(V, set(range(901, 1001)), None, complete_to=1001)
    assert ledger.acknowledgements(110.0) == [(V, 1000)]


def test_a_vehicle_never_acknowledged_is_asked_for_from_its_oldest_second():
    ledger = _ledger()
    assert ledger.acknowledgements(0.0) == [(V, None)]
    ledger.acknowledged(V, None, oldest_held=500)
    ledger.record(V, 2000, 0.0)  # the first live record: everything from 500 is a gap
    assert ledger.vehicle(V).gaps == [[500, 2000]] and ledger.complete_to(V) == 499


def test_acknowledgements_wait_for_the_interval_and_for_progress_past_the_mark():
    ledger = _ledger(every_s=10.0)
    ledger.acknowledgements(0.0)
    ledger.acknowledged(V, None, oldest_held=None)  # an empty store, never acknowledged
    for k in range(100, 110):
        ledger.record(V, k, 0.0)
    assert ledger.acknowledgements(5.0) == []  # within the interval
    assert ledger.acknowledgements(10.0) == [(V, 109)]
    ledger.acknowledged(V, 109, oldest_held=100)
    assert ledger.acknowledgements(30.0) == []  # nothing new past the mark
    ledger.record(V, 115, 0.0)  # a gap [110, 115): only up to 109 is complete
    assert ledger.acknowledgements(40.0) == []
    ledger.requests(40.0)
    ledger.answered(V, {110, 111, 112, 113, 114}, None, complete_to=115)
    assert ledger.acknowledgements(50.0) == [(V, 115)]


def test_a_loss_in_the_writer_opens_everything_after_the_mark_again():
    ledger = _ledger(every_s=1.0)
    ledger.acknowledgements(0.0)
    ledger.acknowledged(V, 99, oldest_held=50)
    for k in range(100, 200):
        ledger.record(V, k, 0.0)
    assert ledger.acknowledgements(1.0) == [(V, 199)]
    assert ledger.lost_before(V, 199) == 100
    assert ledger.vehicle(V).gaps == [[100, 200]] and ledger.complete_to(V) == 99
    assert ledger.acknowledgements(2.0) == []  # nothing is complete past the mark until it is filled


def test_an_unanswered_question_is_asked_again_only_while_reachable():
    ledger = _ledger(every_s=1.0)
    assert ledger.acknowledgements(0.0) == [(V, None)]
    ledger.acknowledgement_failed(V)
    assert ledger.silent(10.0)  # unreachable
    assert ledger.acknowledgements(10.0) == []
    ledger.heard(V, 11.0)
    assert ledger.acknowledgements(11.0) == [(V, None)]


@settings(max_examples=300, deadline=None)
@given(
    arrivals=st.lists(st.tuples(st.integers(0, 300), st.booleans()), min_size=1, max_size=120),
    mark=st.one_of(st.none(), st.integers(0, 300)),
    oldest=st.one_of(st.none(), st.integers(0, 300)),
    stored_at_start=st.one_of(st.none(), st.integers(0, 300)),
)
def test_no_acknowledgement_covers_a_second_the_fleet_did_not_keep(arrivals, mark, oldest, stored_at_start):
    """Seconds arrive live in any order, and the writer keeps some and loses others (a loss is
    seen when an acknowledgement is due, and reopens): every second acknowledged past the
    vehicle's own mark (and from the oldest second it holds) arrived and was kept."""
    ledger = _ledger(every_s=1.0)
    ledger.known(V, stored_at_start)
    assert ledger.acknowledgements(0.0) == [(V, None)]
    ledger.acknowledged(V, mark, oldest)
    kept: set[int] = set()
    lost_since = False
    for i, (k, is_lost) in enumerate(arrivals):
        ledger.record(V, k, 0.0)
        if is_lost:
            lost_since = True
        else:
            kept.add(k)
        for vehicle, upto in ledger.acknowledgements(float(i + 1)):
            if lost_since:
                ledger.lost_before(vehicle, upto)
                lost_since = False
                continue
            floor = ledger.vehicle(V).accountable_from if mark is None else mark + 1
            if floor is not None and oldest is not None:  # older than its oldest: none the vehicle holds
                floor = max(floor, oldest)
            if floor is not None:
                assert set(range(floor, upto + 1)) <= kept, (floor, upto, sorted(kept)[:20])
            ledger.acknowledged(V, upto, oldest)
            mark = upto


def test_a_recorder_says_how_many_records_past_the_retention_wait_for_the_fleet(tmp_path):
    """A keeping store the fleet never acknowledged: the records of 8 days ago are kept, and told."""
    path = tmp_path / "v.sqlite"
    eight_days_ago = int(UTC_EPOCH) - 8 * 24 * 3600
    store = SqliteStore(str(path))
    store.insert_records(
        [
            VehicleRecord(vehicle_id="shuttle01", time=datetime.fromtimestamp(eight_days_ago + k, UTC), t=k, run="r")
            for k in range(120)
        ]
    )
    store.close()
    clock = ManualClock(utc_epoch=UTC_EPOCH)
    network = MemoryNetwork("v")
    listener = network.bus("test", clock, vehicle_id="shuttle01")
    heard = listener.subscribe("events", queue=100)
    recorder = Recorder(
        _cfg("shuttle01", None, blackbox_store={"uri": str(path), "keep_until_acknowledged": True}),
        clock=clock,
        bus=network.bus("blackbox", clock, vehicle_id="shuttle01"),
    )
    recorder.setup()
    try:
        for _ in range(5):
            clock.advance(0.2)
            recorder.step_once(clock.now())
    finally:
        recorder.teardown()
        recorder.bus.close()
    told = [e for _, e in heard.drain() if e.kind == "blackbox_unacknowledged_kept"]
    assert len(told) == 1 and told[0].data["kept"] == 120 and told[0].data["oldest_epoch_s"] == eight_days_ago
    assert "acknowledged nothing" in told[0].message
