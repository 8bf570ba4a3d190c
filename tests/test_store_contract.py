"""One contract for every black-box store engine (blackbox.register.store.record_store.RecordStore).

"sqlite" always runs, on a file in tmp_path. "mongodb", the store both deployments use, runs
wherever ARES_TEST_MONGO_URI points at a MongoDB server (>= 7.0), each test in a throw-away
database that is dropped afterwards; a server it cannot reach fails those tests. Without the
variable they are skipped with the reason, and the test command's summary says which stores it
tested and which not, and why (tests/conftest.py), so nobody mistakes them for passed. No
MongoDB server, nor a wire-compatible one, is installable on the development machine: the PyPI
"in-memory" servers download mongod at run time, and the embedded look-alikes are mocks.

The tests' clock is set about 30 days ahead of the real one: MongoDB's TTL monitor deletes by
the server's real clock, so data a week older than the test clock is still in the future for it
and only the store's own purge removes it.
"""

from __future__ import annotations

import itertools
import os
import select
import subprocess
import sys
import threading
import time
import uuid
from datetime import UTC, datetime, timedelta

import orjson
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ares.core.localhost import free_port
from ares.core.messages import (
    DriveMode,
    EventLevel,
    Position,
    ProcessHealth,
    ProcessState,
    SensorHealth,
    StoredEvent,
    VehicleRecord,
)
from ares.tools.bench.blackbox_store import T0, realistic_records
from blackbox.register.store.record_store import RETENTION, StoreSettings, StoreUnavailable, User
from blackbox.register.store.sqlite_store import SqliteStore

MONGO_URI = os.environ.get("ARES_TEST_MONGO_URI")
MONGO_SKIP = "ARES_TEST_MONGO_URI unset: no MongoDB server to test against; point it at a MongoDB >= 7.0"
RUN_ID = uuid.uuid4().hex[:8]
_databases = itertools.count()

# whole hour, ~30 days ahead of the real clock (see the module docstring)
BASE = (datetime.now(UTC) + timedelta(days=30)).replace(minute=0, second=0, microsecond=0)
SQLITE_SETTINGS = StoreSettings(busy_timeout_s=0.5)


class Clock:
    """The store's clock, moved by hand."""

    def __init__(self, now: datetime):
        self.t = now

    def __call__(self) -> datetime:
        return self.t


@pytest.fixture(params=["sqlite", "mongodb"])
def engine(request):
    # the engine a test ran on, or was skipped for: the summary of tests/conftest.py reads it
    request.node.user_properties.append(("store_engine", request.param))
    if request.param == "mongodb" and not MONGO_URI:
        pytest.skip(MONGO_SKIP)
    return request.param


@pytest.fixture
def clock():
    return Clock(BASE)


@pytest.fixture
def store(engine, clock, tmp_path):
    if engine == "sqlite":
        s = SqliteStore(str(tmp_path / "blackbox.sqlite"), now=clock, settings=SQLITE_SETTINGS)
        yield s
        s.close()
    else:
        from blackbox.register.store.mongo_store import MongoStore

        throwaway = StoreSettings(mongo_db=f"ares_test_{RUN_ID}_{next(_databases)}")
        s = MongoStore(MONGO_URI, now=clock, settings=throwaway)
        try:
            yield s
        finally:
            s.drop_database()
            s.close()


# ---- builders --------------------------------------------------------------------------------


def record(vehicle: str, second: float, **fields) -> VehicleRecord:
    """A validated record `second` s after BASE (negative: before)."""
    base = dict(
        vehicle_id=vehicle,
        time=BASE + timedelta(seconds=second),
        t=float(second),
        position=Position(
            x=1.5 + second,
            y=-2.25,
            z=0.5,
            easting=440001.5,
            northing=4473997.75,
            zone=30,
            hemisphere="N",
            lat=40.41,
            lon=-3.71,
        ),
        speed_mps=3.25,
        steering_wheel_deg=-10.5,
        mode=DriveMode.AUTOMATIC,
        scores={"odometry": 0.875},
        controller="mpc",
        sensors={"gnss": SensorHealth(rate_hz=5.0, ok=True)},
        processes={"gnss": ProcessHealth(state=ProcessState.RUNNING, restarts=1)},
    )
    return VehicleRecord(**{**base, **fields})


def event(vehicle: str, second: float, kind: str = "mode_change", **fields) -> StoredEvent:
    base = dict(
        vehicle_id=vehicle,
        time=BASE + timedelta(seconds=second),
        t=float(second),
        source="dbw_bridge",
        kind=kind,
        level=EventLevel.WARNING,
        message=f"{kind} at {second}",
        data={"from": "READY", "n": 2},
    )
    return StoredEvent(**{**base, **fields})


def expected(model) -> dict:
    """What a store gives back for a model: JSON values, `time` as an aware UTC datetime."""
    doc = model.model_dump(mode="json")
    doc["time"] = model.time
    return doc


def seconds_of(docs: list[dict]) -> list[float]:
    return [(d["time"] - BASE).total_seconds() for d in docs]


def at(second: float) -> datetime:
    return BASE + timedelta(seconds=second)


# ---- records ---------------------------------------------------------------------------------


def test_insert_and_latest(store):
    assert store.latest("shuttle01") is None
    records = [record("shuttle01", s, speed_mps=float(s)) for s in (0, 1, 2)]
    assert store.insert_records(records) == 3
    latest = store.latest("shuttle01")
    assert latest == expected(records[-1])
    assert latest["time"].utcoffset() == timedelta(0)
    assert store.insert_records([]) == 0


def test_range_is_half_open_ordered_and_pages(store):
    # inserted out of order: the store returns them in time order
    store.insert_records([record("v", s) for s in reversed(range(100))])
    docs = store.records("v", at(10), at(50), limit=1000)
    assert seconds_of(docs) == list(range(10, 50))  # start included, end excluded
    assert docs[0] == expected(record("v", 10))
    assert store.count_records("v", at(10), at(50)) == 40
    pages = [store.records("v", at(10), at(50), skip=skip, limit=15) for skip in (0, 15, 30, 45)]
    assert [len(p) for p in pages] == [15, 15, 10, 0]
    assert [d for p in pages for d in p] == docs
    assert store.records("v", at(10), at(50), limit=0) == []
    # bounds between seconds
    assert seconds_of(store.records("v", at(10.5), at(12.5))) == [11, 12]
    assert store.count_records("v", at(10.5), at(12.5)) == 2
    assert store.records("v", at(200), at(300)) == []
    assert store.count_records("v", at(200), at(300)) == 0


def test_retried_and_overlapping_batches_create_no_duplicates(store):
    assert store.insert_records([record("v", s) for s in range(50)]) == 50
    assert store.insert_records([record("v", s) for s in range(25, 75)]) == 25
    assert store.insert_records([record("v", s) for s in range(75)]) == 0
    # the same second twice in one batch: stored once (the first one)
    assert store.insert_records([record("v", 80, speed_mps=1.0), record("v", 80, speed_mps=2.0)]) == 1
    assert store.count_records("v", at(0), at(100)) == 76
    assert seconds_of(store.records("v", at(0), at(100))) == [*range(75), 80]
    assert store.latest("v")["speed_mps"] == 1.0


def test_vehicles_are_kept_apart(store):
    assert store.vehicles() == []
    store.insert_records([record("a", s, speed_mps=1.0) for s in range(10)])
    store.insert_records([record("b", s, speed_mps=2.0) for s in range(5, 20)])
    assert store.vehicles() == ["a", "b"]
    assert store.count_records("a", at(0), at(100)) == 10
    assert store.count_records("b", at(0), at(100)) == 15
    assert {d["vehicle_id"] for d in store.records("a", at(0), at(100))} == {"a"}
    assert {d["speed_mps"] for d in store.records("b", at(0), at(100))} == {2.0}
    assert store.latest("a")["time"] == at(9)
    assert store.latest("b")["time"] == at(19)
    assert store.latest("c") is None
    store.insert_events([event("c", 1.0)])
    assert store.vehicles() == ["a", "b", "c"]  # a vehicle known by its events only


def test_records_json_matches_records(store):
    store.insert_records([record("v", s) for s in range(20)])
    raw = store.records_json("v", at(5), at(15), skip=2, limit=5)
    parsed = orjson.loads(raw)
    for doc in parsed:
        doc["time"] = datetime.fromisoformat(doc["time"])
    assert parsed == store.records("v", at(5), at(15), skip=2, limit=5)
    assert orjson.loads(store.records_json("v", at(100), at(200))) == []


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    present=st.sets(st.integers(0, 60), max_size=40),
    start=st.floats(-5, 65, allow_nan=False),
    span=st.floats(0, 70, allow_nan=False),
    skip=st.integers(0, 10),
    limit=st.integers(0, 50),
)
def test_range_queries_match_a_model(store, present, start, span, skip, limit):
    vehicle = uuid.uuid4().hex  # a fresh vehicle per example, in the one store
    store.insert_records([record(vehicle, s) for s in present])
    start_t = at(start).replace(microsecond=at(start).microsecond // 1000 * 1000)  # BSON keeps ms
    end_t = start_t + timedelta(milliseconds=round(span * 1000))
    inside = sorted(s for s in present if start_t <= at(s) < end_t)
    assert seconds_of(store.records(vehicle, start_t, end_t, skip=skip, limit=limit)) == inside[skip : skip + limit]
    assert store.count_records(vehicle, start_t, end_t) == len(inside)


# ---- events ----------------------------------------------------------------------------------


def test_events_range_kinds_and_paging(store):
    events = [
        event("v", 0.125, "mode_change"),
        event("v", 0.5, "watchdog", level=EventLevel.FAULT),
        event("v", 1.25, "process_restart"),
        event("v", 2.0, "mode_change"),
        event("w", 1.0, "mode_change"),
    ]
    assert store.insert_events(events) == 5
    assert store.insert_events([]) == 0
    docs = store.events("v", at(0), at(2))
    assert docs == [expected(e) for e in events[:3]]  # end excluded, other vehicle apart
    assert docs[1]["level"] == "fault"
    assert seconds_of(store.events("v", at(0), at(10), kinds=["mode_change"])) == [0.125, 2.0]
    assert seconds_of(store.events("v", at(0), at(10), kinds=["watchdog", "process_restart"])) == [0.5, 1.25]
    assert store.events("v", at(0), at(10), kinds=[]) == []
    assert seconds_of(store.events("v", at(0), at(10), skip=1, limit=2)) == [0.5, 1.25]
    assert seconds_of(store.events("w", at(0), at(10))) == [1.0]


def test_a_query_that_selects_nothing_and_a_negative_skip(store):
    store.insert_events([event("v", 1.0), event("v", 2.0)])
    store.insert_records([record("v", 1), record("v", 2)])
    assert store.events("v", at(0), at(10), limit=0) == [] and store.events("v", at(0), at(10), limit=-1) == []
    assert seconds_of(store.events("v", at(0), at(10), skip=-5)) == [1.0, 2.0]
    assert (
        store.records("v", at(0), at(10), limit=0) == []
        and orjson.loads(store.records_json("v", at(0), at(10), limit=0)) == []
    )
    assert seconds_of(store.records("v", at(0), at(10), skip=-5)) == [1, 2]


def test_a_retried_event_batch_adds_nothing(store):
    batch = [event("v", 3.0, "mode_change"), event("v", 3.0, "watchdog"), event("v", 4.5)]
    assert store.insert_events(batch) == 3
    assert store.insert_events(batch) == 0  # retried after an uncertain failure
    assert store.insert_events([batch[2], event("v", 5.0)]) == 1  # overlapping
    assert seconds_of(store.events("v", at(0), at(10))) == [3.0, 3.0, 4.5, 5.0]


def test_events_of_one_instant_keep_their_order(store):
    store.insert_events([event("v", 3.0, f"k{i}") for i in range(5)])
    assert [d["kind"] for d in store.events("v", at(0), at(10))] == [f"k{i}" for i in range(5)]


# ---- users -----------------------------------------------------------------------------------


def test_users_put_get_list_and_replace(store):
    assert store.get_user("ana") is None
    assert store.list_users() == []
    created = datetime(2026, 1, 2, 3, 4, 5, tzinfo=UTC)
    ana = User(name="ana", role="auditor", password_hash="$argon2id$v=19$a", created=created)
    bob = User(name="bob", role="admin", password_hash="$argon2id$v=19$b", created=created)
    store.put_user(bob)
    store.put_user(ana)
    assert store.get_user("ana") == ana
    assert store.list_users() == [ana, bob]
    promoted = User(name="ana", role="fleet", password_hash="$argon2id$v=19$c", created=created + timedelta(days=1))
    store.put_user(promoted)
    assert store.get_user("ana") == promoted
    assert store.list_users() == [promoted, bob]


# ---- retention -------------------------------------------------------------------------------


def test_retention_removes_only_what_is_older_than_seven_days(store, clock):
    week = RETENTION.total_seconds()
    clock.t = BASE - timedelta(days=2)  # nothing is old yet while inserting
    old, edge, young = -week - 3600, -week, -week + 1  # 8 days - 1 h ago, exactly 7 days, just under
    store.insert_records([record("v", s) for s in (old, old + 1, edge, young, 0)])
    store.insert_events([event("v", s) for s in (old, edge + 0.5, 0)])
    clock.t = BASE
    removed = store.purge_expired()
    assert removed == 3  # two records, one event
    assert seconds_of(store.records("v", at(-2 * week), at(1))) == [edge, young, 0]
    assert seconds_of(store.events("v", at(-2 * week), at(1))) == [edge + 0.5, 0]
    assert store.purge_expired() == 0
    # a day later, the rest of the week-old data goes too
    clock.t = BASE + timedelta(days=1)
    assert store.purge_expired() == 3
    assert seconds_of(store.records("v", at(-2 * week), at(1))) == [0]


def test_ping_answers_while_the_store_does(store):
    # ping returns (None) while the store answers, touches nothing, and the store goes on serving
    store.insert_records([record("v", 0)])
    assert store.ping() is None
    assert store.count_records("v", at(0), at(1)) == 1 and store.vehicles() == ["v"]


def test_ping_of_a_store_that_cannot_answer_raises_unavailable(tmp_path, clock):
    """RecordStore.ping: "Raise StoreUnavailable unless the store answers" (the error callers
    retry on, and /health reports): a closed SQLite store, and a MongoDB URI where nothing listens
    (no server needed). Every MongoDB call is bounded by the configured timeouts, all 0.3 s here."""
    from blackbox.register.store.mongo_store import MongoStore

    closed = SqliteStore(str(tmp_path / "closed.sqlite"), now=clock, settings=SQLITE_SETTINGS)
    closed.ping()
    closed.close()
    with pytest.raises(StoreUnavailable, match="closed"):
        closed.ping()

    short = StoreSettings(
        mongo_server_selection_timeout_ms=300,
        mongo_connect_timeout_ms=300,
        mongo_socket_timeout_ms=300,
        mongo_timeout_ms=300,
    )
    absent = MongoStore(f"mongodb://127.0.0.1:{free_port()}/?directConnection=true", now=clock, settings=short)
    try:
        started = time.monotonic()
        with pytest.raises(StoreUnavailable, match="MongoDB"):
            absent.ping()
        assert time.monotonic() - started < 2.5  # the timeouts' 0.3 s and some slack: not hung
    finally:
        absent.close()


# ---- SQLite only -----------------------------------------------------------------------------

LOCKER = """
import sqlite3, sys
conn = sqlite3.connect(sys.argv[1], isolation_level=None)
conn.execute("BEGIN EXCLUSIVE")
print("locked", flush=True)
sys.stdin.readline()
conn.execute("COMMIT")
print("released", flush=True)
"""


def _read_line(proc: subprocess.Popen, timeout_s: float = 10.0) -> str:
    ready, _, _ = select.select([proc.stdout], [], [], timeout_s)
    assert ready, "the locking process did not answer"
    return proc.stdout.readline().strip()


def test_sqlite_locked_by_another_process_is_unavailable_then_recovers(tmp_path, clock):
    path = tmp_path / "blackbox.sqlite"
    store = SqliteStore(str(path), now=clock, settings=SQLITE_SETTINGS)
    store.insert_records([record("v", 0)])
    proc = subprocess.Popen(
        [sys.executable, "-c", LOCKER, str(path)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    try:
        assert _read_line(proc) == "locked"
        started = time.monotonic()
        with pytest.raises(StoreUnavailable):
            store.insert_records([record("v", 1)])
        waited = time.monotonic() - started
        assert waited >= 0.4, waited  # waited for the lock before giving up
        with pytest.raises(StoreUnavailable):
            store.put_user(User("ana", "auditor", "h", BASE))
        # WAL: readers are not blocked by the writer's lock
        assert seconds_of(store.records("v", at(0), at(10))) == [0]
        proc.stdin.write("\n")
        proc.stdin.flush()
        assert _read_line(proc) == "released"
        assert proc.wait(timeout=10) == 0
        assert store.insert_records([record("v", 1)]) == 1
        assert store.count_records("v", at(0), at(10)) == 2
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        store.close()


def test_sqlite_restart_keeps_the_data(tmp_path, clock):
    path = str(tmp_path / "blackbox.sqlite")
    first = SqliteStore(path, now=clock, settings=SQLITE_SETTINGS)
    first.insert_records([record("v", s) for s in range(10)])
    first.insert_events([event("v", 1.5)])
    user = User("ana", "auditor", "h", BASE)
    first.put_user(user)
    first.close()
    with pytest.raises(StoreUnavailable):
        first.latest("v")  # a closed store says so
    second = SqliteStore(path, now=clock, settings=SQLITE_SETTINGS)
    try:
        assert second.count_records("v", at(0), at(10)) == 10
        assert second.latest("v") == expected(record("v", 9))
        assert seconds_of(second.events("v", at(0), at(10))) == [1.5]
        assert second.get_user("ana") == user
        assert second.insert_records([record("v", s) for s in range(12)]) == 2
    finally:
        second.close()


def test_sqlite_file_from_before_unique_events_is_deduplicated_on_opening(tmp_path, clock):
    import sqlite3

    path = str(tmp_path / "blackbox.sqlite")
    first = SqliteStore(path, now=clock, settings=SQLITE_SETTINGS)
    first.insert_events([event("v", 1.5), event("v", 2.5)])
    first.close()
    with sqlite3.connect(path) as conn:  # as such a file was: no unique index, a duplicate
        conn.execute("DROP INDEX events_once")
        conn.execute("INSERT INTO events SELECT * FROM events WHERE ts = (SELECT min(ts) FROM events)")
    conn.close()
    second = SqliteStore(path, now=clock, settings=SQLITE_SETTINGS)
    try:
        assert seconds_of(second.events("v", at(0), at(10))) == [1.5, 2.5]
        assert second.insert_events([event("v", 1.5)]) == 0
    finally:
        second.close()


def test_sqlite_purges_on_insert_at_most_once_a_minute(tmp_path, clock):
    store = SqliteStore(str(tmp_path / "blackbox.sqlite"), now=clock, settings=SQLITE_SETTINGS)
    try:
        week = RETENTION.total_seconds()
        clock.t = BASE
        store.insert_records([record("v", 0)])  # first insert: purge runs (nothing old)
        clock.t = BASE + timedelta(seconds=30)
        store.insert_records([record("v", -week - 100)])  # already expired, but the purge is not due
        assert store.count_records("v", at(-2 * week), at(100)) == 2
        clock.t = BASE + timedelta(seconds=61)
        store.insert_records([record("v", 1)])  # due: the expired record goes
        assert seconds_of(store.records("v", at(-2 * week), at(100))) == [0, 1]
    finally:
        store.close()


def test_sqlite_statement_past_the_query_timeout_is_unavailable(tmp_path, clock):
    store = SqliteStore(str(tmp_path / "blackbox.sqlite"), now=lambda: T0, settings=SQLITE_SETTINGS)
    try:
        for first in range(0, 30_000, 5000):  # enough rows for the statement to be checked on its way
            store.insert_records(realistic_records("v", first, 5000))
        end = T0 + timedelta(seconds=30_000)
        store._query_timeout_s = 1e-6  # every statement is already late
        with pytest.raises(StoreUnavailable, match="interrupted"):
            store.records("v", T0, end, limit=30_000)
        store._query_timeout_s = 10.0
        assert len(store.records("v", T0, end, limit=30_000)) == 30_000
    finally:
        store.close()


def test_sqlite_threads_share_one_store(tmp_path, clock):
    store = SqliteStore(str(tmp_path / "blackbox.sqlite"), now=clock, settings=StoreSettings(busy_timeout_s=5.0))
    errors = []

    def work(vehicle: str) -> None:
        try:
            for first in range(0, 200, 20):
                store.insert_records([record(vehicle, s) for s in range(first, first + 20)])
                assert len(store.records(vehicle, at(0), at(1000))) == first + 20
        except Exception as exc:  # reported to the main thread
            errors.append(exc)

    threads = [threading.Thread(target=work, args=(f"v{i}",)) for i in range(4)]
    try:
        for t in threads:
            t.start()
        for t in threads:
            t.join(timeout=30)
        assert errors == []
        assert store.vehicles() == ["v0", "v1", "v2", "v3"]
        assert all(store.count_records(f"v{i}", at(0), at(1000)) == 200 for i in range(4))
    finally:
        store.close()
