"""Checks of the black box's records: one per second, none duplicated, none missing."""

from __future__ import annotations

import math
from datetime import UTC, datetime

from blackbox.register.store.sqlite_store import SqliteStore

PAST, FUTURE = datetime(2000, 1, 1, tzinfo=UTC), datetime(2100, 1, 1, tzinfo=UTC)
VEHICLE = "shuttle01"


def assert_every_second_once(ts: list[int]) -> None:
    assert ts, "no records"
    assert len(ts) == len(set(ts)), f"duplicated seconds: {sorted(t for t in set(ts) if ts.count(t) > 1)}"
    missing = sorted(set(range(min(ts), max(ts) + 1)) - set(ts))
    assert not missing, f"missing seconds: {missing}"


def assert_drive_recorded(path, result: dict, seconds: int) -> None:
    """The store of a drive of at least `seconds` of vehicle time holds one record per second, none
    duplicated, none missing, exactly `seconds` for the drive's first `seconds`; `ares run`'s count
    (`blackbox_records`) agrees with it."""
    assert result["total_time_s"] >= seconds
    ts, events = stored(path)
    assert_every_second_once(ts)  # distinct seconds == count, no gap
    if "blackbox_records" in result:
        assert result["blackbox_records"] == len(ts)
    # whatever fraction of a second the drive starts at, its first seconds hold exactly as many whole ones
    drive_start = result["t_start_s"]
    drive = [t for t in ts if drive_start <= t < drive_start + seconds]
    assert len(drive) == seconds, f"{len(drive)} records during the first {seconds} s of the drive"
    assert ts[-1] >= math.floor(result["t_end_s"]), "the last seconds were flushed when the stack stopped"
    assert not [e for e in events if e["kind"].startswith("blackbox_")], "the store never went down"


def stored(path) -> tuple[list[int], list[dict]]:
    store = SqliteStore(str(path))
    try:
        ts = [int(r["t"]) for r in store.records(VEHICLE, PAST, FUTURE, limit=1_000_000)]
        return ts, store.events(VEHICLE, PAST, FUTURE, limit=1_000_000)
    finally:
        store.close()


def records(path) -> list[dict]:
    """Every record of VEHICLE in the store file, oldest first."""
    store = SqliteStore(str(path))
    try:
        return store.records(VEHICLE, PAST, FUTURE, limit=1_000_000)
    finally:
        store.close()
