"""The embedded black-box store: one SQLite file (stdlib sqlite3), the default without MongoDB.

Layout:
- records (vehicle_id, ts, dup, run, doc): ts is the record's whole second (unix s), doc the
  record's JSON, run the recording run it came from (VehicleRecord.run; '' for none).
  PRIMARY KEY (vehicle_id, ts, dup) WITHOUT ROWID keeps a vehicle's records clustered in time
  order, so an hour is one contiguous range read. A record whose (vehicle, second, run) is
  already stored is skipped (a retried batch is a no-op); one of another run for a second
  already held (a clock set back between two runs) is kept beside it with the next `dup`, so
  no record counted as written is ever dropped or overwritten. The queries (latest, records,
  records_json, count_records: the API's) read `dup = 0` only: one record per second as
  before, the first one stored for that second; a record stored for a second once never
  changes to another; its `run` tells which run it came from. Files from before `dup`/`run` are
  rebuilt when first opened (each of their records becomes `dup = 0` of run '', its document as
  it was, without a `run`);
- events (vehicle_id, ts, kind, doc), indexed on (vehicle_id, ts): several events may share a
  second, but the same event twice (a retried batch) is stored once (unique on all columns;
  files from before that rule are de-duplicated when first opened);
- acknowledged (vehicle_id, upto): the second up to which the fleet's store holds every record
  of the vehicle (its acknowledgement); with `keep_until_acknowledged` the purge deletes nothing
  after it;
- users (name, role, password_hash, created, disabled, generation), and revoked_tokens
  (token_id, expires): the token ids refused before their expiry.

The file (and SQLite's -wal and -shm beside it, which take its mode) is its owner's only (0600):
it holds the users' password hashes.

Concurrency: WAL journal (readers never wait for the writer). FastAPI runs handlers in a
thread pool, so each call borrows a connection from a small pool (one per concurrent call):
sqlite3 releases the GIL while SQLite works, so reads on different threads overlap. Every call
is bounded: a lock held elsewhere (another process, a long write) is waited for at most
`busy_timeout_s`, a statement runs at most `query_timeout_s`; past that, StoreUnavailable.

Read path: documents come back as dicts decoded by orjson in one call per query; nothing is
validated again (they were validated on the way in).
"""

from __future__ import annotations

import logging
import math
import os
import queue
import sqlite3
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from datetime import UTC, datetime, timedelta
from pathlib import Path

import orjson

from ares.core.messages import StoredEvent, VehicleRecord
from blackbox.register.store.record_store import (
    RETENTION,
    RecordStore,
    StoreSettings,
    StoreUnavailable,
    User,
    as_utc,
    utc_now,
)

log = logging.getLogger(__name__)

_EPOCH = datetime(1970, 1, 1, tzinfo=UTC)

SCHEMA = """
CREATE TABLE IF NOT EXISTS records (
    vehicle_id TEXT NOT NULL,
    ts INTEGER NOT NULL,
    dup INTEGER NOT NULL DEFAULT 0,
    run TEXT NOT NULL DEFAULT '',
    doc TEXT NOT NULL,
    PRIMARY KEY (vehicle_id, ts, dup)
) WITHOUT ROWID;
CREATE TABLE IF NOT EXISTS events (
    vehicle_id TEXT NOT NULL,
    ts REAL NOT NULL,
    kind TEXT NOT NULL,
    doc TEXT NOT NULL
);
CREATE INDEX IF NOT EXISTS events_vehicle_ts ON events (vehicle_id, ts);
DELETE FROM events WHERE rowid NOT IN (SELECT min(rowid) FROM events GROUP BY vehicle_id, ts, kind, doc);
CREATE UNIQUE INDEX IF NOT EXISTS events_once ON events (vehicle_id, ts, kind, doc);
CREATE TABLE IF NOT EXISTS users (
    name TEXT PRIMARY KEY,
    role TEXT NOT NULL,
    password_hash TEXT NOT NULL,
    created TEXT NOT NULL,
    disabled INTEGER NOT NULL DEFAULT 0,
    generation INTEGER NOT NULL DEFAULT 0
);
CREATE TABLE IF NOT EXISTS revoked_tokens (
    token_id TEXT PRIMARY KEY,
    expires REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS acknowledged (
    vehicle_id TEXT PRIMARY KEY,
    upto INTEGER NOT NULL
);
"""
# columns the users table gained after files were made: added to those files when first opened
USER_COLUMNS_ADDED = {
    "disabled": "INTEGER NOT NULL DEFAULT 0",
    "generation": "INTEGER NOT NULL DEFAULT 0",
}
USER_COLUMNS = "name, role, password_hash, created, disabled, generation"
FILE_MODE = 0o600  # the file holds the users' password hashes: its owner's only


def whole_second(dt: datetime) -> int:
    return math.floor(as_utc(dt).timestamp())


def _first_second_from(dt: datetime) -> int:
    # records sit on whole seconds: "ts >= start" and "ts >= ceil(start)" select the same ones
    return math.ceil(as_utc(dt).timestamp())


class _Connection(sqlite3.Connection):
    """A pooled connection; `deadline` (time.monotonic) bounds the statement running on it."""

    deadline = math.inf


class SqliteStore(RecordStore):
    """RecordStore on a SQLite file. `path` None: settings.path.
    `settings`: the `blackbox_store` section (its defaults when not given)."""

    def __init__(
        self,
        path: str | None = None,
        now: Callable[[], datetime] = utc_now,
        *,
        settings: StoreSettings = StoreSettings(),
    ):
        self.now = now
        self.settings = settings
        self.path = Path(path or settings.path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        _owner_only(self.path)
        self._busy_timeout_s = settings.busy_timeout_s
        self._query_timeout_s = settings.query_timeout_s
        self._purge_interval = timedelta(seconds=settings.purge_interval_s)
        self._idle: queue.SimpleQueue[_Connection] = queue.SimpleQueue()
        self._lock = threading.Lock()  # guards the fields below
        self._schema_lock = threading.Lock()
        self._ready = False  # schema created (done lazily: the file may be locked at start)
        self._closed = False
        self._last_purge: datetime | None = None

    # ---- connections ---------------------------------------------------------------------

    def _open(self) -> _Connection:
        conn = sqlite3.connect(
            self.path, timeout=self._busy_timeout_s, isolation_level=None, check_same_thread=False, factory=_Connection
        )
        try:
            # checked every 100k virtual-machine steps (~ms): cheap, and long statements stop
            conn.set_progress_handler(lambda: time.monotonic() > conn.deadline, 100_000)
            conn.execute(f"PRAGMA synchronous = {self.settings.synchronous}")
            # reads of an hour (~5 MB) map the file's pages instead of copying them
            conn.execute(f"PRAGMA mmap_size = {self.settings.mmap_size_mb * 2**20}")
            with self._schema_lock:  # one thread sets the file up; the others wait
                if not self._ready:
                    self._create_schema_retrying(conn)
        except BaseException:
            conn.close()
            raise
        return conn

    def _create_schema_retrying(self, conn: _Connection) -> None:
        """_create_schema, retried for up to the busy timeout: switching a new file to WAL takes
        an exclusive lock, and SQLite reports a clash with another process doing the same as
        "database is locked" at once, without waiting in its busy handler."""
        deadline = time.monotonic() + self._busy_timeout_s
        pause = 0.01
        while True:
            try:
                self._create_schema(conn)
                return
            except sqlite3.OperationalError as exc:
                if "locked" not in str(exc) or time.monotonic() + pause > deadline:
                    raise
            time.sleep(pause)
            pause = min(pause * 2, 0.2)

    def _create_schema(self, conn: _Connection) -> None:
        # page size only counts before the first table exists; large pages keep a ~1.4 kB record
        # inside its b-tree page (no overflow page to chase per row)
        conn.execute(f"PRAGMA page_size = {self.settings.page_size}")
        if conn.execute("PRAGMA journal_mode = WAL").fetchone()[0].lower() != "wal":
            raise sqlite3.OperationalError("could not switch the journal to WAL")
        present = {row[0] for row in conn.execute("SELECT name FROM sqlite_master")}
        if present >= {
            "records",
            "events",
            "events_vehicle_ts",
            "events_once",
            "users",
            "revoked_tokens",
            "acknowledged",
        } and (_records_keyed_by_run(conn)):
            # an existing file: no write lock needed, so a restarted reader can serve queries
            # even while another process holds the write lock
            with self._lock:
                self._ready = True
            return
        conn.execute("BEGIN IMMEDIATE")
        try:
            _rebuild_records_keyed_by_run(conn)
            for statement in SCHEMA.split(";"):
                if statement.strip():
                    conn.execute(statement)
            _add_user_columns(conn)
            conn.execute("COMMIT")
        except BaseException:
            conn.execute("ROLLBACK")
            raise
        with self._lock:
            self._ready = True

    @contextmanager
    def _connection(self, write: bool = False) -> Iterator[_Connection]:
        """A pooled connection for one call; `write`: inside one IMMEDIATE transaction (takes
        the write lock first, so the busy timeout applies to it, then commits)."""
        with self._lock:
            if self._closed:
                raise StoreUnavailable(f"embedded store {self.path} is closed")
        conn = None
        try:
            try:
                conn = self._idle.get_nowait()
            except queue.Empty:
                conn = self._open()
            conn.deadline = time.monotonic() + self._query_timeout_s
            if write:
                conn.execute("BEGIN IMMEDIATE")
                try:
                    yield conn
                    conn.execute("COMMIT")
                except BaseException:
                    if conn.in_transaction:
                        conn.execute("ROLLBACK")
                    raise
            else:
                yield conn
        except sqlite3.DatabaseError as exc:
            # locked, busy, interrupted (timeout), I/O error, cannot open, not a database: the
            # store cannot serve now. Integrity and programming errors are bugs: let them show.
            if isinstance(exc, sqlite3.OperationalError) or type(exc) is sqlite3.DatabaseError:
                raise StoreUnavailable(f"embedded store {self.path}: {exc}") from exc
            raise
        finally:
            if conn is not None:
                conn.deadline = math.inf
                with self._lock:
                    closed = self._closed
                if closed:
                    conn.close()
                else:
                    self._idle.put(conn)

    # ---- records ---------------------------------------------------------------------------

    def _insert_new(self, sql: str, rows: list, oldest: float) -> int:
        """executemany an insert that skips what is already stored, in one transaction; how many
        rows were new. `oldest`: the earliest time (unix s) among the rows."""
        if not rows:
            return 0
        with self._connection(write=True) as conn:
            before = conn.total_changes
            conn.executemany(sql, rows)
            new = conn.total_changes - before
        self._purge_if_due(oldest)
        return new

    def insert_records(self, records: Sequence[VehicleRecord]) -> int:
        return self._insert_new(
            "INSERT INTO records (vehicle_id, ts, dup, run, doc) "
            "SELECT :vehicle, :ts, coalesce((SELECT max(dup) + 1 FROM records WHERE vehicle_id = :vehicle "
            "AND ts = :ts), 0), :run, :doc "
            "WHERE NOT EXISTS (SELECT 1 FROM records WHERE vehicle_id = :vehicle AND ts = :ts AND run = :run)",
            rows := [_record_row(r) for r in records],
            min((float(row["ts"]) for row in rows), default=math.inf),
        )

    def latest(self, vehicle_id: str) -> dict | None:
        with self._connection() as conn:
            rows = conn.execute(
                "SELECT ts, doc FROM records WHERE vehicle_id = ? AND dup = 0 ORDER BY ts DESC LIMIT 1", (vehicle_id,)
            ).fetchall()
        docs = _decode_records(rows)
        return docs[0] if docs else None

    def records(
        self, vehicle_id: str, start: datetime, end: datetime, *, skip: int = 0, limit: int = 1000
    ) -> list[dict]:
        if limit <= 0:
            return []
        return _decode_records(self._record_rows("ts, doc", vehicle_id, start, end, skip, limit))

    def _record_rows(
        self, columns: str, vehicle_id: str, start: datetime, end: datetime, skip: int, limit: int
    ) -> list[tuple]:
        with self._connection() as conn:
            return conn.execute(
                f"SELECT {columns} FROM records WHERE vehicle_id = ? AND ts >= ? AND ts < ? AND dup = 0 "
                "ORDER BY ts LIMIT ? OFFSET ?",
                (vehicle_id, _first_second_from(start), _first_second_from(end), limit, max(skip, 0)),
            ).fetchall()

    def records_json(
        self, vehicle_id: str, start: datetime, end: datetime, *, skip: int = 0, limit: int = 1000
    ) -> bytes:
        """records() as one JSON array (UTF-8 bytes), the documents exactly as stored (`time` as
        an RFC 3339 string): for a handler that sends JSON on, it skips building ~75 Python
        objects per record and encoding them again (an hour: ~4 ms instead of ~35 ms)."""
        if limit <= 0:
            return b"[]"
        rows = self._record_rows("CAST(doc AS BLOB)", vehicle_id, start, end, skip, limit)
        return b"[" + b",".join([row[0] for row in rows]) + b"]"

    def count_records(self, vehicle_id: str, start: datetime, end: datetime) -> int:
        with self._connection() as conn:
            return conn.execute(
                "SELECT count(*) FROM records WHERE vehicle_id = ? AND ts >= ? AND ts < ? AND dup = 0",
                (vehicle_id, _first_second_from(start), _first_second_from(end)),
            ).fetchone()[0]

    def vehicles(self) -> list[str]:
        with self._connection() as conn:
            return sorted(set(_vehicle_ids(conn, "records")) | set(_vehicle_ids(conn, "events")))

    # ---- events ------------------------------------------------------------------------------

    def insert_events(self, events: Sequence[StoredEvent]) -> int:
        return self._insert_new(
            "INSERT OR IGNORE INTO events (vehicle_id, ts, kind, doc) VALUES (?, ?, ?, ?)",
            rows := [_event_row(e) for e in events],
            min((row[1] for row in rows), default=math.inf),
        )

    def _query_events(
        self, vehicle_id: str, start: datetime, end: datetime, kinds: list[str] | None, skip: int, limit: int
    ) -> list[dict]:
        sql = "SELECT doc FROM events WHERE vehicle_id = ? AND ts >= ? AND ts < ?"
        params: list = [vehicle_id, as_utc(start).timestamp(), as_utc(end).timestamp()]
        if kinds is not None:
            sql += f" AND kind IN ({', '.join('?' * len(kinds))})"
            params += kinds
        sql += " ORDER BY ts, rowid LIMIT ? OFFSET ?"  # rowid: events of one instant in arrival order
        params += [limit, skip]
        with self._connection() as conn:
            rows = conn.execute(sql, params).fetchall()
        loads, parse_time = orjson.loads, datetime.fromisoformat
        docs = [loads(row[0]) for row in rows]
        for doc in docs:
            doc["time"] = parse_time(doc["time"])
        return docs

    # ---- retention -----------------------------------------------------------------------------

    def purge_expired(self) -> int:
        """What is older than RETENTION by the store's clock, of each vehicle whose newest entry
        (in that table) is younger than that: a vehicle whose every entry looks expired either has
        a clock far behind the store's (days behind at boot) or stopped recording a week ago, and
        in both cases its last entries are what must not go. With `keep_until_acknowledged`, only
        what is also at or before the vehicle's acknowledged mark."""
        cutoff = (self.now() - RETENTION).timestamp()
        with self._connection(write=True) as conn:
            before = conn.total_changes
            marks = dict(conn.execute("SELECT vehicle_id, upto FROM acknowledged").fetchall())
            # per vehicle, so each DELETE is a range of the (vehicle_id, ts) key, not a table scan
            for table in ("records", "events"):
                for vehicle_id in _vehicle_ids(conn, table):
                    until = cutoff
                    if self.settings.keep_until_acknowledged:
                        if vehicle_id not in marks:
                            continue
                        until = min(cutoff, marks[vehicle_id] + 1)
                    newest = conn.execute(f"SELECT max(ts) FROM {table} WHERE vehicle_id = ?", (vehicle_id,))
                    if newest.fetchone()[0] >= cutoff:
                        conn.execute(f"DELETE FROM {table} WHERE vehicle_id = ? AND ts < ?", (vehicle_id, until))
            return conn.total_changes - before

    def acknowledged(self, vehicle_id: str) -> int | None:
        with self._connection() as conn:
            row = conn.execute("SELECT upto FROM acknowledged WHERE vehicle_id = ?", (vehicle_id,)).fetchone()
        return None if row is None else int(row[0])

    def acknowledge(self, vehicle_id: str, upto_epoch_s: int) -> int:
        with self._connection(write=True) as conn:
            conn.execute(
                "INSERT INTO acknowledged (vehicle_id, upto) VALUES (?, ?) "
                "ON CONFLICT (vehicle_id) DO UPDATE SET upto = max(upto, excluded.upto)",
                (vehicle_id, int(upto_epoch_s)),
            )
            return int(conn.execute("SELECT upto FROM acknowledged WHERE vehicle_id = ?", (vehicle_id,)).fetchone()[0])

    def oldest_second(self, vehicle_id: str) -> int | None:
        with self._connection() as conn:
            row = conn.execute("SELECT min(ts) FROM records WHERE vehicle_id = ?", (vehicle_id,)).fetchone()
        return None if row[0] is None else int(row[0])

    def _purge_if_due(self, oldest_inserted: float) -> None:
        """After an insert (records or events): purge at most once per purge_interval_s of the store's clock. Runs in
        its own transaction, so a failed purge never loses the insert; it is retried later. An insert
        of entries already past the retention by the store's clock (the writer's clock is behind)
        purges nothing: the entries just stored would be the first to go."""
        now = self.now()
        if oldest_inserted < (now - RETENTION).timestamp():
            log.warning("retention purge skipped: entries stored older than %s (a clock behind?)", RETENTION)
            return
        with self._lock:
            if self._last_purge is not None and now - self._last_purge < self._purge_interval:
                return
            self._last_purge = now
        try:
            removed = self.purge_expired()
        except StoreUnavailable as exc:
            log.warning("retention purge postponed: %s", exc)
            return
        if removed:
            log.info("retention purge removed %d records and events", removed)

    # ---- users ---------------------------------------------------------------------------------

    def get_user(self, name: str) -> User | None:
        with self._connection() as conn:
            row = conn.execute(f"SELECT {USER_COLUMNS} FROM users WHERE name = ?", (name,)).fetchone()
        return _user(row) if row else None

    def put_user(self, user: User) -> None:
        with self._connection(write=True) as conn:
            conn.execute(
                f"INSERT INTO users ({USER_COLUMNS}) VALUES (?, ?, ?, ?, ?, ?) "
                "ON CONFLICT (name) DO UPDATE SET role = excluded.role, "
                "password_hash = excluded.password_hash, created = excluded.created, "
                "disabled = excluded.disabled, generation = excluded.generation",
                (
                    user.name,
                    user.role,
                    user.password_hash,
                    as_utc(user.created).isoformat(),
                    int(user.disabled),
                    user.generation,
                ),
            )

    def list_users(self) -> list[User]:
        with self._connection() as conn:
            rows = conn.execute(f"SELECT {USER_COLUMNS} FROM users ORDER BY name").fetchall()
        return [_user(row) for row in rows]

    def delete_user(self, name: str) -> bool:
        with self._connection(write=True) as conn:
            return conn.execute("DELETE FROM users WHERE name = ?", (name,)).rowcount > 0

    def revoke_token(self, token_id: str, expires: datetime) -> None:
        with self._connection(write=True) as conn:
            # the entries past their token's expiry are no longer needed: they go with each new one
            conn.execute("DELETE FROM revoked_tokens WHERE expires < ?", (self.now().timestamp(),))
            conn.execute(
                "INSERT OR REPLACE INTO revoked_tokens (token_id, expires) VALUES (?, ?)",
                (token_id, as_utc(expires).timestamp()),
            )

    def token_revoked(self, token_id: str) -> bool:
        with self._connection() as conn:
            return conn.execute("SELECT 1 FROM revoked_tokens WHERE token_id = ?", (token_id,)).fetchone() is not None

    # ---- lifecycle -------------------------------------------------------------------------------

    def ping(self) -> None:
        with self._connection() as conn:
            conn.execute("SELECT count(*) FROM users").fetchone()

    def close(self) -> None:
        """Close the idle connections now, the borrowed ones when they come back."""
        with self._lock:
            self._closed = True
        while True:
            try:
                self._idle.get_nowait().close()
            except queue.Empty:
                return


# ---- row codecs ------------------------------------------------------------------------------


def _record_row(record: VehicleRecord) -> dict[str, str | int]:
    second = whole_second(record.time)
    t = record.time
    if t.microsecond or t.utcoffset() != timedelta(0):
        # a record stands for a whole UTC second: store exactly that second
        record = record.model_copy(update={"time": _EPOCH + timedelta(seconds=second)})
    return {"vehicle": record.vehicle_id, "ts": second, "run": record.run or "", "doc": record.model_dump_json()}


def _decode_records(rows: list[tuple[int, str]]) -> list[dict]:
    # one orjson call per row measured faster than one over the joined rows (no 5 MB string
    # to build and scan); `time` from the key column, cheaper than parsing the ISO string
    loads = orjson.loads
    docs = [loads(doc) for _, doc in rows]
    for doc, (ts, _) in zip(docs, rows):
        doc["time"] = _EPOCH + timedelta(seconds=ts)
    return docs


def _event_row(event: StoredEvent) -> tuple[str, float, str, str]:
    t = event.time
    if t.utcoffset() != timedelta(0):
        event = event.model_copy(update={"time": as_utc(t)})
    return event.vehicle_id, event.time.timestamp(), event.kind, event.model_dump_json()


def _user(row: tuple) -> User:
    name, role, password_hash, created, disabled, generation = row
    return User(
        name=name,
        role=role,
        password_hash=password_hash,
        created=datetime.fromisoformat(created),
        disabled=bool(disabled),
        generation=generation,
    )


def _records_keyed_by_run(conn: sqlite3.Connection) -> bool:
    return "run" in {row[1] for row in conn.execute("PRAGMA table_info(records)")}


def _rebuild_records_keyed_by_run(conn: sqlite3.Connection) -> None:
    """A records table from before `dup`/`run` (key (vehicle_id, ts)), rebuilt with them: the
    key of a WITHOUT ROWID table cannot be altered in place. Its records become dup 0 of run ''."""
    if not conn.execute("SELECT 1 FROM sqlite_master WHERE name = 'records'").fetchone():
        return
    if _records_keyed_by_run(conn):
        return
    log.info("embedded store: rebuilding the records table with a run per record (once)")
    conn.execute("ALTER TABLE records RENAME TO records_before_run")
    conn.execute(SCHEMA.split(";")[0])  # CREATE TABLE records, the current layout
    conn.execute(
        "INSERT INTO records (vehicle_id, ts, dup, run, doc) SELECT vehicle_id, ts, 0, '', doc FROM records_before_run"
    )
    conn.execute("DROP TABLE records_before_run")


def _add_user_columns(conn: sqlite3.Connection) -> None:
    """The users table's later columns, on a file made before them."""
    present = {row[1] for row in conn.execute("PRAGMA table_info(users)")}
    for column, declaration in USER_COLUMNS_ADDED.items():
        if column not in present:
            conn.execute(f"ALTER TABLE users ADD COLUMN {column} {declaration}")


def _owner_only(path: Path) -> None:
    """Create the store's file readable and writable by its owner only, before SQLite does (with
    the umask's 0644); an existing file is narrowed to that too."""
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, FILE_MODE)
    except OSError as exc:  # not ours to open: SQLite will say what it makes of it
        log.warning("embedded store %s: not narrowed to its owner: %s", path, exc)
        return
    try:
        if os.fstat(fd).st_mode & 0o777 != FILE_MODE:
            os.fchmod(fd, FILE_MODE)
    except OSError as exc:  # another user's file: theirs to protect
        log.warning("embedded store %s: not narrowed to its owner: %s", path, exc)
    finally:
        os.close(fd)


def _vehicle_ids(conn: sqlite3.Connection, table: str) -> list[str]:
    """Distinct vehicle_id by hopping along the (vehicle_id, ts) index: one lookup per vehicle
    rather than a scan of every row (SELECT DISTINCT would read all 600k rows of a week)."""
    return [
        row[0]
        for row in conn.execute(
            f"WITH RECURSIVE ids(id) AS ("
            f" SELECT (SELECT min(vehicle_id) FROM {table})"
            f" UNION ALL"
            f" SELECT (SELECT min(vehicle_id) FROM {table} WHERE vehicle_id > id) FROM ids WHERE id IS NOT NULL)"
            f" SELECT id FROM ids WHERE id IS NOT NULL"
        )
    ]
