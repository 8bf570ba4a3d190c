"""Nothing deleted that the fleet has not acknowledged (issue 42, item 3): the embedded store's
acknowledged-up-to mark and its purge, on real SQLite files under a controlled store clock."""

from __future__ import annotations

import sqlite3
from datetime import UTC, datetime, timedelta

from ares.core.messages import VehicleRecord
from blackbox.register.store.record_store import RETENTION, StoreSettings
from blackbox.register.store.sqlite_store import SqliteStore

VEHICLE = "shuttle01"
BASE = datetime(2026, 6, 1, tzinfo=UTC)
WEEK = int(RETENTION.total_seconds())
KEEPING = StoreSettings(synchronous="OFF", keep_until_acknowledged=True)


def _record(epoch_s: int) -> VehicleRecord:
    return VehicleRecord(vehicle_id=VEHICLE, time=datetime.fromtimestamp(epoch_s, UTC), t=float(epoch_s), run="r")


def _seconds(store: SqliteStore) -> list[int]:
    rows = store.records(VEHICLE, datetime(2000, 1, 1, tzinfo=UTC), datetime(2100, 1, 1, tzinfo=UTC), limit=100_000)
    return [int(r["time"].timestamp()) for r in rows]


def _store_with_a_week_and_an_hour(path, settings: StoreSettings, clock: list[datetime]) -> tuple[SqliteStore, int]:
    """Records of the hour 8 days ago and of now, inserted while they were young."""
    now = int(BASE.timestamp())
    old = now - WEEK - 24 * 3600
    clock[0] = BASE - timedelta(days=8)
    store = SqliteStore(str(path), now=lambda: clock[0], settings=settings)
    store.insert_records([_record(old + k) for k in range(3600)])
    clock[0] = BASE
    store.insert_records([_record(now - k) for k in range(10)])
    return store, old


def test_without_an_acknowledgement_the_keeping_store_purges_nothing_and_says_what_it_keeps(tmp_path):
    clock = [BASE]
    store, old = _store_with_a_week_and_an_hour(tmp_path / "v.sqlite", KEEPING, clock)
    assert len(_seconds(store)) == 3610  # the insert of now's seconds purged nothing
    assert store.purge_expired() == 0
    assert store.unacknowledged_expired(VEHICLE) == (3600, old)
    store.close()


def test_the_purge_deletes_only_the_acknowledged_seconds_past_the_retention(tmp_path):
    clock = [BASE]
    store, old = _store_with_a_week_and_an_hour(tmp_path / "v.sqlite", KEEPING, clock)
    assert store.acknowledge(VEHICLE, old + 1799) == old + 1799  # the fleet holds the first half hour
    assert store.purge_expired() == 1800
    kept = _seconds(store)
    assert kept[0] == old + 1800 and len(kept) == 1810
    assert store.unacknowledged_expired(VEHICLE) == (1800, old + 1800)
    store.close()


def test_the_seven_day_purge_is_as_before_without_the_setting(tmp_path):
    clock = [BASE]
    store, _ = _store_with_a_week_and_an_hour(tmp_path / "v.sqlite", StoreSettings(synchronous="OFF"), clock)
    assert len(_seconds(store)) == 10  # the insert of now's seconds purged the old hour
    store.close()


def test_the_mark_survives_reopening_and_never_goes_back(tmp_path):
    path = tmp_path / "v.sqlite"
    store = SqliteStore(str(path), settings=KEEPING)
    assert store.acknowledged(VEHICLE) is None
    assert store.acknowledge(VEHICLE, 1_000_000) == 1_000_000
    store.close()
    reopened = SqliteStore(str(path), settings=KEEPING)
    assert reopened.acknowledged(VEHICLE) == 1_000_000
    assert reopened.acknowledge(VEHICLE, 999_000) == 1_000_000  # backwards: the higher mark stays
    assert reopened.acknowledged("shuttle02") is None  # per vehicle
    reopened.close()


def test_a_file_from_before_the_mark_gains_its_table_when_opened(tmp_path):
    path = tmp_path / "v.sqlite"
    store = SqliteStore(str(path), settings=KEEPING)
    store.insert_records([_record(int(BASE.timestamp()))])
    store.close()
    with sqlite3.connect(path) as conn:
        conn.execute("DROP TABLE acknowledged")
    reopened = SqliteStore(str(path), settings=KEEPING)
    assert reopened.acknowledge(VEHICLE, 5) == 5 and reopened.oldest_second(VEHICLE) == int(BASE.timestamp())
    reopened.close()
