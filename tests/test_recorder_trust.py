"""The black box cannot fail quietly (issue 42): a full disk, a second recorder, a clock set back or
far behind. The writer thread, the spool and the embedded store are the real ones; the full disk
is a real 3 MB tmpfs holding the store and the spool (mounted for the test: it needs root)."""

from __future__ import annotations

import errno
import os
import sqlite3
import subprocess
from datetime import UTC, datetime, timedelta

import pytest

from ares.core.messages import VehicleRecord
from blackbox.register.recorder import StoreWriter
from blackbox.register.spool import Spool, SpoolBusy
from blackbox.register.store.record_store import RETENTION, StoreSettings, utc_now
from blackbox.register.store.sqlite_store import SqliteStore
from tests.helpers.stack import wait_until
from tests.test_recorder import Rig, recorder_config

VEHICLE = "shuttle01"
T0 = datetime.now(UTC).replace(microsecond=0) - timedelta(days=1)
SETTINGS = StoreSettings(synchronous="OFF")


def record(k: int, run: str | None = "run-a", speed: float = 1.0, at: datetime = T0) -> VehicleRecord:
    return VehicleRecord(vehicle_id=VEHICLE, time=at + timedelta(seconds=k), t=float(k), speed_mps=speed, run=run)


def writer_on(folder, **options) -> StoreWriter:
    return StoreWriter(
        lambda: SqliteStore(str(folder / "blackbox.sqlite"), settings=SETTINGS),
        Spool(folder / "blackbox-spool.sqlite", max_entries=1_000_000),
        batch_wait_s=0.05,
        retry_min_s=0.05,
        retry_max_s=0.2,
        **options,
    )


def kinds(writer: StoreWriter) -> list[str]:
    return [notice.kind for notice in writer.take_notices()]


def rows_in(path) -> list[tuple[int, int, str]]:
    """Every record row of a store file, whatever the API shows: (second, dup, run)."""
    db = sqlite3.connect(path)
    try:
        return db.execute("SELECT ts, dup, run FROM records ORDER BY ts, dup").fetchall()
    finally:
        db.close()


@pytest.fixture
def small_disk(tmp_path):
    """A 3 MB filesystem of its own, unmounted after the test."""
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    mount = tmp_path / "disk"
    mount.mkdir()
    subprocess.run(["mount", "-t", "tmpfs", "-o", "size=3m", "tmpfs", str(mount)], check=True)
    try:
        yield mount
    finally:
        subprocess.run(["umount", "-l", str(mount)], check=False)


def fill(folder) -> os.PathLike:
    """Fill the filesystem to its last byte with one file; returns the file (remove it to free the disk)."""
    filler = folder / "filler"
    with open(filler, "wb", buffering=0) as out:  # unbuffered: nothing left to fail at close
        try:
            while True:
                out.write(b"\0" * 65536)
        except OSError as exc:
            assert exc.errno == errno.ENOSPC
    return filler


def test_a_full_disk_is_told_keeps_the_newest_in_memory_and_every_record_counted_is_stored(small_disk):
    writer = writer_on(small_disk, memory_max_entries=500)
    writer.start()
    try:
        for k in range(10):
            writer.submit(record(k))
        wait_until(lambda: writer.records_written == 10 and writer.store_up, 10, "the first records")
        filler = fill(small_disk)
        for k in range(10, 4010):
            assert writer.submit(record(k))
        wait_until(lambda: writer.status().dropped > 0 and writer._queue.empty(), 20, "the memory's bound")
        status = writer.status()
        assert writer._thread.is_alive()  # the writer lives on
        assert not status.store_up and status.store_faults > 0 and status.in_memory == 500
        told = kinds(writer)
        assert "blackbox_store_down" in told and "blackbox_fault" in told
        assert status.written + status.dropped + status.in_memory + status.spooled == 4010

        os.unlink(filler)  # room again: what waits in memory reaches the store, in order
        wait_until(lambda: writer.store_up and not writer.status().in_memory, 20, "the backlog's flush")
        assert "blackbox_store_up" in kinds(writer)
    finally:
        writer.close(2.0)
    status = writer.status()
    assert status.written + status.dropped == 4010 and status.dropped >= 3000
    seconds = [ts for ts, _, _ in rows_in(small_disk / "blackbox.sqlite")]
    assert len(seconds) == status.written  # every record counted as written is in the store
    newest = int((T0 + timedelta(seconds=4009)).timestamp())
    assert seconds[-500:] == list(range(newest - 499, newest + 1))  # the newest were the ones kept


def test_a_writer_stopped_while_the_disk_is_full_counts_what_it_could_not_keep(small_disk):
    """Memory does not outlive the process: what waits there at the stop, with neither the store nor
    the spool taking it, is counted as dropped and told, never left uncounted."""
    writer = writer_on(small_disk, memory_max_entries=500)
    writer.start()
    try:
        for k in range(10):
            writer.submit(record(k))
        wait_until(lambda: writer.records_written == 10 and writer.store_up, 10, "the first records")
        fill(small_disk)
        for k in range(10, 210):
            assert writer.submit(record(k))
        wait_until(lambda: writer.status().in_memory == 200 and writer._queue.empty(), 20, "the records held")
    finally:
        writer.close(2.0)
    status = writer.status()
    assert status.in_memory == 0 and status.spooled == 0
    assert status.written == 10 and status.dropped == 200 and status.written + status.dropped == 210
    assert len(rows_in(small_disk / "blackbox.sqlite")) == status.written
    told = [n for n in writer.take_notices() if n.kind == "blackbox_fault"]
    assert any(n.data.get("dropped") == 200 for n in told), [n.message for n in told]


def test_a_second_writer_on_the_same_spool_is_refused_and_removes_nothing(tmp_path):
    first, second = writer_on(tmp_path), writer_on(tmp_path)
    first.start()
    try:
        with pytest.raises(SpoolBusy):
            second.start()
        first.submit(record(0))
        wait_until(lambda: first.records_written == 1, 10, "the first writer's record")
    finally:
        first.close(2.0)
    again = writer_on(tmp_path)  # the first one gone, the lock is free
    again.start()
    again.close(2.0)


def test_a_clock_set_back_between_two_runs_drops_no_record_and_the_api_keeps_the_first(tmp_path):
    writer = writer_on(tmp_path)
    writer.start()
    try:
        for k in range(100):
            writer.submit(record(k, run="run-a", speed=1.0))
        for k in range(50, 150):  # the second run's clock 50 s behind the first's end
            writer.submit(record(k, run="run-b", speed=2.0))
        wait_until(lambda: writer.records_written == 200, 10, "both runs' records")
    finally:
        writer.close(2.0)
    rows = rows_in(tmp_path / "blackbox.sqlite")
    assert len(rows) == 200  # written 200, stored 200
    assert sum(run == "run-b" and dup == 1 for _, dup, run in rows) == 50
    store = SqliteStore(str(tmp_path / "blackbox.sqlite"), settings=SETTINGS)
    try:
        docs = store.records(VEHICLE, T0, T0 + timedelta(seconds=200))
        assert len(docs) == 150 == store.count_records(VEHICLE, T0, T0 + timedelta(seconds=200))
        # one record per second: the first stored for it (run a's for 50..99), never replaced later
        assert [d["speed_mps"] for d in docs] == [1.0] * 100 + [2.0] * 50
        assert docs[0]["run"] == "run-a" and docs[-1]["run"] == "run-b"  # which run each came from
        # a retried batch of an already stored run is still a no-op
        assert store.insert_records([record(k, run="run-b", speed=2.0) for k in range(50, 150)]) == 0
    finally:
        store.close()


def test_a_store_from_before_the_run_key_is_rebuilt_and_stays_readable(tmp_path):
    path = tmp_path / "blackbox.sqlite"
    db = sqlite3.connect(path)
    db.execute(
        "CREATE TABLE records (vehicle_id TEXT NOT NULL, ts INTEGER NOT NULL, doc TEXT NOT NULL, "
        "PRIMARY KEY (vehicle_id, ts)) WITHOUT ROWID"
    )
    old = [record(k, run=None) for k in range(3)]
    db.executemany(
        "INSERT INTO records VALUES (?, ?, ?)",
        [(r.vehicle_id, int(r.time.timestamp()), r.model_dump_json(exclude={"run"})) for r in old],
    )
    db.commit()
    db.close()
    store = SqliteStore(str(path), settings=SETTINGS)
    try:
        assert [d["t"] for d in store.records(VEHICLE, T0, T0 + timedelta(seconds=10))] == [0.0, 1.0, 2.0]
        assert store.insert_records([record(2, run="new", speed=5.0), record(3, run="new")]) == 2
        assert [d["speed_mps"] for d in store.records(VEHICLE, T0, T0 + timedelta(seconds=10))] == [1.0] * 4
    finally:
        store.close()
    assert rows_in(path) == [(int(r.time.timestamp()), 0, "") for r in old] + [
        (int(T0.timestamp()) + 2, 1, "new"),
        (int(T0.timestamp()) + 3, 0, "new"),
    ]


def test_a_clock_far_behind_the_stores_purges_none_of_what_it_writes(tmp_path):
    behind = (utc_now() - RETENTION - timedelta(days=1)).replace(microsecond=0)  # a vehicle clock 8 days behind
    store = SqliteStore(str(tmp_path / "blackbox.sqlite"), settings=SETTINGS)
    try:
        assert store.insert_records([record(k, at=behind) for k in range(600)]) == 600  # the purge was due
        assert store.count_records(VEHICLE, behind, behind + timedelta(seconds=600)) == 600
        assert store.purge_expired() == 0  # every entry of the vehicle looks expired: none goes
    finally:
        store.close()

    # a run of the right time stored before, then the clock behind at the next boot
    store = SqliteStore(str(tmp_path / "other.sqlite"), settings=SETTINGS)
    try:
        today = utc_now().replace(microsecond=0) - timedelta(hours=1)
        store.insert_records([record(k, run="today", at=today) for k in range(10)])
        store._last_purge = None  # the purge is due again
        assert store.insert_records([record(k, run="booted-behind", at=behind) for k in range(600)]) == 600
        assert store.count_records(VEHICLE, behind, behind + timedelta(seconds=600)) == 600
    finally:
        store.close()


def test_the_recorder_publishes_its_writers_state_each_second_and_a_full_disk_shows_in_it(small_disk):
    rig = Rig(recorder_config(small_disk, memory_max_entries=20))
    statuses = rig.feeder.subscribe("blackbox/status", queue=1000)
    events = rig.feeder.subscribe("events", queue=1000)
    recorder = rig.start_recorder()
    try:
        rig.drive(3.0)
        wait_until(lambda: recorder.writer.records_written == 3, 10, "the first records")
        rig.drive(4.0)
        wait_until(lambda: statuses.latest is not None and statuses.latest.written >= 3, 10, "a status")
        assert statuses.latest.store_up and statuses.latest.dropped == 0
        filler = fill(small_disk)

        def one_more_second() -> bool:  # the recorder goes on; its status comes with each second
            rig.drive(rig.clock.now() + 1.0)
            return statuses.latest.dropped > 0

        wait_until(one_more_second, 20, "the dropped records in the status")
        latest = statuses.latest
        assert not latest.store_up and latest.store_faults > 0 and latest.in_memory == 20 and latest.last_error
        told = {ev.kind for _, ev in events.drain()}
        assert {"blackbox_store_down", "blackbox_fault"} <= told
        os.unlink(filler)
        wait_until(lambda: recorder.writer.store_up and not recorder.writer.status().in_memory, 20, "the flush")
    finally:
        rig.stop_recorder()
    final = recorder.writer.status()
    assert len(rows_in(small_disk / "blackbox.sqlite")) == final.written and final.dropped > 0
    # the last status, published at teardown, holds the counts after the final flush
    assert statuses.latest.written == final.written and statuses.latest.store_up
