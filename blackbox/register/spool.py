"""The black box's disk spool: where records and events wait while the store cannot take them.

The event register (blackbox/register/recorder.py) writes to the store from a writer thread. When an
insert fails (StoreUnavailable, or any other error), the batch is appended here instead; once
the store answers again the spool is flushed to it in the order it was filled, and the file is
removed when empty. A spool left behind by a process that was stopped or killed during an
outage is found by the next start (same file name: one spool per vehicle) and flushed first.

The spool is a small SQLite file (not the store's file, so a locked store does not lock it):
one row per record or event, `seq` giving the order. SQLite rather than a JSON-lines file
because a crash in the middle of an append then loses nothing already spooled (a torn last
line would need repair), and dropping the oldest rows is one DELETE instead of a rewrite.

It is bounded (`max_entries`, default about 8 days of records plus their events): beyond the
bound the OLDEST rows go first, and append() reports how many were dropped so the recorder can
raise a FAULT event. Re-sending a row that already reached the store is harmless: the store's
inserts are idempotent per (vehicle, second, run).

Thread-safe: the writer thread fills and flushes it; at shutdown the node's own thread may
spool what the writer could not finish.

One writer per spool (SpoolLock): a spool is one vehicle's queue towards one store, and a
second writer on it would remove the file under the first (it deletes the spool once it has
flushed it). The lock is an flock on `<spool>.lock`, released by the kernel when the process
ends however it ends, so a recorder killed mid-run never blocks the next start.
"""

from __future__ import annotations

import fcntl
import os
import sqlite3
import threading
from collections.abc import Iterable, Sequence
from pathlib import Path

from ares.core.messages import StoredEvent, VehicleRecord

Item = VehicleRecord | StoredEvent

RECORD, EVENT = "record", "event"


def kind_of(item: Item) -> str:
    return RECORD if isinstance(item, VehicleRecord) else EVENT


def _parse(kind: str, doc: str) -> Item:
    return (VehicleRecord if kind == RECORD else StoredEvent).model_validate_json(doc)


class Spool:
    def __init__(self, path: str | Path, max_entries: int):
        if max_entries < 1:
            raise ValueError("a spool must hold at least one entry")
        self.path = Path(path)
        self.max_entries = int(max_entries)
        self._lock = threading.RLock()
        self._db: sqlite3.Connection | None = None
        self._count = 0
        self.dropped_total = 0
        if self.path.exists():  # a leftover from an earlier run: count what waits
            self._open()

    # ---- file ---------------------------------------------------------------------------
    def _open(self) -> sqlite3.Connection:
        if self._db is None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            db = sqlite3.connect(self.path, timeout=5.0, isolation_level=None, check_same_thread=False)
            try:
                db.execute(
                    "CREATE TABLE IF NOT EXISTS spool ("
                    "seq INTEGER PRIMARY KEY AUTOINCREMENT, kind TEXT NOT NULL, doc TEXT NOT NULL)"
                )
                self._count = db.execute("SELECT COUNT(*) FROM spool").fetchone()[0]
            except BaseException:  # a full disk: the next append tries again from scratch
                db.close()
                raise
            self._db = db
        return self._db

    def _remove(self) -> None:
        """Close and delete the (empty) file: no spool file means nothing is waiting."""
        if self._db is not None:
            self._db.close()
            self._db = None
        for suffix in ("", "-journal", "-wal", "-shm"):
            Path(str(self.path) + suffix).unlink(missing_ok=True)
        self._count = 0

    # ---- use ----------------------------------------------------------------------------
    def __len__(self) -> int:
        with self._lock:
            return self._count

    @property
    def pending(self) -> bool:
        return len(self) > 0

    def append(self, items: Iterable[Item]) -> int:
        """Append items in order; returns how many of the oldest entries were dropped to stay
        within max_entries (0 normally)."""
        rows = [(kind_of(item), item.model_dump_json()) for item in items]
        if not rows:
            return 0
        with self._lock:
            db = self._open()
            dropped = 0
            with db:  # one transaction: the batch is spooled whole or not at all
                db.execute("BEGIN IMMEDIATE")
                db.executemany("INSERT INTO spool (kind, doc) VALUES (?, ?)", rows)
                over = self._count + len(rows) - self.max_entries
                if over > 0:
                    db.execute("DELETE FROM spool WHERE seq IN (SELECT seq FROM spool ORDER BY seq LIMIT ?)", (over,))
                    dropped = over
            self._count += len(rows) - dropped
            self.dropped_total += dropped
            return dropped

    def peek(self, limit: int) -> tuple[int, list[Item]]:
        """The oldest entries (up to limit) and the seq of the last one, for flush()/ack()."""
        with self._lock:
            if self._db is None or self._count == 0:
                return 0, []
            rows = self._db.execute("SELECT seq, kind, doc FROM spool ORDER BY seq LIMIT ?", (limit,)).fetchall()
        if not rows:
            return 0, []
        return rows[-1][0], [_parse(kind, doc) for _, kind, doc in rows]

    def ack(self, upto_seq: int) -> None:
        """Forget every entry up to upto_seq (they reached the store); remove the file once empty."""
        with self._lock:
            if self._db is None:
                return
            with self._db:
                self._db.execute("BEGIN IMMEDIATE")
                self._db.execute("DELETE FROM spool WHERE seq <= ?", (upto_seq,))
            self._count = self._db.execute("SELECT COUNT(*) FROM spool").fetchone()[0]
            if self._count == 0:
                self._remove()

    def close(self) -> None:
        with self._lock:
            if self._db is not None:
                if self._count == 0:
                    self._remove()
                else:
                    self._db.close()
                    self._db = None


class SpoolBusy(RuntimeError):
    """Another writer (another recorder process, most likely) already holds this spool."""


class SpoolLock:
    """The exclusive claim of one writer on a spool file (see the module's docstring)."""

    def __init__(self, spool: str | Path):
        self.path = Path(str(spool) + ".lock")
        self._fd: int | None = None

    def acquire(self) -> None:
        """Take the lock without waiting; SpoolBusy if another process (or writer) has it."""
        if self._fd is not None:
            return
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise SpoolBusy(f"{self.path}: another black-box writer is using this spool and store") from None
        self._fd = fd

    def release(self) -> None:
        # the file stays: removing it would let a third writer lock a new file while a second
        # still holds the old one
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None


def split(items: Sequence[Item]) -> tuple[list[VehicleRecord], list[StoredEvent]]:
    records = [i for i in items if isinstance(i, VehicleRecord)]
    events = [i for i in items if isinstance(i, StoredEvent)]
    return records, events


def load_all(path: str | Path) -> list[Item]:
    """Every entry of a spool file, oldest first (for inspection and tests)."""
    if not Path(path).exists():
        return []
    db = sqlite3.connect(path)
    try:
        return [_parse(k, d) for k, d in db.execute("SELECT kind, doc FROM spool ORDER BY seq")]
    finally:
        db.close()
