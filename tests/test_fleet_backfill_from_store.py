"""The fleet fills a gap of any age from the vehicle's store, not from the recorder's memory
(issue 42, item 3): a real recorder node on a real SQLite file answers `blackbox/records`, the
fleet's ledger asks and closes. Before the change a 2-hour outage left 3,599 seconds "left on
vehicle", never asked for again."""

from __future__ import annotations

import time
from datetime import UTC, datetime

from ares.app import run_config
from ares.core import config
from ares.core.clock import ManualClock
from ares.core.membus import MemoryNetwork
from ares.core.messages import RecordRange, VehicleRecord
from blackbox.fleet.sync import FleetLedger, FleetSyncParams
from blackbox.register.recorder_node import Recorder
from blackbox.register.store.sqlite_store import SqliteStore
from tests.helpers.stack import NO_LIDARS

VEHICLE = "shuttle01"
NOW = int(time.time()) // 3600 * 3600  # within the store's 7-day retention
OUTAGE_S = 7200


def _recorder(tmp_path, store_path, **params) -> Recorder:
    clock = ManualClock(utc_epoch=float(NOW))
    cfg = run_config.build(
        (str(NO_LIDARS),),
        config.deep_merge({"vehicle_id": VEHICLE, "blackbox_store": {"uri": str(store_path)}}, {"blackbox": params}),
    )
    node = Recorder(cfg, clock=clock, bus=MemoryNetwork("v").bus("blackbox", clock, vehicle_id=VEHICLE))
    node.setup()
    return node


def _stored_outage(path, missing: set[int] = frozenset()) -> None:
    """The vehicle's store as the outage left it: every second of the 2 hours, but `missing`."""
    store = SqliteStore(str(path))
    start = NOW - OUTAGE_S
    store.insert_records(
        [
            VehicleRecord(vehicle_id=VEHICLE, time=datetime.fromtimestamp(k, UTC), t=float(k - start), run="before")
            for k in range(start, NOW)
            if k not in missing
        ]
    )
    store.close()


def _fill(recorder: Recorder, ledger: FleetLedger, rounds: int) -> set[int]:
    received: set[int] = set()
    wall = 0.0
    for _ in range(rounds):
        wall += 1.0
        for _, start, end in ledger.requests(wall):
            batch = recorder._records(RecordRange(t=0.0, start_epoch_s=start, end_epoch_s=end))
            seconds = {int(r.time.timestamp()) for r in batch.records}
            received |= seconds
            ledger.answered(VEHICLE, seconds, batch.oldest_epoch_s, batch.complete_to_epoch_s)
    return received


def test_a_two_hour_outage_is_filled_completely_from_the_vehicles_store(tmp_path):
    store_path = tmp_path / "vehicle.sqlite"
    never = {NOW - 5000, NOW - 4999, NOW - 10}  # seconds the recorder did not write (not running)
    _stored_outage(store_path, missing=never)
    recorder = _recorder(tmp_path, store_path, fleet_memory_s=3600, answer_max_records=250)
    ledger = FleetLedger(FleetSyncParams(backfill_max_s=600))
    ledger.heard(VEHICLE, 0.0)
    ledger.record(VEHICLE, NOW - OUTAGE_S - 1, 0.0)  # the last second before the link was cut
    ledger.record(VEHICLE, NOW, float(OUTAGE_S))  # the first after
    try:
        received = _fill(recorder, ledger, rounds=200)
    finally:
        recorder.teardown()
        recorder.bus.close()
    v = ledger.vehicle(VEHICLE)
    assert ledger.open_seconds(VEHICLE) == 0 and v.gaps == []
    assert len(received) == OUTAGE_S - len(never) == v.filled
    assert v.left_on_vehicle == 0 and v.never_recorded == len(never)


def test_a_store_that_cannot_be_read_leaves_the_seconds_open_to_ask_again(tmp_path):
    store_path = tmp_path / "vehicle.sqlite"
    _stored_outage(store_path)
    recorder = _recorder(tmp_path, store_path, answer_store_retry_s=3600.0)
    recorder.reader_retry_at = float("inf")  # as after a read that failed: memory alone answers
    ledger = FleetLedger(FleetSyncParams(backfill_max_s=600, backfill_retry_s=2.0))
    ledger.heard(VEHICLE, 0.0)
    ledger.record(VEHICLE, NOW - OUTAGE_S - 1, 0.0)
    ledger.record(VEHICLE, NOW, float(OUTAGE_S))
    try:
        assert _fill(recorder, ledger, rounds=10) == set()
        assert ledger.open_seconds(VEHICLE) == OUTAGE_S  # not closed: neither sent nor "never recorded"
        v = ledger.vehicle(VEHICLE)
        assert v.never_recorded == 0 and v.left_on_vehicle == 0
        recorder.reader_retry_at = 0.0  # the store answers again
        assert len(_fill(recorder, ledger, rounds=200)) == OUTAGE_S
        assert ledger.open_seconds(VEHICLE) == 0
    finally:
        recorder.teardown()
        recorder.bus.close()


def test_the_fleets_acknowledgement_is_kept_and_one_naming_the_future_or_the_past_is_refused(tmp_path):
    from ares.core.messages import Acknowledgement

    store_path = tmp_path / "vehicle.sqlite"
    _stored_outage(store_path)
    recorder = _recorder(tmp_path, store_path)
    try:
        recorder.clock.advance(3.0)
        recorder.step_once(recorder.clock.now())  # seconds NOW+1 .. NOW+3 recorded
        newest = recorder.newest_recorded
        assert newest == NOW + 3
        asked = recorder._acknowledge(Acknowledgement(t=0.0))
        assert (asked.acknowledged_epoch_s, asked.oldest_held_epoch_s, asked.refused) == (None, NOW - OUTAGE_S, "")
        assert recorder._acknowledge(Acknowledgement(t=0.0, upto_epoch_s=NOW - 100)).acknowledged_epoch_s == NOW - 100
        future = recorder._acknowledge(Acknowledgement(t=0.0, upto_epoch_s=NOW + 10**9))
        assert future.acknowledged_epoch_s == newest and "ahead of the newest second recorded" in future.refused
        past = recorder._acknowledge(Acknowledgement(t=0.0, upto_epoch_s=NOW - 5000))
        assert past.acknowledged_epoch_s == newest and "behind the mark" in past.refused
        assert recorder.acknowledgements_refused == 2
    finally:
        recorder.teardown()
        recorder.bus.close()
    reopened = SqliteStore(str(store_path))
    assert reopened.acknowledged(VEHICLE) == newest  # in the file: it outlives the recorder
    reopened.close()
