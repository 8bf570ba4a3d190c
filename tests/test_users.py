"""Accounts that can be taken back (issue 42): a token is only as good as its account now.

Against a real embedded store on a file and the real application: a deleted, disabled, demoted
or re-passworded user's token is refused, at renewal and on any route; a token signed with the
key but longer-lived than the rules, a revoked token id and a token of another vehicle are
refused; the admin's routes and `ares users` do the same changes; the store's file is its
owner's only.
"""

from __future__ import annotations

import io
import json
import os
import sqlite3
import stat
import time

import jwt
import pytest
from fastapi.testclient import TestClient

from blackbox.api import create_app
from blackbox.api.credentials import Tokens
from tests.helpers.api import (
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

LATEST = f"/api/v1/vehicles/{VEHICLE}/latest"
RENEW = "/api/v1/auth/renew"
NEW_PASSWORD = "another long passphrase"


@pytest.fixture
def api(tmp_path):
    """(client, app, store): the API over a seeded store, a user of every role."""
    store = open_test_store(tmp_path / "blackbox.sqlite")
    seed(store)
    app = create_app(store, api_settings(state_dir=str(tmp_path / "state")), VEHICLE_ID)
    add_role_users(store, app)
    yield TestClient(app), app, store
    store.close()


def refused(client: TestClient, token: str) -> list[str]:
    """The token tried on renewal and on a route: the details of the refusals (both must be 401)."""
    details = []
    for r in (client.post(RENEW, headers=auth(token)), client.get(LATEST, headers=auth(token))):
        assert r.status_code == 401, r.text
        assert r.headers["www-authenticate"] == "Bearer"
        details.append(r.json()["detail"])
    return details


def served(client: TestClient, token: str) -> None:
    assert client.get(LATEST, headers=auth(token)).status_code == 200
    assert client.post(RENEW, headers=auth(token)).status_code == 200


# ---- the account behind the token ---------------------------------------------------------------


def test_a_deleted_users_token_is_refused_at_renewal_and_on_any_route(api):
    client, _, store = api
    token = token_for(client, "fleet")
    renewed = client.post(RENEW, headers=auth(token)).json()["access_token"]
    served(client, token)
    r = client.delete("/api/v1/users/fleet", headers=auth(token_for(client, "admin")))
    assert r.status_code == 204 and store.get_user("fleet") is None
    for t in (token, renewed):  # the renewed one too: renewal gave no way around it
        assert refused(client, t) == ["this account is disabled or removed"] * 2
    assert client.post("/api/v1/auth/token", data={"username": "fleet", "password": PASSWORD}).status_code == 401


def test_a_disabled_users_token_is_refused_and_enabling_lets_them_log_in_again(api):
    client, _, store = api
    admin = auth(token_for(client, "admin"))
    token = token_for(client, "operator")
    r = client.post("/api/v1/users/operator/disable", headers=admin)
    assert r.status_code == 200 and r.json()["disabled"] is True and store.get_user("operator").disabled
    refused(client, token)
    assert client.post("/api/v1/auth/token", data={"username": "operator", "password": PASSWORD}).status_code == 401
    listed = {u["name"]: u["disabled"] for u in client.get("/api/v1/users", headers=admin).json()}
    assert listed["operator"] is True and listed["auditor"] is False
    r = client.post("/api/v1/users/operator/enable", headers=admin)
    assert r.status_code == 200 and r.json()["disabled"] is False
    refused(client, token)  # enabling again does not bring back the tokens of before
    served(client, token_for(client, "operator"))


def test_a_role_change_or_a_new_password_ends_the_tokens_held(api):
    client, _, _ = api
    admin = auth(token_for(client, "admin"))
    auditor = token_for(client, "auditor")
    r = client.put("/api/v1/users/auditor/role", headers=admin, json={"role": "fleet"})
    assert r.status_code == 200 and r.json()["role"] == "fleet"
    assert refused(client, auditor) == ["the account changed since this token was issued: log in again"] * 2
    fleet = token_for(client, "auditor")
    r = client.post("/api/v1/auth/token", data={"username": "auditor", "password": PASSWORD})
    assert r.json()["role"] == "fleet"
    r = client.put("/api/v1/users/auditor/password", headers=admin, json={"password": NEW_PASSWORD})
    assert r.status_code == 200
    refused(client, fleet)
    assert client.post("/api/v1/auth/token", data={"username": "auditor", "password": PASSWORD}).status_code == 401
    served(client, token_for(client, "auditor", NEW_PASSWORD))
    r = client.put("/api/v1/users/auditor/password", headers=admin, json={"password": "short"})
    assert r.status_code == 422 and "at least 10" in r.json()["detail"]


def test_the_admins_routes_answer_404_409_403_as_documented(api):
    client, _, store = api
    admin = auth(token_for(client, "admin"))
    for method, path, body in (
        ("DELETE", "/api/v1/users/nobody", None),
        ("POST", "/api/v1/users/nobody/disable", None),
        ("POST", "/api/v1/users/nobody/enable", None),
        ("PUT", "/api/v1/users/nobody/role", {"role": "fleet"}),
        ("PUT", "/api/v1/users/nobody/password", {"password": NEW_PASSWORD}),
    ):
        r = client.request(method, path, headers=admin, json=body)
        assert r.status_code == 404 and r.json()["detail"] == "no user 'nobody'", (method, path)
        r = client.request(method, path, headers=auth(token_for(client, "operator")), json=body)
        assert r.status_code == 403, (method, path)
    # an admin cannot lock themselves out: another admin can
    for method, path, body in (
        ("DELETE", "/api/v1/users/admin", None),
        ("POST", "/api/v1/users/admin/disable", None),
        ("PUT", "/api/v1/users/admin/role", {"role": "auditor"}),
    ):
        r = client.request(method, path, headers=admin, json=body)
        assert r.status_code == 409 and "their own account" in r.json()["detail"], (method, path)
    assert store.get_user("admin").role == "admin" and not store.get_user("admin").disabled
    # the same role again is no change: the tokens held stay good
    assert client.put("/api/v1/users/admin/role", headers=admin, json={"role": "admin"}).status_code == 200
    assert client.get("/api/v1/users", headers=admin).status_code == 200  # still the admin
    schema = client.get("/openapi.json").json()["paths"]
    for path, method in (
        ("/api/v1/users/{name}", "delete"),
        ("/api/v1/users/{name}/disable", "post"),
        ("/api/v1/users/{name}/role", "put"),
    ):
        assert {"401", "403", "404", "409", "422", "503"} <= set(schema[path][method]["responses"]), path


# ---- the token itself ---------------------------------------------------------------------------


def test_a_token_past_the_maximum_lifetime_is_refused_even_signed_with_the_key(api):
    client, app, store = api
    good = token_for(client, "auditor")
    claims = jwt.decode(good, options={"verify_signature": False})
    secret = app.state.services.tokens.secret
    ten_years = {**claims, "exp": claims["iat"] + 10 * 365 * 86400}
    from_the_future = {**claims, "iat": claims["iat"] + 3600, "exp": claims["iat"] + 3600 + 600}
    token = jwt.encode(ten_years, secret, algorithm="HS256")
    assert refused(client, token) == ["invalid token: a token lives at most 900 s"] * 2
    assert refused(client, jwt.encode(from_the_future, secret, algorithm="HS256")) == ["invalid token"] * 2
    within = jwt.encode({**claims, "exp": claims["iat"] + 900}, secret, algorithm="HS256")
    served(client, within)  # the rules' own lifetime is accepted


def test_a_revoked_token_id_is_refused_and_only_that_one(api):
    client, app, store = api
    first, second = token_for(client, "auditor"), token_for(client, "auditor")
    assert client.post("/api/v1/auth/revoke", headers=auth(first)).status_code == 204
    assert refused(client, first) == ["token revoked: log in again"] * 2
    served(client, second)
    jti = jwt.decode(first, options={"verify_signature": False})["jti"]
    assert store.token_revoked(jti) and not store.token_revoked("another id")
    # the revocation is the store's, not the process's: another API over the same file refuses it
    other = TestClient(create_app(store, app.state.services.settings, VEHICLE_ID))
    assert other.get(LATEST, headers=auth(first)).status_code == 401


def test_a_token_for_another_vehicle_is_refused(api, tmp_path):
    client, app, store = api
    settings = app.state.services.settings  # the same state directory: the same signing key
    other_vehicle = TestClient(create_app(store, settings, "shuttle02"))
    theirs = token_for(other_vehicle, "auditor")
    assert other_vehicle.get(LATEST, headers=auth(theirs)).status_code == 200
    assert refused(client, theirs) == ["this token is for another vehicle's black box"] * 2
    claims = jwt.decode(token_for(client, "auditor"), options={"verify_signature": False})
    no_audience = jwt.encode({k: v for k, v in claims.items() if k != "aud"}, app.state.services.tokens.secret)
    assert refused(client, no_audience) == ["invalid token"] * 2


def test_tokens_without_an_account_check_still_check_signature_lifetime_and_audience(api):
    _, app, _ = api
    services = app.state.services
    tokens = Tokens(services.settings.auth, services.tokens.secret, VEHICLE_ID)
    token, ttl = tokens.issue("auditor", "auditor", 3)
    claims = tokens.verify(token)
    assert (claims.name, claims.role, claims.generation, ttl) == ("auditor", "auditor", 3, 900)
    assert claims.expires <= time.time() + 900


# ---- ares users ---------------------------------------------------------------------------------


def test_cli_users_role_passwd_disable_enable_delete(api, monkeypatch, capsys):
    """`ares users` on the file a running API serves: its changes refuse that API's tokens."""
    from ares import cli

    client, _, store = api
    db = str(store.path)
    tokens = {name: token_for(client, name) for name in ("fleet", "operator", "auditor")}

    assert cli.main(["users", "role", "fleet", "auditor", "--store", db]) == 0
    refused(client, tokens["fleet"])
    monkeypatch.setattr("sys.stdin", io.StringIO(f"{NEW_PASSWORD}\n"))
    assert cli.main(["users", "passwd", "operator", "--store", db]) == 0
    refused(client, tokens["operator"])
    served(client, token_for(client, "operator", NEW_PASSWORD))
    assert cli.main(["users", "disable", "auditor", "--store", db]) == 0
    refused(client, tokens["auditor"])
    assert cli.main(["users", "list", "--store", db, "--json"]) == 0
    capsys.readouterr()
    assert cli.main(["users", "list", "--store", db, "--json"]) == 0
    listed = {u["name"]: (u["role"], u["disabled"]) for u in json.loads(capsys.readouterr().out)["users"]}
    assert listed["fleet"] == ("auditor", False) and listed["auditor"] == ("auditor", True)
    assert cli.main(["users", "enable", "auditor", "--store", db]) == 0
    served(client, token_for(client, "auditor"))
    assert cli.main(["users", "delete", "fleet", "--store", db]) == 0
    assert store.get_user("fleet") is None
    assert cli.main(["users", "delete", "fleet", "--store", db]) == 1
    monkeypatch.setattr("sys.stdin", io.StringIO("short\n"))
    assert cli.main(["users", "passwd", "operator", "--store", db]) == 1
    err = capsys.readouterr().err
    assert "no user 'fleet'" in err and "too short" in err


# ---- the store's file ---------------------------------------------------------------------------


def test_the_sqlite_store_file_is_its_owners_only(tmp_path):
    old_umask = os.umask(0o022)  # the usual one: files 0644 unless the store says otherwise
    fresh = open_test_store(tmp_path / "fresh" / "blackbox.sqlite")
    try:
        seed(fresh)
        loose = tmp_path / "loose.sqlite"
        sqlite3.connect(loose).close()  # made by another tool, with the umask's mode
        assert stat.S_IMODE(loose.stat().st_mode) == 0o644
        opened = open_test_store(loose)
        opened.list_users()
        opened.close()
        files = [*(tmp_path / "fresh").iterdir(), loose]
        # the store's write-ahead log and shared memory beside it (SQLite gives them the file's
        # mode) as well as the file
        assert {f.name for f in files} == {
            "blackbox.sqlite",
            "blackbox.sqlite-wal",
            "blackbox.sqlite-shm",
            "loose.sqlite",
        }
        for f in files:
            assert stat.S_IMODE(f.stat().st_mode) == 0o600, f
    finally:
        fresh.close()
        os.umask(old_umask)


def test_a_store_file_from_before_the_account_columns_is_upgraded(tmp_path):
    path = tmp_path / "old.sqlite"
    conn = sqlite3.connect(path)
    conn.executescript(
        "CREATE TABLE users (name TEXT PRIMARY KEY, role TEXT NOT NULL, password_hash TEXT NOT NULL, "
        "created TEXT NOT NULL);"
        "INSERT INTO users VALUES ('ana', 'auditor', 'h', '2026-01-01T00:00:00+00:00');"
    )
    conn.close()
    store = open_test_store(path)
    try:
        ana = store.get_user("ana")
        assert (ana.role, ana.disabled, ana.generation) == ("auditor", False, 0)
        assert store.delete_user("ana") and store.get_user("ana") is None and not store.delete_user("ana")
    finally:
        store.close()


def test_a_change_by_another_process_is_seen_within_account_cache_s(api):
    """`ares users` (or another API process) changes the store behind this API's back: an account
    this API found allowing a token a moment ago is trusted for account_cache_s, then asked again."""
    from blackbox.api.credentials import set_disabled

    client, app, store = api
    accounts = app.state.services.tokens.accounts
    clock = [1000.0]
    accounts.now = lambda: clock[0]
    token = token_for(client, "auditor")
    served(client, token)  # found allowing it: trusted for account_cache_s (1 s)
    set_disabled(store, "auditor", True)  # as `ares users disable auditor` does, on the same file
    clock[0] += 0.5
    assert client.get(LATEST, headers=auth(token)).status_code == 200
    clock[0] += 0.6
    refused(client, token)
