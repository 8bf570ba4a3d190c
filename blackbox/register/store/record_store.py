"""The black box's store interface: what every storage engine offers.

Two engines implement RecordStore: MongoDB through pymongo (deployment: a time-series
collection, 7-day expiry) and an embedded SQLite store (the default when no MongoDB is
configured; same 7-day retention). The REST API's repository and the event register talk only
to this interface; one contract test suite runs over both. Which engine a URI opens is
blackbox.register.store.open_store' business: the engines import this module, so it imports none of them.

Records and events go in as validated models (ares.core.messages.VehicleRecord / StoredEvent) and
come out as plain dicts of JSON-ready values (datetimes as datetime objects), because the
queries return thousands of them and validating each again would cost more than the query.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from typing import Literal

from pydantic import model_validator

from ares.core.config import Params, param
from ares.core.messages import StoredEvent, VehicleRecord

RETENTION = timedelta(days=7)


MONGO_SCHEMES = ("mongodb://", "mongodb+srv://")


class StoreSettings(Params):
    """The `blackbox_store` section: where the black box keeps its records, and how."""

    uri: str | None = param(
        None,
        "a mongodb:// URI, or the embedded store's file (null: `path`); "
        "`ares run --store URI` sets it for the recorder and the API",
    )
    path: str = param(
        "data/blackbox.sqlite",
        "embedded store's file when no MongoDB URI is given (relative to the working directory of `ares run`)",
    )
    busy_timeout_s: float = param(
        2.0, "longest a call waits for a lock held by another connection or process -> StoreUnavailable", unit="s", gt=0
    )
    query_timeout_s: float = param(
        10.0, "longest one SQLite statement may run before it is interrupted -> StoreUnavailable", unit="s", gt=0
    )
    synchronous: Literal["OFF", "NORMAL", "FULL", "EXTRA"] = param(
        "FULL", "each commit reaches the disk before insert returns (a black box must survive a power cut)"
    )
    purge_interval_s: float = param(
        60.0, "inserts run the retention purge at most this often (store clock)", unit="s", gt=0
    )
    keep_until_acknowledged: bool = param(
        False,
        "the purge deletes only seconds past the retention that the fleet acknowledged holding; off: 7 days",
    )
    page_size: int = param(16384, "new files only: a ~1.4 kB record fits its b-tree page", unit="B", ge=512)
    mmap_size_mb: int = param(256, "reads map the file instead of copying pages", unit="MiB", ge=0)
    mongo_db: str = param("ares", "MongoDB database (records: time series; events; users)")
    mongo_server_selection_timeout_ms: int = param(
        2000,
        "pymongo's serverSelectionTimeoutMS; while mongo_timeout_ms bounds an operation, pymongo 4.20 waits that "
        "instead (measured: an unreachable server is given up after mongo_timeout_ms)",
        unit="ms",
        gt=0,
    )
    mongo_connect_timeout_ms: int = param(2000, "connection timeout", unit="ms", gt=0)
    mongo_socket_timeout_ms: int = param(5000, "socket timeout", unit="ms", gt=0)
    mongo_timeout_ms: int = param(
        5000,
        "client-side bound on every operation, server selection included (pymongo timeoutMS): no reachable "
        "server this long -> StoreUnavailable",
        unit="ms",
        gt=0,
    )
    mongo_user: str | None = param(None, "MongoDB user (a deployment's: docs/deploy.md); null: the URI's, if any")
    mongo_password_file: str | None = param(
        None, "file holding that user's password (a compose secret), so that no config or URI carries it"
    )

    @model_validator(mode="after")
    def _mongo_user_and_password(self) -> StoreSettings:
        if (self.mongo_user is None) != (self.mongo_password_file is None):
            raise ValueError("blackbox_store: give both mongo_user and mongo_password_file, or neither")
        return self

    def location(self) -> str:
        """The configured URI, else the embedded store's file."""
        return self.uri or self.path


def is_mongo(uri: str) -> bool:
    return uri.startswith(MONGO_SCHEMES)


class StoreUnavailable(RuntimeError):
    """The store cannot be reached or did not answer in time; the caller may retry later."""


@dataclass(frozen=True)
class User:
    name: str
    role: str  # auditor | operator | fleet | admin
    password_hash: str
    created: datetime
    disabled: bool = False  # refused at login and on every request, kept for the record
    # bumped whenever the account changes (role, password, disabled): tokens carry the generation
    # they were issued under, so a change ends every token issued before it
    generation: int = 0


_EARLIEST = datetime(1970, 1, 1, tzinfo=UTC)
_LATEST = datetime(9000, 1, 1, tzinfo=UTC)


def as_utc(dt: datetime) -> datetime:
    """Aware UTC datetime; a naive one is taken to be UTC already."""
    if dt.tzinfo is None:
        return dt.replace(tzinfo=UTC)
    return dt.astimezone(UTC)


def utc_now() -> datetime:
    return datetime.now(UTC)


class RecordStore(ABC):
    """What every engine offers. The engines subclass it; what is the same for all of them (the
    arguments' checks of a query) is here once, each engine keeping only its query."""

    now: Callable[[], datetime]  # the store's clock (replaceable in tests for retention)

    @abstractmethod
    def insert_records(self, records: Sequence[VehicleRecord]) -> int:
        """Store records; one per (vehicle_id, time): a second already stored is skipped, so a
        retried batch never duplicates. Returns how many were new."""

    @abstractmethod
    def insert_events(self, events: Sequence[StoredEvent]) -> int:
        """Store events; the same event twice (a retried batch) is stored once. Returns how many were new."""

    @abstractmethod
    def latest(self, vehicle_id: str) -> dict | None: ...

    @abstractmethod
    def records(
        self, vehicle_id: str, start: datetime, end: datetime, *, skip: int = 0, limit: int = 1000
    ) -> list[dict]:
        """Records with start <= time < end, oldest first."""

    @abstractmethod
    def records_json(
        self, vehicle_id: str, start: datetime, end: datetime, *, skip: int = 0, limit: int = 1000
    ) -> bytes:
        """records() as one JSON array (UTF-8), `time` as RFC 3339 with Z: what a handler
        sends on, without building and encoding the dicts again."""

    @abstractmethod
    def count_records(self, vehicle_id: str, start: datetime, end: datetime) -> int: ...

    def events(
        self,
        vehicle_id: str,
        start: datetime,
        end: datetime,
        *,
        kinds: Sequence[str] | None = None,
        skip: int = 0,
        limit: int = 1000,
    ) -> list[dict]:
        """Events with start <= time < end, of `kinds` when given, oldest first (those of one
        instant in the order they arrived), from the skip-th on, at most `limit`. A limit below 1
        or an empty `kinds` selects nothing (to MongoDB, limit 0 would mean no limit); a negative
        skip counts as 0."""
        if limit <= 0 or (kinds is not None and not kinds):
            return []
        return self._query_events(vehicle_id, start, end, None if kinds is None else list(kinds), max(skip, 0), limit)

    @abstractmethod
    def _query_events(
        self, vehicle_id: str, start: datetime, end: datetime, kinds: list[str] | None, skip: int, limit: int
    ) -> list[dict]:
        """The engine's query behind events(), on checked arguments: limit >= 1, skip >= 0, kinds
        None (any) or not empty."""

    @abstractmethod
    def vehicles(self) -> list[str]: ...

    @abstractmethod
    def purge_expired(self) -> int:
        """Remove what is older than RETENTION by the store's clock; returns how many. With
        `keep_until_acknowledged`, of each vehicle only what is also at or before its acknowledged
        mark (nothing of a vehicle without one): the fleet's store holds it."""

    @abstractmethod
    def acknowledged(self, vehicle_id: str) -> int | None:
        """The second (UTC epoch s) up to which the fleet's store holds every record of the
        vehicle, as the fleet last acknowledged it; None before the first acknowledgement."""

    @abstractmethod
    def acknowledge(self, vehicle_id: str, upto_epoch_s: int) -> int:
        """Raise the vehicle's acknowledged mark to `upto_epoch_s` (never lower it: a purge may
        already have deleted what it covered); returns the mark now stored."""

    def oldest_second(self, vehicle_id: str) -> int | None:
        """The oldest second of the vehicle's records held (UTC epoch s), None if none."""
        first = self.records(vehicle_id, _EARLIEST, _LATEST, limit=1)
        return None if not first else math.floor(as_utc(first[0]["time"]).timestamp())

    def unacknowledged_expired(self, vehicle_id: str) -> tuple[int, int | None]:
        """(how many, the oldest) of the vehicle's records older than RETENTION that the purge
        keeps for want of an acknowledgement."""
        cutoff = self.now() - RETENTION
        mark = self.acknowledged(vehicle_id)
        start = _EARLIEST if mark is None else datetime.fromtimestamp(mark + 1, UTC)
        if start >= cutoff:
            return 0, None
        count = self.count_records(vehicle_id, start, cutoff)
        if not count:
            return 0, None
        first = self.records(vehicle_id, start, cutoff, limit=1)
        return count, math.floor(as_utc(first[0]["time"]).timestamp()) if first else None

    @abstractmethod
    def get_user(self, name: str) -> User | None: ...

    @abstractmethod
    def put_user(self, user: User) -> None: ...

    @abstractmethod
    def list_users(self) -> list[User]: ...

    @abstractmethod
    def delete_user(self, name: str) -> bool:
        """Remove the user; False when there was none."""

    @abstractmethod
    def revoke_token(self, token_id: str, expires: datetime) -> None:
        """Refuse the token `token_id` from now on; kept until `expires` (the token's own expiry:
        past it the signature check refuses the token anyway, so the entry can go)."""

    @abstractmethod
    def token_revoked(self, token_id: str) -> bool: ...

    @abstractmethod
    def ping(self) -> None:
        """Raise StoreUnavailable unless the store answers."""

    @abstractmethod
    def close(self) -> None: ...
