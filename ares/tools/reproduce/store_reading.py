"""A drive's black box read back as an auditor reads it: every event and record of its vehicle."""

from __future__ import annotations

from datetime import UTC, datetime
from pathlib import Path

PAST, FUTURE = datetime(2000, 1, 1, tzinfo=UTC), datetime(2100, 1, 1, tzinfo=UTC)


def events_and_records(store_file: Path, vehicle_id: str = "shuttle01") -> tuple[list[dict], list[dict]]:
    from blackbox.register.store.sqlite_store import SqliteStore

    store = SqliteStore(str(store_file))
    try:
        return (
            store.events(vehicle_id, PAST, FUTURE, limit=1_000_000),
            store.records(vehicle_id, PAST, FUTURE, limit=1_000_000),
        )
    finally:
        store.close()
