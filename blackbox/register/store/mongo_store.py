"""The deployment black-box store: MongoDB through pymongo 4.x.

Collections (database blackbox_store.mongo_db):
- records: a time-series collection (timeField "time", metaField "vehicle_id", granularity
  "seconds") expiring after RETENTION; MongoDB stores it in per-vehicle buckets, compressed.
  Time-series collections cannot have unique indexes, so "one record per vehicle, second and
  run" is kept by the writer: insert_records first reads which seconds and runs of the batch's
  range are already stored for the vehicle and inserts only the others; a second another run
  holds (a clock set back between two runs) is stored beside it with `dup` 1, 2, ..., and the
  reads (latest, records, count) give the first only, as the embedded store does. That is exact
  for one writer per vehicle (the event register); two concurrent writers of one vehicle could
  both insert a second;
- events: a plain collection (events are few, and a plain collection allows any delete), a TTL
  index on time (RETENTION) and an index on (vehicle_id, time);
- users: unique index on name;
- revoked_tokens: the token ids refused before their expiry, removed by a TTL index past it;
- acknowledged: per vehicle, the second up to which the fleet's store holds every record.

With `keep_until_acknowledged` (a vehicle that waits for its fleet) records and events have no
TTL: the server's monitor would delete seconds the fleet never acknowledged. An existing
collection's TTL is switched off (collMod) and the events' TTL index dropped at setup, and
inserts run purge_expired (which keeps what is not acknowledged) at most every
`purge_interval_s`, as the embedded store does.

Setup (collections, indexes) runs on first use and is retried on the next call until it
succeeds, so the API and the register can start before the database does. Every call is
bounded by the configured timeouts (server selection, connect, socket, and pymongo's
client-side operation timeout `timeoutMS`); a server that cannot be reached or does not answer
in time raises StoreUnavailable.

Datetimes: BSON keeps milliseconds, so an event's sub-millisecond part is dropped; the client
is tz_aware, so every datetime read back is aware UTC.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import contextmanager
from datetime import UTC, datetime
from typing import Any

import orjson
from pymongo import ASCENDING, DESCENDING, MongoClient
from pymongo.errors import (
    AutoReconnect,
    BulkWriteError,
    CollectionInvalid,
    ConnectionFailure,
    ExecutionTimeout,
    NetworkTimeout,
    OperationFailure,
    PyMongoError,
    ServerSelectionTimeoutError,
)

from ares.core.config import read_secret
from ares.core.messages import StoredEvent, VehicleRecord
from blackbox.register.store.record_store import (
    RETENTION,
    RecordStore,
    StoreSettings,
    StoreUnavailable,
    User,
    utc_now,
)

# the server cannot be reached, or did not answer in time
UNAVAILABLE = (ServerSelectionTimeoutError, AutoReconnect, NetworkTimeout, ExecutionTimeout, ConnectionFailure)
NAMESPACE_EXISTS = 48  # server error code: the collection was created meanwhile
DUPLICATE_KEY = 11000  # server error code: a unique index refused the document
EVENT_IDENTITY = ("vehicle_id", "time", "source", "kind", "message")  # the same event, stored once
RETENTION_S = int(RETENTION.total_seconds())
_PROJECTION = {"_id": 0}


def _utc(dt: datetime) -> datetime:
    return dt.replace(tzinfo=UTC) if dt.tzinfo is None else dt.astimezone(UTC)


class MongoStore(RecordStore):
    """RecordStore on MongoDB; `settings`: the `blackbox_store` section (tests: a throw-away
    database name)."""

    def __init__(self, uri: str, now: Callable[[], datetime] = utc_now, *, settings: StoreSettings = StoreSettings()):
        self.now = now
        self.settings = s = settings
        # MongoClient connects in the background: constructing it never blocks or fails on
        # an absent server; the first operation waits at most serverSelectionTimeoutMS
        credentials = {}
        if s.mongo_user is not None and s.mongo_password_file is not None:
            password = read_secret(s.mongo_password_file, "blackbox_store.mongo_password_file")
            credentials = {"username": s.mongo_user, "password": password}
        self._client: MongoClient = MongoClient(
            uri,
            **credentials,
            serverSelectionTimeoutMS=s.mongo_server_selection_timeout_ms,
            connectTimeoutMS=s.mongo_connect_timeout_ms,
            socketTimeoutMS=s.mongo_socket_timeout_ms,
            timeoutMS=s.mongo_timeout_ms,
            tz_aware=True,
            tzinfo=UTC,
            appname="ares-blackbox",
        )
        self._db = self._client[s.mongo_db]
        self._records = self._db["records"]
        self._events = self._db["events"]
        self._users = self._db["users"]
        self._revoked = self._db["revoked_tokens"]
        self._acknowledged = self._db["acknowledged"]
        self._last_purge: datetime | None = None
        self._setup_lock = threading.Lock()
        self._ready = False

    # ---- plumbing --------------------------------------------------------------------------

    def _setup(self) -> None:
        existing = set(self._db.list_collection_names())
        ttl: dict[str, Any] = {} if self.settings.keep_until_acknowledged else {"expireAfterSeconds": RETENTION_S}
        if "records" not in existing:
            try:
                self._db.create_collection(
                    "records",
                    timeseries={"timeField": "time", "metaField": "vehicle_id", "granularity": "seconds"},
                    **ttl,
                )
            except CollectionInvalid:
                pass  # created by another process since we listed
            except OperationFailure as exc:
                if exc.code != NAMESPACE_EXISTS:
                    raise
        elif not ttl:  # made with a TTL before the vehicle waited for its fleet
            self._db.command("collMod", "records", expireAfterSeconds="off")
        # MongoDB >= 6.3 already indexes (meta, time) on new time-series collections; asking
        # again for the same index is a no-op, and covers older servers
        self._records.create_index([("vehicle_id", ASCENDING), ("time", ASCENDING)])
        self._events.create_index([("vehicle_id", ASCENDING), ("time", ASCENDING)])
        # an event is stored once: a batch retried after an uncertain failure adds nothing
        self._events.create_index([(f, ASCENDING) for f in EVENT_IDENTITY], unique=True, name="event_once")
        if ttl:
            self._events.create_index("time", expireAfterSeconds=RETENTION_S)
        elif "time_1" in self._events.index_information():
            self._events.drop_index("time_1")
        self._users.create_index("name", unique=True)
        # a revoked token id is kept until its token expires (the server's TTL monitor removes it)
        self._revoked.create_index("token_id", unique=True)
        self._revoked.create_index("expires", expireAfterSeconds=0)
        self._acknowledged.create_index("vehicle_id", unique=True)

    @contextmanager
    def _call(self, setup: bool = True) -> Iterator[None]:
        """Run one store call: set up first if not done yet; unreachable or late -> StoreUnavailable."""
        try:
            if setup and not self._ready:
                with self._setup_lock:
                    if not self._ready:
                        self._setup()
                        self._ready = True
            yield
        except UNAVAILABLE as exc:
            raise StoreUnavailable(f"MongoDB: {exc}") from exc
        except PyMongoError as exc:
            # pymongo flags every error caused by a timeout (timeoutMS expired in a bulk
            # write, write concern timeout, ...): the same "try again later"
            if exc.timeout:
                raise StoreUnavailable(f"MongoDB: {exc}") from exc
            raise

    # ---- records -----------------------------------------------------------------------------

    def insert_records(self, records: Sequence[VehicleRecord]) -> int:
        # per vehicle, one document per whole second and run (the first of a batch's duplicates wins)
        by_vehicle: dict[str, dict[tuple[datetime, str], dict]] = {}
        for record in records:
            t = _utc(record.time).replace(microsecond=0)
            doc = record.model_dump(mode="json")
            doc["time"] = t
            by_vehicle.setdefault(record.vehicle_id, {}).setdefault((t, record.run or ""), doc)
        if not by_vehicle:
            return 0
        new: list[dict] = []
        with self._call():
            for vehicle_id, docs in by_vehicle.items():
                times = [t for t, _ in docs]
                held = self._records.find(
                    {"vehicle_id": vehicle_id, "time": {"$gte": min(times), "$lte": max(times)}},
                    {"_id": 0, "time": 1, "run": 1, "dup": 1},
                )
                new.extend(_new_documents(docs, held))
            if new:
                self._records.insert_many(new, ordered=False)
        self._purge_if_due()
        return len(new)

    def _purge_if_due(self) -> None:
        """Without a TTL (keep_until_acknowledged) the purge is the inserts': at most every
        purge_interval_s of the store's clock; one that fails is tried again later."""
        if not self.settings.keep_until_acknowledged:
            return
        now = self.now()
        if self._last_purge is not None and (now - self._last_purge).total_seconds() < self.settings.purge_interval_s:
            return
        self._last_purge = now
        try:
            self.purge_expired()
        except StoreUnavailable:
            return

    def latest(self, vehicle_id: str) -> dict | None:
        with self._call():
            return self._records.find_one(
                {"vehicle_id": vehicle_id, "dup": {"$exists": False}}, _PROJECTION, sort=[("time", DESCENDING)]
            )

    def records(
        self, vehicle_id: str, start: datetime, end: datetime, *, skip: int = 0, limit: int = 1000
    ) -> list[dict]:
        if limit <= 0:  # limit(0) means "no limit" to MongoDB
            return []
        with self._call():
            cursor = (
                self._records.find(_range(vehicle_id, start, end), _PROJECTION)
                .sort("time", ASCENDING)
                .skip(max(skip, 0))
                .limit(limit)
            )
            return list(cursor)

    def records_json(
        self, vehicle_id: str, start: datetime, end: datetime, *, skip: int = 0, limit: int = 1000
    ) -> bytes:
        """records() as one JSON array (bytes), `time` as RFC 3339 with Z, as the embedded store gives it."""
        return orjson.dumps(self.records(vehicle_id, start, end, skip=skip, limit=limit), option=orjson.OPT_UTC_Z)

    def count_records(self, vehicle_id: str, start: datetime, end: datetime) -> int:
        with self._call():
            return self._records.count_documents(_range(vehicle_id, start, end))

    def vehicles(self) -> list[str]:
        with self._call():
            # MongoDB advises $group over distinct on time-series collections (it groups the
            # buckets' meta field without unpacking the measurements)
            recorded = {doc["_id"] for doc in self._records.aggregate([{"$group": {"_id": "$vehicle_id"}}])}
            return sorted(recorded | set(self._events.distinct("vehicle_id")))

    # ---- events --------------------------------------------------------------------------------

    def insert_events(self, events: Sequence[StoredEvent]) -> int:
        docs = []
        for event in events:
            doc = event.model_dump(mode="json")
            doc["time"] = _utc(event.time)
            docs.append(doc)
        if not docs:
            return 0
        with self._call():
            # unordered, so a duplicate does not stop the rest; events of one instant still read
            # back in arrival order, by their client-made, increasing ObjectIds
            try:
                return len(self._events.insert_many(docs, ordered=False).inserted_ids)
            except BulkWriteError as exc:
                errors = exc.details.get("writeErrors", [])
                if any(e.get("code") != DUPLICATE_KEY for e in errors) or exc.details.get("writeConcernErrors"):
                    raise
                return int(exc.details.get("nInserted", 0))

    def _query_events(
        self, vehicle_id: str, start: datetime, end: datetime, kinds: list[str] | None, skip: int, limit: int
    ) -> list[dict]:
        query = _range(vehicle_id, start, end)
        if kinds is not None:
            query["kind"] = {"$in": kinds}
        with self._call():
            # _id (an ObjectId, increasing per client) keeps events of one instant in arrival order
            cursor = (
                self._events.find(query, _PROJECTION)
                .sort([("time", ASCENDING), ("_id", ASCENDING)])
                .skip(skip)
                .limit(limit)
            )
            return list(cursor)

    # ---- retention -----------------------------------------------------------------------------

    def purge_expired(self) -> int:
        """MongoDB's TTL monitor already removes expired data (every ~60 s, by the server's
        clock) unless the store keeps what is not acknowledged. This deletes explicitly by the
        store's clock too, so the retention contract holds exactly and can be tested with a
        controlled clock. Deleting from a time-series collection on its timeField needs MongoDB
        >= 7.0; on releases affected by SERVER-99527 such a delete can expire data inserted later
        within ~2 h of the deleted range early, which a 7-day cutoff meets only for records
        uploaded a week late."""
        cutoff = self.now() - RETENTION
        with self._call():
            if not self.settings.keep_until_acknowledged:
                removed = self._records.delete_many({"time": {"$lt": cutoff}}).deleted_count
                return removed + self._events.delete_many({"time": {"$lt": cutoff}}).deleted_count
            removed = 0
            for mark in self._acknowledged.find({}, {"_id": 0}):
                until = min(cutoff, datetime.fromtimestamp(mark["upto"] + 1, UTC))
                older = {"vehicle_id": mark["vehicle_id"], "time": {"$lt": until}}
                removed += self._records.delete_many(older).deleted_count
                removed += self._events.delete_many(older).deleted_count
            return removed

    def acknowledged(self, vehicle_id: str) -> int | None:
        with self._call():
            doc = self._acknowledged.find_one({"vehicle_id": vehicle_id}, {"_id": 0, "upto": 1})
        return None if doc is None else int(doc["upto"])

    def acknowledge(self, vehicle_id: str, upto_epoch_s: int) -> int:
        with self._call():
            # $max: the mark never goes back, whichever of two writers comes last
            doc = self._acknowledged.find_one_and_update(
                {"vehicle_id": vehicle_id},
                {"$max": {"upto": int(upto_epoch_s)}},
                upsert=True,
                return_document=True,
                projection={"_id": 0, "upto": 1},
            )
        return int(doc["upto"])

    # ---- users ---------------------------------------------------------------------------------

    def get_user(self, name: str) -> User | None:
        with self._call():
            doc = self._users.find_one({"name": name}, _PROJECTION)
        return _user(doc) if doc else None

    def put_user(self, user: User) -> None:
        doc = {
            "name": user.name,
            "role": user.role,
            "password_hash": user.password_hash,
            "created": _utc(user.created),
            "disabled": user.disabled,
            "generation": user.generation,
        }
        with self._call():
            self._users.replace_one({"name": user.name}, doc, upsert=True)

    def list_users(self) -> list[User]:
        with self._call():
            return [_user(doc) for doc in self._users.find({}, _PROJECTION).sort("name", ASCENDING)]

    def delete_user(self, name: str) -> bool:
        with self._call():
            return self._users.delete_one({"name": name}).deleted_count > 0

    def revoke_token(self, token_id: str, expires: datetime) -> None:
        with self._call():
            self._revoked.replace_one(
                {"token_id": token_id}, {"token_id": token_id, "expires": _utc(expires)}, upsert=True
            )

    def token_revoked(self, token_id: str) -> bool:
        with self._call():
            return self._revoked.find_one({"token_id": token_id}, {"_id": 1}) is not None

    # ---- lifecycle -------------------------------------------------------------------------------

    def ping(self) -> None:
        with self._call(setup=False):
            self._client.admin.command("ping")

    def close(self) -> None:
        self._client.close()

    def drop_database(self) -> None:
        """Remove this store's whole database (tests' throw-away databases)."""
        with self._call(setup=False):
            self._client.drop_database(self._db.name)


def _range(vehicle_id: str, start: datetime, end: datetime) -> dict:
    """A vehicle's records of [start, end) as the API reads them: one per second, the first stored
    (a second held twice, by two runs, keeps its second record with `dup`, as the embedded store)."""
    return {"vehicle_id": vehicle_id, "time": {"$gte": _utc(start), "$lt": _utc(end)}, "dup": {"$exists": False}}


def _new_documents(docs: dict[tuple[datetime, str], dict], held: Iterable[dict]) -> list[dict]:
    """Of a batch's documents (by second and run), those to insert: a (second, run) stored already
    is a retried batch's and skipped; a second another run holds (a clock set back between two runs)
    is kept beside it, numbered `dup` after the ones there, so no run's record is dropped."""
    runs_at: dict[datetime, set[str]] = {}
    dups_at: dict[datetime, int] = {}
    for doc in held:
        t = _utc(doc["time"])
        runs_at.setdefault(t, set()).add(doc.get("run") or "")
        dups_at[t] = max(dups_at.get(t, 0), int(doc.get("dup") or 0))
    out = []
    for (t, run), doc in docs.items():
        if run in runs_at.get(t, set()):
            continue
        if t in runs_at:
            dups_at[t] += 1
            doc["dup"] = dups_at[t]
        runs_at.setdefault(t, set()).add(run)
        dups_at.setdefault(t, 0)
        out.append(doc)
    return out


def _user(doc: dict) -> User:
    return User(
        name=doc["name"],
        role=doc["role"],
        password_hash=doc["password_hash"],
        created=doc["created"],
        # documents written before these fields: an enabled account of generation 0
        disabled=bool(doc.get("disabled", False)),
        generation=int(doc.get("generation", 0)),
    )
