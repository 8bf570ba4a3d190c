"""The reliability report's cost is bounded (issue 42): a window's settled hours are tallied
once and cached (a late record in one of them is still counted), and the reports computed at
once per role are limited (the lowest role cannot take every core)."""

from __future__ import annotations

from datetime import timedelta

from fastapi.testclient import TestClient

from ares.core.messages import ProcessHealth, VehicleRecord
from blackbox.api import create_app
from blackbox.register import reliability as rel
from tests.helpers.api import VEHICLE, add_role_users, api_settings, auth, open_test_store, seed, token_for

VEHICLE_ID = "shuttle01"
URL = f"/api/v1/vehicles/{VEHICLE}/reliability"


def iso(dt) -> str:
    return dt.isoformat().replace("+00:00", "Z")


def whole_window_tally(store, start, end):
    """The report's figures the way they were made before the cache: every record at once."""
    records = store.records(VEHICLE, start, end, limit=10**6)
    faults = [e["time"] for e in store.events(VEHICLE, start, end, limit=10**6) if e["level"] == "fault"]
    return rel.tally_window(records, faults, until=min(end, store.now())), len(records)


def test_settled_hours_are_cached_and_a_late_record_still_counts(tmp_path):
    store = open_test_store(tmp_path / "blackbox.sqlite")
    try:
        now = store.now()
        first = seed(store, now - timedelta(hours=5))  # 30 min, five hours ago, with an outage
        seed(store, now - timedelta(hours=2, minutes=10))
        seed(store)  # and the last 30 min
        app = create_app(store, api_settings(), VEHICLE_ID)
        add_role_users(store, app)
        client = TestClient(app)
        h = auth(token_for(client, "auditor"))
        params = {"start": iso(first - timedelta(minutes=1)), "end": iso(now)}

        report = client.get(URL, headers=h, params=params).json()
        tally, count = whole_window_tally(store, first - timedelta(minutes=1), now)
        assert report["records"] == count == 3 * 1800
        assert report["failures"] == tally.failures == 3
        assert report["operating_hours"] * 3600 == tally.operating_s
        assert report["repair_hours"] * 3600 == tally.repair_s
        cache = app.state.services.repository.reliability_pieces
        assert len(cache) >= 4  # the settled whole hours of the window

        assert client.get(URL, headers=h, params=params).json() == report  # from the cache

        # a record uploaded late, into a settled hour: that hour is tallied again
        late = VehicleRecord(
            vehicle_id=VEHICLE,
            time=first - timedelta(seconds=30),
            t=0.0,
            mode="AUTOMATIC",
            processes={"controller": ProcessHealth(state="running")},
        )
        store.insert_records([late])
        again = client.get(URL, headers=h, params=params).json()
        assert again["records"] == report["records"] + 1
        assert again["operating_hours"] * 3600 == report["operating_hours"] * 3600 + 1
    finally:
        store.close()


def test_reports_in_flight_are_limited_per_role(tmp_path):
    store = open_test_store(tmp_path / "blackbox.sqlite")
    seed(store)
    try:
        app = create_app(store, api_settings(rate_limit={"reports_per_role": 2}), VEHICLE_ID)
        add_role_users(store, app)
        client = TestClient(app)
        fleet, auditor = auth(token_for(client, "fleet")), auth(token_for(client, "auditor"))
        guard = app.state.services.guard
        with guard.report_slot("fleet") as one, guard.report_slot("fleet") as two:
            assert one and two  # two fleet reports being computed
            r = client.get(URL, headers=fleet)
            assert r.status_code == 429 and int(r.headers["retry-after"]) > 0
            assert "fleet" in r.json()["detail"]
            assert client.get(URL, headers=auditor).status_code == 200  # another role's slots
        assert client.get(URL, headers=fleet).status_code == 200
        assert guard.reports_in_flight["fleet"] == 0
    finally:
        store.close()
