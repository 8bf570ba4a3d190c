"""The black box REST API (blackbox/api/) against a real embedded store on a temporary file.

The helpers at the top (seed, settings, clients) are reused by test_api_security.py and
test_api_schema.py.
"""

from __future__ import annotations

import csv
import io
import json
import time
from datetime import UTC, datetime, timedelta

import pytest
from fastapi.testclient import TestClient

from ares.core.config import VEHICLE_ID_PATTERN
from ares.core.messages import EventLevel, StoredEvent, VehicleRecord
from blackbox.api import CSV_COLUMNS, RECORD_FIELDS, create_app
from blackbox.api.credentials import ROLES
from blackbox.register.store.record_store import RETENTION, StoreUnavailable
from tests.helpers.api import (
    FAULT_AT,
    N_RECORDS,
    OTHER,
    PASSWORD,
    VEHICLE,
    VEHICLE_ID,
    add_role_users,
    api_settings,
    auth,
    open_test_store,
    seed,
    token_for,
)


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    """(client, app, store, first record time, {role: token}), shared by the module's read-only
    tests (the ones that write use fresh names)."""
    store = open_test_store(tmp_path_factory.mktemp("api") / "blackbox.sqlite")
    first = seed(store)
    app = create_app(store, api_settings(), VEHICLE_ID)
    add_role_users(store, app)
    client = TestClient(app)
    tokens = {role: token_for(client, role) for role in ROLES}
    yield client, app, store, first, tokens
    store.close()


def iso(dt: datetime) -> str:
    return dt.astimezone(UTC).isoformat().replace("+00:00", "Z")


# ---- health, auth ------------------------------------------------------------------------------


def test_health(world):
    client, *_ = world
    r = client.get("/api/v1/health")
    assert r.status_code == 200 and r.json() == {"status": "ok", "store": "ok", "detail": None}


def test_token_and_renew(world):
    client, app, _, _, tokens = world
    r = client.post("/api/v1/auth/token", data={"username": "auditor", "password": PASSWORD})
    body = r.json()
    assert body["token_type"] == "bearer" and body["expires_in"] == 900 and body["role"] == "auditor"
    assert app.state.services.tokens.verify(body["access_token"]).name == "auditor"
    r = client.post("/api/v1/auth/renew", headers=auth(tokens["fleet"]))
    assert r.status_code == 200
    renewed = r.json()["access_token"]
    assert renewed != tokens["fleet"] and r.json()["role"] == "fleet"
    assert client.get("/api/v1/vehicles", headers=auth(renewed)).status_code == 200
    assert client.post("/api/v1/auth/renew").status_code == 401


def test_wrong_password_and_unknown_user(world):
    client, *_ = world
    for name, pw in (("auditor", "nope nope nope"), ("nobody", PASSWORD)):
        r = client.post("/api/v1/auth/token", data={"username": name, "password": pw})
        assert r.status_code == 401 and r.json()["detail"] == "wrong user name or password"
        assert r.headers["www-authenticate"] == "Bearer"
    r = client.post("/api/v1/auth/token", data={"username": "auditor"})
    assert r.status_code == 422 and "password" in r.json()["detail"]


# ---- vehicles and latest -------------------------------------------------------------------------


def test_vehicles(world):
    client, _, _, _, tokens = world
    r = client.get("/api/v1/vehicles", headers=auth(tokens["fleet"]))
    assert r.status_code == 200
    by_id = {v["vehicle_id"]: v for v in r.json()["vehicles"]}
    assert set(by_id) == {VEHICLE, OTHER}
    assert by_id[VEHICLE]["mode"] == "AUTOMATIC" and by_id[OTHER]["mode"] == "READY"


def test_latest_and_its_cache(store):
    seed(store)
    # long enough that a busy machine answers the second request within it
    app = create_app(store, api_settings(limits={"latest_cache_s": 1.0}), VEHICLE_ID)
    add_role_users(store, app)
    client = TestClient(app)
    h = auth(token_for(client, "fleet"))
    r = client.get(f"/api/v1/vehicles/{VEHICLE}/latest", headers=h)
    assert r.status_code == 200 and r.headers["content-type"] == "application/json"
    latest = VehicleRecord.model_validate(r.json())
    assert latest.t == N_RECORDS - 1 and latest.mode.value == "AUTOMATIC"
    store.insert_records(
        [VehicleRecord(vehicle_id=VEHICLE, time=latest.time + timedelta(seconds=1), t=N_RECORDS, mode="MANUAL")]
    )
    assert client.get(f"/api/v1/vehicles/{VEHICLE}/latest", headers=h).json()["t"] == N_RECORDS - 1  # cached
    time.sleep(1.05)
    assert client.get(f"/api/v1/vehicles/{VEHICLE}/latest", headers=h).json()["t"] == N_RECORDS


def test_unknown_vehicle_404(world):
    client, _, _, _, tokens = world
    for path in ("latest", "records", "events", "reliability", "export"):
        r = client.get(f"/api/v1/vehicles/nosuch/{path}", headers=auth(tokens["auditor"]))
        assert r.status_code == 404, path
        assert "unknown vehicle 'nosuch'" in r.json()["detail"]


def test_vehicle_id_is_a_configured_one(world):
    """The path's vehicle id is what a stack's configuration allows (ares.core.config), in ASCII: the
    same for the schema's reader (ECMA 262, where \\s is no NEL) and the server (where it is)."""
    client, _, _, _, tokens = world
    op = client.get("/openapi.json").json()["paths"]["/api/v1/vehicles/{vehicle_id}/latest"]["get"]
    (param,) = [p for p in op["parameters"] if p["name"] == "vehicle_id"]
    assert param["schema"]["pattern"] == VEHICLE_ID_PATTERN
    for bad in ("shuttle\x8501", "shuttle 01", "a" * 65, "é"):
        r = client.get(f"/api/v1/vehicles/{bad}/latest", headers=auth(tokens["auditor"]))
        assert r.status_code == 422, repr(bad)


# ---- records -----------------------------------------------------------------------------------


def test_records_paging(world):
    client, _, _, first, tokens = world
    h = auth(tokens["auditor"])
    window = {"start": iso(first), "end": iso(first + timedelta(seconds=N_RECORDS))}
    r = client.get(f"/api/v1/vehicles/{VEHICLE}/records", params={**window, "page_size": 500}, headers=h)
    body = r.json()
    assert r.status_code == 200 and body["total"] == N_RECORDS and len(body["records"]) == 500
    assert body["fields"] is None and set(body["records"][0]) == set(RECORD_FIELDS)
    VehicleRecord.model_validate(body["records"][0])
    r = client.get(f"/api/v1/vehicles/{VEHICLE}/records", params={**window, "page_size": 500, "page": 4}, headers=h)
    page4 = r.json()["records"]
    assert len(page4) == N_RECORDS - 1500 and page4[0]["t"] == 1500 and page4[-1]["t"] == N_RECORDS - 1
    r = client.get(f"/api/v1/vehicles/{VEHICLE}/records", params={**window, "page_size": 500, "page": 5}, headers=h)
    assert r.status_code == 200 and r.json()["records"] == []
    # a sub-window: start inclusive, end exclusive
    r = client.get(
        f"/api/v1/vehicles/{VEHICLE}/records",
        headers=h,
        params={"start": iso(first + timedelta(seconds=10)), "end": iso(first + timedelta(seconds=20))},
    )
    assert [rec["t"] for rec in r.json()["records"]] == [float(i) for i in range(10, 20)]


def test_a_page_of_every_field_is_the_same_whether_spliced_or_selected(world):
    """Without a field selection the stored documents are spliced into the page as they are;
    selecting every field goes through dicts. Both give the same page."""
    client, _, _, first, tokens = world
    h = auth(tokens["auditor"])
    window = {"start": iso(first), "end": iso(first + timedelta(seconds=N_RECORDS)), "page_size": 50, "page": 3}
    spliced = client.get(f"/api/v1/vehicles/{VEHICLE}/records", params=window, headers=h).json()
    selected = client.get(
        f"/api/v1/vehicles/{VEHICLE}/records", headers=h, params={**window, "fields": ",".join(RECORD_FIELDS)}
    ).json()
    assert spliced.pop("fields") is None and sorted(selected.pop("fields")) == sorted(RECORD_FIELDS)
    assert spliced == selected and len(spliced["records"]) == 50


def test_records_default_window_is_last_hour(world):
    client, _, _, _, tokens = world
    r = client.get(f"/api/v1/vehicles/{VEHICLE}/records", params={"page_size": 1}, headers=auth(tokens["operator"]))
    body = r.json()
    assert r.status_code == 200 and body["total"] == N_RECORDS
    start, end = datetime.fromisoformat(body["start"]), datetime.fromisoformat(body["end"])
    assert end - start == timedelta(hours=1)


def test_field_selection(world):
    client, _, _, first, tokens = world
    h = auth(tokens["auditor"])
    r = client.get(
        f"/api/v1/vehicles/{VEHICLE}/records",
        headers=h,
        params={"fields": "speed_mps,mode,position", "start": iso(first), "page_size": 3},
    )
    body = r.json()
    assert r.status_code == 200 and body["fields"] == ["time", "speed_mps", "mode", "position"]
    assert all(set(rec) == {"time", "speed_mps", "mode", "position"} for rec in body["records"])
    assert body["records"][0]["position"]["easting"] == 440000.0
    r = client.get(f"/api/v1/vehicles/{VEHICLE}/records", headers=h, params={"fields": "mode,time", "page_size": 1})
    assert r.status_code == 200 and r.json()["fields"] == ["time", "mode"]
    r = client.get(f"/api/v1/vehicles/{VEHICLE}/records", headers=h, params={"page_size": 1})
    assert r.status_code == 200 and r.json()["fields"] is None  # nothing selected: every field
    r = client.get(f"/api/v1/vehicles/{VEHICLE}/records", headers=h, params={"fields": "", "page_size": 1})
    assert r.status_code == 422  # an empty name is no field
    # the schema's array of field names, comma-separated, each once: anything else is refused
    r = client.get(f"/api/v1/vehicles/{VEHICLE}/records", headers=h, params={"fields": "speed_mps,altitude,_id"})
    assert r.status_code == 422
    assert "unknown field(s) 'altitude', '_id'" in r.json()["detail"]
    for bad in ("speed_mps, mode", "speed_mps,,mode", "mode,mode"):
        r = client.get(f"/api/v1/vehicles/{VEHICLE}/records", headers=h, params={"fields": bad})
        assert r.status_code == 422, bad


def test_fields_enumerated_in_the_schema(world):
    client, *_ = world
    op = client.get("/openapi.json").json()["paths"]["/api/v1/vehicles/{vehicle_id}/records"]["get"]
    (fields,) = [p for p in op["parameters"] if p["name"] == "fields"]
    assert fields["in"] == "query" and fields["style"] == "form" and fields["explode"] is False
    assert fields["schema"]["items"]["enum"] == list(RECORD_FIELDS) and fields["schema"]["uniqueItems"] is True


@pytest.mark.parametrize(
    "params, message",
    [
        ({"page_size": 100000}, "page_size"),
        ({"page": 0}, "page"),
        ({"start": "2025-01-01T00:00:00"}, "UTC offset"),  # naive: ambiguous
        ({"start": "yesterday"}, "start"),
        ({"start": "0.5"}, "RFC 3339"),  # pydantic alone: 0.5 s after 1970
        ({"end": "2026-01-31"}, "RFC 3339"),
        ({"end": "2026-01-31 08:00:00Z"}, "RFC 3339"),
        ({"end": "2026-01-31T08:59:60Z"}, "leap second"),  # only at 23:59:60 UTC
        ({"fields": "mode,altitude"}, "unknown field"),
    ],
)
def test_records_bad_parameters_422(world, params, message):
    client, _, _, _, tokens = world
    r = client.get(f"/api/v1/vehicles/{VEHICLE}/records", params=params, headers=auth(tokens["auditor"]))
    assert r.status_code == 422
    assert message in r.json()["detail"]


def test_windows_beyond_the_retention_are_clipped(store):
    """Any date-time is a valid bound (the schema says so): what the window holds inside the
    7-day retention is served, and the answer says that the window was clipped."""
    now = store.now().replace(microsecond=0)
    oldest = now - RETENTION
    # every 10 s from 400 s before the retention's start to 60 s after it: events, then records
    # (the first insert purged what had expired; the records are in before the next purge is due)
    store.insert_events(
        [
            StoredEvent(
                vehicle_id=VEHICLE,
                time=oldest + timedelta(seconds=s, milliseconds=500),
                t=s + 0.5,
                source="test",
                kind="mark",
                level=EventLevel.INFO,
                message=str(s),
            )
            for s in range(-400, 60, 10)
        ]
    )
    store.insert_records(
        [
            VehicleRecord(vehicle_id=VEHICLE, time=oldest + timedelta(seconds=s), t=float(s), mode="READY")
            for s in range(-400, 60, 10)
        ]
    )
    app = create_app(store, api_settings(), VEHICLE_ID)
    add_role_users(store, app)
    client = TestClient(app)
    h = auth(token_for(client, "auditor"))
    url = f"/api/v1/vehicles/{VEHICLE}"
    inside = [float(s) for s in range(10, 60, 10)]  # the one at the retention's start may have just left it

    def get(path, **params):
        r = client.get(f"{url}/{path}", params=params, headers=h)
        assert r.status_code == 200, (path, params, r.text)
        return r

    long_ago = {"start": "2000-01-01T00:00:00Z", "end": iso(oldest + timedelta(seconds=60))}
    body = get("records", page_size=1000, **long_ago).json()
    assert body["clipped"] is True and datetime.fromisoformat(body["start"]) >= oldest
    assert [r["t"] for r in body["records"]][-5:] == inside and min(r["t"] for r in body["records"]) >= 0
    body = get("events", page_size=1000, kind="mark", **long_ago).json()
    assert body["clipped"] is True and [e["t"] for e in body["events"]][-5:] == [t + 0.5 for t in inside]
    body = get("reliability", **long_ago).json()
    assert body["clipped"] is True and 5 <= body["records"] <= 6
    r = get("export", **long_ago)
    assert r.headers["x-window-clipped"] == "true" and len(r.text.splitlines()) in (5, 6)
    assert datetime.fromisoformat(r.headers["x-window-start"]) >= oldest
    assert r.headers["x-window-end"] == iso(oldest + timedelta(seconds=60))

    # a start a moment before the retention's ("now - 7 days" computed earlier) is served as asked
    body = get("records", page_size=1000, start=iso(oldest - timedelta(seconds=100))).json()
    assert body["clipped"] is False and [r["t"] for r in body["records"]][:3] == [-100.0, -90.0, -80.0]
    # not clipped: the window asked for
    r = get("export", start=iso(oldest + timedelta(seconds=5)), end=iso(oldest + timedelta(seconds=35)))
    assert r.headers["x-window-clipped"] == "false" and len(r.text.splitlines()) == 3
    assert get("records", start=iso(now - timedelta(hours=2)))
    assert get("records").json()["clipped"] is False

    # wholly before the retention, reversed, or empty: nothing, at end = start
    for params in (
        {"start": "2000-01-01T00:00:00Z", "end": "2000-01-02T00:00:00Z"},
        {"end": "2000-01-02T00:00:00Z"},
        {"start": iso(now - timedelta(minutes=1)), "end": iso(now - timedelta(minutes=2))},
        {"start": iso(now + timedelta(days=1))},
    ):
        for path in ("records", "events", "reliability"):
            body = get(path, **params).json()
            assert body["clipped"] is True and body["start"] == body["end"], (path, params)
            assert body.get("total", 0) == 0 and body.get("events", []) == [], path
            assert body.get("records", 0) in (0, []), path
        r = get("export", **params)
        assert r.text == "" and r.headers["x-window-clipped"] == "true"
        assert r.headers["x-window-start"] == r.headers["x-window-end"]
    body = get("records", start=iso(now), end=iso(now)).json()
    assert body["clipped"] is False and body["total"] == 0  # empty as asked
    # RFC 3339 has them: the year 0000, a leap second
    assert get("records", start="0000-01-01T00:00:00Z").json()["clipped"] is True
    leap = (now - timedelta(days=1)).replace(hour=15, minute=59, second=0)
    body = get("records", start=leap.strftime("%Y-%m-%dT%H:%M:60-08:00"), end=iso(now)).json()
    assert body["start"] == iso(leap.replace(hour=23, second=59, microsecond=999999))
    # the extremes of date-time: no overflow, the latest there is
    body = get("records", start="0001-01-01T00:00:00+01:00", end="9999-12-31T23:59:59-01:00").json()
    assert body["clipped"] is True and body["end"].startswith("9999-12-31T23:59:59")
    assert body["total"] in (5, 6)


# ---- export ------------------------------------------------------------------------------------


def test_export_jsonl(world):
    client, _, _, first, tokens = world
    params = {
        "start": iso(first + timedelta(seconds=100)),
        "end": iso(first + timedelta(seconds=1300)),
        "format": "jsonl",
    }
    r = client.get(f"/api/v1/vehicles/{VEHICLE}/export", params=params, headers=auth(tokens["auditor"]))
    assert r.status_code == 200 and r.headers["content-type"].startswith("application/x-ndjson")
    assert r.headers["content-disposition"].startswith(f'attachment; filename="{VEHICLE}_')
    lines = r.text.splitlines()
    assert len(lines) == 1200
    records = [VehicleRecord.model_validate_json(line) for line in lines]
    assert [rec.t for rec in records] == [float(i) for i in range(100, 1300)]
    assert records[FAULT_AT - 100].mode.value == "MANUAL"


def test_export_csv(world):
    client, _, _, first, tokens = world
    params = {"start": iso(first), "end": iso(first + timedelta(seconds=N_RECORDS)), "format": "csv"}
    r = client.get(f"/api/v1/vehicles/{VEHICLE}/export", params=params, headers=auth(tokens["auditor"]))
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/csv")
    rows = list(csv.reader(io.StringIO(r.text)))
    assert tuple(rows[0]) == CSV_COLUMNS
    assert len(rows) == 1 + N_RECORDS
    row = dict(zip(rows[0], rows[11]))
    assert row["vehicle_id"] == VEHICLE and float(row["t"]) == 10.0 and row["mode"] == "AUTOMATIC"
    assert float(row["position.x"]) == 10.0 and row["position.hemisphere"] == "N"
    assert row["time"] == iso(first + timedelta(seconds=10))
    assert json.loads(row["scores"]) == {"odometry": 0.9}
    assert json.loads(row["sensors"]) == {"gnss": {"rate_hz": 5.0, "ok": True}}
    assert row["awareness_level"] == ""  # None -> empty cell
    assert float(row["command.commanded_speed_mps"]) == 3.0 and row["command.target_speed_mps"] == ""
    assert row["command.commanded_curvature"] == "0.002"


def test_export_bad_format_and_roles(world):
    client, _, _, _, tokens = world
    url = f"/api/v1/vehicles/{VEHICLE}/export"
    assert client.get(url, params={"format": "xml"}, headers=auth(tokens["auditor"])).status_code == 422
    for role in ("operator", "fleet", "admin"):
        r = client.get(url, headers=auth(tokens[role]))
        assert r.status_code == 403 and "needs auditor" in r.json()["detail"]


# ---- events and reliability ----------------------------------------------------------------------


def test_events(world):
    client, _, _, first, tokens = world
    h = auth(tokens["fleet"])
    url = f"/api/v1/vehicles/{VEHICLE}/events"
    r = client.get(url, headers=h, params={"start": iso(first), "page_size": 20})
    body = r.json()
    assert r.status_code == 200 and len(body["events"]) == 20 and body["has_more"] is True
    StoredEvent.model_validate(body["events"][0])
    r = client.get(url, headers=h, params={"start": iso(first), "page_size": 20, "page": 2})
    assert len(r.json()["events"]) == 11 and r.json()["has_more"] is False
    r = client.get(url, headers=h, params={"start": iso(first), "kind": "watchdog"})
    events = r.json()["events"]
    assert [e["kind"] for e in events] == ["watchdog"] and events[0]["level"] == "fault"
    r = client.get(url, headers=h, params={"start": iso(first), "kind": "watchdog,mode_change", "page_size": 100})
    assert len(r.json()["events"]) == 31
    assert client.get(url, headers=h, params={"kind": "a b"}).status_code == 422


def test_reliability(world):
    client, _, _, first, tokens = world
    r = client.get(
        f"/api/v1/vehicles/{VEHICLE}/reliability",
        headers=auth(tokens["operator"]),
        params={"start": iso(first), "end": iso(first + timedelta(seconds=N_RECORDS)), "t_hours": 2},
    )
    body = r.json()
    assert r.status_code == 200, body
    assert body["records"] == N_RECORDS and body["failures"] == 1 and body["open_failures"] == 0
    operating_h = (N_RECORDS - 60) / 3600
    repair_h = 59.7 / 3600  # fault at 1200.3 s, up again in the record of 1260 s
    assert body["operating_hours"] == pytest.approx(operating_h)
    assert body["repair_hours"] == pytest.approx(repair_h)
    assert body["mtbf_hours"] == pytest.approx(operating_h)
    assert body["mttr_hours"] == pytest.approx(repair_h)
    assert body["availability"] == pytest.approx(operating_h / (operating_h + repair_h))
    assert body["reliability"] == pytest.approx(pytest.importorskip("math").exp(-2 / operating_h))
    assert "AUTOMATIC" in body["definitions"]
    r = client.get(f"/api/v1/vehicles/{VEHICLE}/reliability", headers=auth(tokens["operator"]), params={"t_hours": 0})
    assert r.status_code == 422


# ---- users -------------------------------------------------------------------------------------


def test_users_admin_only(world):
    client, _, _, _, tokens = world
    h = auth(tokens["admin"])
    names = [u["name"] for u in client.get("/api/v1/users", headers=h).json()]
    assert names == sorted(ROLES)
    assert all("password" not in json.dumps(u) for u in client.get("/api/v1/users", headers=h).json())
    r = client.post("/api/v1/users", headers=h, json={"name": "carol", "role": "auditor", "password": "0123456789ab"})
    assert r.status_code == 201 and r.json()["role"] == "auditor"
    assert token_for(client, "carol", "0123456789ab")
    r = client.post("/api/v1/users", headers=h, json={"name": "carol", "role": "fleet", "password": "0123456789ab"})
    assert r.status_code == 409
    r = client.post("/api/v1/users", headers=h, json={"name": "dave", "role": "fleet", "password": "short"})
    assert r.status_code == 422 and "password" in r.json()["detail"] and "at least 10" in r.json()["detail"]
    r = client.post("/api/v1/users", headers=h, json={"name": "Eve!", "role": "fleet", "password": "0123456789ab"})
    assert r.status_code == 422
    r = client.post("/api/v1/users", headers=h, json={"name": "eve", "role": "root", "password": "0123456789ab"})
    assert r.status_code == 422
    for role in ("auditor", "operator", "fleet"):
        assert client.get("/api/v1/users", headers=auth(tokens[role])).status_code == 403
        assert (
            client.post(
                "/api/v1/users",
                headers=auth(tokens[role]),
                json={"name": "mallory", "role": "admin", "password": "0123456789ab"},
            ).status_code
            == 403
        )


# ---- roles, no writes, store down, documentation ----------------------------------------------

ENDPOINTS = {
    "/api/v1/vehicles": {"fleet", "auditor", "operator"},
    f"/api/v1/vehicles/{VEHICLE}/latest": {"fleet", "auditor", "operator"},
    f"/api/v1/vehicles/{VEHICLE}/records": {"auditor", "operator"},
    f"/api/v1/vehicles/{VEHICLE}/export": {"auditor"},
    f"/api/v1/vehicles/{VEHICLE}/events": {"auditor", "operator", "fleet"},
    f"/api/v1/vehicles/{VEHICLE}/reliability": {"auditor", "operator", "fleet"},
    "/api/v1/users": {"admin"},
}


def test_roles_matrix(world):
    client, _, _, _, tokens = world
    for path, allowed in ENDPOINTS.items():
        assert client.get(path).status_code == 401, path
        for role in ROLES:
            status = client.get(path, headers=auth(tokens[role])).status_code
            assert status == (200 if role in allowed else 403), (path, role, status)


def test_nothing_alters_records(world):
    client, app, _, _, tokens = world
    h = auth(tokens["admin"])
    for method in ("PUT", "DELETE", "PATCH", "POST"):
        for path in (
            f"/api/v1/vehicles/{VEHICLE}/records",
            f"/api/v1/vehicles/{VEHICLE}/latest",
            f"/api/v1/vehicles/{VEHICLE}/events",
        ):
            assert client.request(method, path, headers=h).status_code == 405, (method, path)
    schema = client.get("/openapi.json").json()
    writes = {(p, m) for p, ops in schema["paths"].items() for m in ops if m in ("put", "delete", "patch", "post")}
    # an API over a store alone: logging in and out, and the users; with a vehicle's bus the
    # operator's commands too, which alter no record (tests/test_api_commands.py)
    assert writes == {
        ("/api/v1/auth/token", "post"),
        ("/api/v1/auth/renew", "post"),
        ("/api/v1/auth/revoke", "post"),
        ("/api/v1/users", "post"),
        ("/api/v1/users/{name}", "delete"),
        ("/api/v1/users/{name}/role", "put"),
        ("/api/v1/users/{name}/password", "put"),
        ("/api/v1/users/{name}/disable", "post"),
        ("/api/v1/users/{name}/enable", "post"),
    }


def test_other_methods_get_405_and_allow(world):
    """Every method a path does not have: 405, with Allow listing exactly the path's methods (the
    schema's), whatever the path's first route is (/users has GET and POST)."""
    client, *_ = world
    paths = client.get("/openapi.json").json()["paths"]
    for path, ops in paths.items():
        url = path.replace("{vehicle_id}", VEHICLE)
        documented = {m.upper() for m in ops}
        for method in {"GET", "HEAD", "POST", "PUT", "PATCH", "DELETE", "OPTIONS", "TRACE"} - documented:
            r = client.request(method, url)
            assert r.status_code == 405, (method, path)
            assert set(r.headers["allow"].split(", ")) == documented, (method, path)
    assert client.options("/api/v1/users").headers["allow"] == "GET, POST"
    assert client.get("/api/v1/auth/token").headers["allow"] == "POST"
    assert client.options("/api/v1/nothing").status_code == 404


def test_login_form_is_what_its_schema_says(world):
    client, *_ = world
    url = "/api/v1/auth/token"
    form = {"username": "auditor", "password": PASSWORD}
    assert client.post(url, data=form).status_code == 200
    assert client.post(url, data={**form, "grant_type": "password"}).status_code == 200
    assert client.post(url, data={**form, "grant_type": "client_credentials"}).status_code == 422
    r = client.post(url, data={**form, "scope": "admin"})
    assert r.status_code == 422 and r.json()["errors"][0]["loc"] == ["body", "scope"]
    # the longest fields the schema allows, in 4-byte characters: a wrong password, not a refused form
    r = client.post(url, data={"username": "\U0001d57f" * 64, "password": "\U0001d57f" * 256, "grant_type": "password"})
    assert r.status_code == 401, r.text
    body = client.get("/openapi.json").json()["paths"][url]["post"]["requestBody"]["content"]
    schema = client.get("/openapi.json").json()["components"]["schemas"]["LoginForm"]
    assert body["application/x-www-form-urlencoded"]["schema"] == {"$ref": "#/components/schemas/LoginForm"}
    assert schema["additionalProperties"] is False and schema["required"] == ["username", "password"]


def test_errors_documented(world):
    client, *_ = world
    paths = client.get("/openapi.json").json()["paths"]
    for path in (
        "/api/v1/vehicles/{vehicle_id}/records",
        "/api/v1/vehicles/{vehicle_id}/export",
        "/api/v1/vehicles/{vehicle_id}/latest",
        "/api/v1/vehicles/{vehicle_id}/events",
        "/api/v1/vehicles/{vehicle_id}/reliability",
    ):
        assert {"200", "401", "403", "404", "422", "429", "503"} <= set(paths[path]["get"]["responses"]), path
    for path, ops in paths.items():
        for op in ops.values():
            assert {"403", "413", "429"} <= set(op["responses"]), path
            assert op["responses"]["429"]["headers"]["Retry-After"]["required"] is True, path
            if "401" in op["responses"]:
                assert op["responses"]["401"]["headers"]["WWW-Authenticate"]["required"] is True, path
    assert paths["/api/v1/users"]["post"]["requestBody"]["content"]["application/json"]["schema"] == {
        "$ref": "#/components/schemas/NewUser"
    }
    new_user = client.get("/openapi.json").json()["components"]["schemas"]["NewUser"]
    assert new_user["properties"]["password"]["minLength"] == 10  # auth.min_password_length
    assert paths["/api/v1/auth/token"]["post"]["requestBody"]["content"].keys() == {"application/x-www-form-urlencoded"}


class DownStore:
    """A store whose server is gone: every call raises StoreUnavailable."""

    def __init__(self, inner):
        self.inner = inner
        self.path = inner.path

    def now(self):
        return self.inner.now()

    def __getattr__(self, name):
        def fail(*_args, **_kwargs):
            raise StoreUnavailable("connection refused")

        return fail


def test_store_down_503(store):
    seed(store)
    app = create_app(store, api_settings(), VEHICLE_ID)
    add_role_users(store, app)
    client = TestClient(app)
    tokens = {role: token_for(client, role) for role in ROLES}
    down = TestClient(create_app(DownStore(store), api_settings(), VEHICLE_ID))
    r = down.get("/api/v1/health")
    assert r.status_code == 503 and r.json()["store"] == "unavailable"
    for path, allowed in ENDPOINTS.items():
        role = sorted(allowed)[0]
        r = down.get(path, headers=auth(tokens[role]))
        assert r.status_code == 503, path
        assert r.json()["detail"] == "the black box store is unavailable; retry later"
        assert r.headers["retry-after"] == "5"
    r = down.post("/api/v1/auth/token", data={"username": "auditor", "password": PASSWORD})
    assert r.status_code == 503


# ---- CLI: users --------------------------------------------------------------------------------


def test_cli_users(tmp_path, monkeypatch, capsys):
    from ares import cli

    db = str(tmp_path / "cli.sqlite")
    monkeypatch.setattr("sys.stdin", io.StringIO("a long password\na long password\n"))
    assert cli.main(["users", "add", "alice", "--role", "auditor", "--store", db]) == 0
    monkeypatch.setattr("sys.stdin", io.StringIO("one line password\n"))
    assert cli.main(["users", "add", "bob", "--role", "fleet", "--store", db]) == 0
    monkeypatch.setattr("sys.stdin", io.StringIO("a long password\nanother password\n"))
    assert cli.main(["users", "add", "carl", "--role", "fleet", "--store", db]) == 1
    monkeypatch.setattr("sys.stdin", io.StringIO("short\n"))
    assert cli.main(["users", "add", "carl", "--role", "fleet", "--store", db]) == 1
    monkeypatch.setattr("sys.stdin", io.StringIO("a long password\n"))
    assert cli.main(["users", "add", "alice", "--role", "admin", "--store", db]) == 1
    err = capsys.readouterr().err
    assert "differ" in err or "twice" in err
    assert "too short" in err and "already exists" in err
    assert cli.main(["users", "list", "--store", db, "--json"]) == 0
    users = json.loads(capsys.readouterr().out)["users"]
    assert [(u["name"], u["role"]) for u in users] == [("alice", "auditor"), ("bob", "fleet")]
    # the hash is a real argon2id hash that the API accepts
    from blackbox.register.store.sqlite_store import SqliteStore

    s = SqliteStore(db)
    app = create_app(s, api_settings(), VEHICLE_ID)
    assert token_for(TestClient(app), "bob", "one line password")
    assert s.get_user("alice").password_hash.startswith("$argon2id$")
    s.close()
