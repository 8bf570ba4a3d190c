"""The MongoDB store's rule for a second held twice (blackbox/register/store/mongo_store.py), which
needs no server: which of a batch's documents are inserted, and with which `dup`. The store's own
contract, on a real server, is tests/test_store_contract.py's (skipped where none runs, as here)."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

from blackbox.register.store.mongo_store import _new_documents, _range

T0 = datetime(2026, 12, 2, 10, 0, tzinfo=UTC)


def batch(*keys: tuple[int, str]) -> dict:
    return {(T0 + timedelta(seconds=k), run): {"time": T0 + timedelta(seconds=k), "run": run} for k, run in keys}


def test_a_retried_batch_inserts_nothing_and_a_second_run_over_the_same_seconds_is_kept_beside():
    held = [{"time": (T0 + timedelta(seconds=k)).replace(tzinfo=None), "run": "run-a"} for k in range(3)]
    assert _new_documents(batch((0, "run-a"), (1, "run-a")), held) == []  # MongoDB gives naive UTC back
    again = _new_documents(batch((1, "run-b"), (2, "run-b"), (3, "run-b")), held)
    assert [(d["time"], d.get("dup")) for d in again] == [
        (T0 + timedelta(seconds=1), 1),
        (T0 + timedelta(seconds=2), 1),
        (T0 + timedelta(seconds=3), None),  # a second no run held: the first of it
    ]


def test_a_third_run_numbers_after_the_ones_there_and_reads_see_the_first_only():
    held = [
        {"time": T0, "run": "run-a"},
        {"time": T0, "run": "run-b", "dup": 1},
    ]
    (third,) = _new_documents(batch((0, "run-c")), held)
    assert third["dup"] == 2
    assert _range("shuttle01", T0, T0 + timedelta(seconds=1))["dup"] == {"$exists": False}
