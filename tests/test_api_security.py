"""REST API security: tokens, rate limits, the IP blacklist, headers, CORS, TLS and a real
uvicorn server over HTTPS."""

from __future__ import annotations

import base64
import json
import ssl
import time
from datetime import timedelta

import httpx
import jwt
import pydantic
import pytest
from fastapi.testclient import TestClient

from ares.core.localhost import free_port
from blackbox.api import ApiSettings, create_app
from blackbox.api.credentials import Argon2Settings, Passwords, Tokens, add_user
from blackbox.api.security import BlacklistSettings, Guard, RateLimitSettings
from tests.helpers.api import (
    PASSWORD,
    VEHICLE,
    add_role_users,
    api_settings,
    auth,
    open_test_store,
    seed,
    start_api_process,
    stop_api_process,
    token_for,
    wait_serving,
)

HEADERS = {
    "strict-transport-security": "max-age=31536000; includeSubDomains",
    "x-content-type-options": "nosniff",
    "x-frame-options": "DENY",
    "referrer-policy": "no-referrer",
    "content-security-policy": "default-src 'none'; frame-ancestors 'none'",
    "cache-control": "no-store",
}

VEHICLE_ID = "shuttle01"  # the stack's own (its API events are this vehicle's)


@pytest.fixture
def store(tmp_path):
    s = open_test_store(tmp_path / "blackbox.sqlite")
    seed(s)
    yield s
    s.close()


def make(store, **overrides):
    app = create_app(store, api_settings(**overrides), VEHICLE_ID)
    add_role_users(store, app)
    return app, TestClient(app)


def b64(data: dict) -> str:
    return base64.urlsafe_b64encode(json.dumps(data).encode()).rstrip(b"=").decode()


def blacklist_events(store):
    now = store.now()
    return store.events("shuttle01", now - timedelta(minutes=5), now + timedelta(minutes=5), kinds=["ip_blacklisted"])


# ---- tokens ------------------------------------------------------------------------------------


def test_bad_tokens_401(store):
    app, client = make(store)
    good = token_for(client, "auditor")
    url = f"/api/v1/vehicles/{VEHICLE}/latest"
    assert client.get(url, headers=auth(good)).status_code == 200
    header, payload, signature = good.split(".")
    claims = jwt.decode(good, options={"verify_signature": False})
    secret, cfg = app.state.services.tokens.secret, app.state.services.settings.auth

    long_ago = Tokens(cfg, secret, VEHICLE_ID, now=lambda: time.time() - cfg.token_ttl_s - 5)
    expired = long_ago.issue("auditor", "auditor", 0)[0]
    tampered = ".".join([header, b64({**claims, "role": "admin", "sub": "admin"}), signature])
    alg_none = ".".join([b64({"alg": "none", "typ": "JWT"}), b64(claims), ""])
    wrong_key = jwt.encode(
        claims, "another key of the same length, sixty-four bytes long, exactly!!", algorithm="HS256"
    )
    other_alg = jwt.encode(claims, secret, algorithm="HS512")  # right key, algorithm not accepted
    no_exp = jwt.encode({k: v for k, v in claims.items() if k != "exp"}, secret, algorithm="HS256")
    bad_role = jwt.encode({**claims, "role": "root"}, secret, algorithm="HS256")
    other_issuer = jwt.encode({**claims, "iss": "elsewhere"}, secret, algorithm="HS256")
    cases = {
        "expired": expired,
        "tampered": tampered,
        "alg none": alg_none,
        "wrong key": wrong_key,
        "HS512": other_alg,
        "no exp": no_exp,
        "bad role": bad_role,
        "issuer": other_issuer,
        "garbage": "not.a.token",
        "huge": "a" * 5000,
    }
    for name, token in cases.items():
        r = client.get(url, headers=auth(token))
        assert r.status_code == 401, name
        assert r.headers["www-authenticate"] == "Bearer", name
        assert r.json()["detail"] in (
            "invalid token",
            "malformed token",
            "token expired: get a new one at /api/v1/auth/token",
        ), name
        assert client.post("/api/v1/auth/renew", headers=auth(token)).status_code == 401, name
    assert client.get(url, headers=auth(expired)).json()["detail"].startswith("token expired")
    assert client.get(url, headers={"Authorization": "Basic dXNlcjpwYXNz"}).status_code == 401
    assert client.get(url).status_code == 401


def test_password_hash_is_maintained(store):
    weak = Passwords(Argon2Settings(time_cost=1, memory_kib=64, parallelism=1))
    add_user(store, weak, "olduser", "fleet", PASSWORD, 10)
    before = store.get_user("olduser").password_hash
    app, client = make(store, auth={"argon2": {"time_cost": 2, "memory_kib": 128, "parallelism": 1}})
    token_for(client, "olduser")
    after = store.get_user("olduser").password_hash
    assert after != before and "m=128,t=2,p=1" in after
    token_for(client, "olduser")  # still the same password
    assert store.get_user("olduser").password_hash == after  # no needless re-hash


# ---- rate limits and blacklist -----------------------------------------------------------------


def test_password_guessing_burst_blacklists(store):
    app, client = make(
        store, rate_limit={"token_per_s": 0.05, "token_burst": 5}, blacklist={"failed_logins": 10, "duration_s": 600}
    )
    statuses = [
        client.post("/api/v1/auth/token", data={"username": "admin", "password": f"guess{i}"}).status_code
        for i in range(15)
    ]
    assert statuses == [401] * 5 + [429] * 4 + [403] * 6
    # blacklisted: everything from that address is refused, even the right password and /health
    assert client.post("/api/v1/auth/token", data={"username": "admin", "password": PASSWORD}).status_code == 403
    r = client.get("/api/v1/health")
    assert r.status_code == 403 and "blacklisted" in r.json()["detail"]
    assert 0 < int(r.headers["retry-after"]) <= 600
    events = blacklist_events(store)
    assert len(events) == 1
    event = events[0]
    assert event["source"] == "api" and event["kind"] == "ip_blacklisted" and event["level"] == "warning"
    assert event["data"]["ip"] == "testclient" and "failed logins" in event["data"]["reason"]
    # another address is not affected
    other = TestClient(app, client=("10.1.2.3", 40000))
    assert other.get("/api/v1/health").status_code == 200
    assert token_for(other, "auditor")


def test_429_has_retry_after(store):
    _, client = make(store, rate_limit={"token_per_s": 0.05, "token_burst": 2})
    for _ in range(2):
        client.post("/api/v1/auth/token", data={"username": "fleet", "password": "wrong"})
    r = client.post("/api/v1/auth/token", data={"username": "fleet", "password": PASSWORD})
    assert r.status_code == 429 and int(r.headers["retry-after"]) >= 1 and "login attempts" in r.json()["detail"]


def test_client_rate_limit_then_flood_blacklist(store):
    app, client = make(
        store,
        rate_limit={"client_per_s": 2, "client_burst": 5},
        blacklist={"abuse_requests_per_s": 4, "abuse_window_s": 5},
    )
    statuses = [client.get("/api/v1/health").status_code for _ in range(25)]
    assert statuses[:5] == [200] * 5
    assert 429 in statuses
    assert statuses[-1] == 403  # kept hammering after its 429s: > 4 req/s over 5 s
    assert "requests/s" in blacklist_events(store)[0]["data"]["reason"]


def test_guard_clock():
    now = [1000.0]
    guard = Guard(
        RateLimitSettings(client_per_s=1, client_burst=2, token_per_s=0.1, token_burst=1),
        BlacklistSettings(
            failed_logins=3, failed_logins_window_s=60, duration_s=100, abuse_requests_per_s=50, abuse_window_s=10
        ),
        now=lambda: now[0],
    )
    assert guard.admit("a") is None and guard.admit("a") is None
    assert guard.admit("a").status == 429
    now[0] += 1.0
    assert guard.admit("a") is None  # refilled one token
    # failed logins spread over more than the window do not add up
    for _ in range(2):
        assert guard.login_failed("b") is None
    now[0] += 61
    assert guard.login_failed("b") is None and guard.login_failed("b") is None
    verdict = guard.login_failed("b")
    assert verdict.status == 403 and verdict.newly_blacklisted
    assert guard.admit("b").status == 403 and guard.admit("b").newly_blacklisted is None
    now[0] += 101
    assert guard.admit("b") is None  # the blacklisting expires


def test_steady_client_is_never_blacklisted_but_abnormal_flows_are():
    """The production defaults, on a manual clock: a client at a steady 30 requests/s (also when
    they come in bunches, 30 at the top of each second) is served for 5 minutes without one 429,
    while a flood and a burst of failed logins from other addresses are still blacklisted."""
    cfg = ApiSettings()
    now = [1000.0]
    guard = Guard(cfg.rate_limit, cfg.blacklist, now=lambda: now[0])
    for ip, offsets in (
        ("10.0.0.1", [i / 30 for i in range(30)]),  # evenly spread
        ("10.0.0.2", [i * 1e-4 for i in range(30)]),
    ):  # 30 back to back each second
        start = now[0]
        for second in range(300):
            for dt in offsets:
                now[0] = start + second + dt
                assert guard.admit(ip) is None, (ip, second)
        now[0] = start + 300
        assert guard.blacklisted(ip) is None
    # a flood: 150 requests/s from another address is blacklisted within the abuse window
    verdicts = []
    for _ in range(150 * 10):
        now[0] += 1 / 150
        verdicts.append(guard.admit("10.0.0.3"))
    assert any(v is not None and v.newly_blacklisted for v in verdicts) and guard.blacklisted("10.0.0.3")
    # a burst of failed logins, one a second, is blacklisted (the ones refused with 429 count too)
    for _ in range(cfg.blacklist.failed_logins):
        now[0] += 1.0
        assert guard.blacklisted("10.0.0.4") is None
        if guard.admit("10.0.0.4", login=True) is None:
            guard.login_failed("10.0.0.4")  # what the login handler does on a wrong password
    assert guard.blacklisted("10.0.0.4")
    # the steady clients are untouched by the others' blacklisting
    assert guard.admit("10.0.0.1") is None and guard.admit("10.0.0.2") is None


def test_rate_limit_and_blacklist_must_agree():
    """A client that keeps to its rate limit must never reach the abuse threshold: settings where
    it could are refused, naming both sections."""
    with pytest.raises(ValueError, match="rate_limit and blacklist disagree"):
        ApiSettings.model_validate({"rate_limit": {"client_per_s": 200}})
    with pytest.raises(ValueError, match="rate_limit and blacklist disagree"):
        ApiSettings.model_validate({"blacklist": {"abuse_requests_per_s": 40}})
    ApiSettings.model_validate({"rate_limit": {"client_per_s": 90}})  # 100 + 90 * 10 <= 100 * 10


# ---- headers, CORS, body size --------------------------------------------------------------------


def test_security_headers_everywhere(store):
    _, client = make(store, rate_limit={"client_per_s": 1, "client_burst": 6})
    token = token_for(client, "auditor")
    responses = [
        client.get("/api/v1/health"),  # 200
        client.get(f"/api/v1/vehicles/{VEHICLE}/latest"),  # 401
        client.get("/api/v1/nothing"),  # 404
        client.get(f"/api/v1/vehicles/{VEHICLE}/records", params={"page": 0}, headers=auth(token)),  # 422
        client.get("/openapi.json"),
    ]
    responses += [client.get("/api/v1/health") for _ in range(3)]  # ... 429
    assert {r.status_code for r in responses} == {200, 401, 404, 422, 429}
    for r in responses:
        for name, value in HEADERS.items():
            assert r.headers.get(name) == value, (r.status_code, name)


def test_docs_off_by_default(store):
    _, client = make(store)
    assert client.get("/docs").status_code == 404 and client.get("/redoc").status_code == 404
    assert client.get("/openapi.json").status_code == 200


def test_cors_closed_unless_configured(store):
    _, client = make(store)
    origin = {"Origin": "https://evil.example"}
    r = client.get("/api/v1/health", headers=origin)
    assert r.status_code == 200 and "access-control-allow-origin" not in r.headers
    r = client.options(
        f"/api/v1/vehicles/{VEHICLE}/latest",
        headers={**origin, "Access-Control-Request-Method": "GET", "Access-Control-Request-Headers": "authorization"},
    )
    assert r.status_code == 405 and "access-control-allow-origin" not in r.headers

    _, client = make(store, cors_origins=["https://fleet.example"])
    r = client.get("/api/v1/health", headers={"Origin": "https://fleet.example"})
    assert r.headers["access-control-allow-origin"] == "https://fleet.example"
    r = client.get("/api/v1/health", headers=origin)
    assert "access-control-allow-origin" not in r.headers
    r = client.options("/api/v1/health", headers={**origin, "Access-Control-Request-Method": "GET"})
    assert r.status_code == 400 and "access-control-allow-origin" not in r.headers


def test_body_size_bounded(store):
    _, client = make(store)
    h = auth(token_for(client, "admin"))
    r = client.post("/api/v1/users", headers=h, json={"name": "big", "role": "fleet", "password": "x" * 20000})
    assert r.status_code == 413
    r = client.post("/api/v1/users", headers=h, json={"name": "big", "role": "fleet", "password": "x" * 300})
    assert r.status_code == 422  # within the body limit, over the field's bound
    r = client.post(
        "/api/v1/users", headers=h, json={"name": "big", "role": "fleet", "password": "0123456789", "is_root": True}
    )
    assert r.status_code == 422  # unknown fields are refused


# ---- TLS ---------------------------------------------------------------------------------------


def test_self_signed_certificate_reused(tmp_path):
    from cryptography import x509

    from blackbox.api.tls import self_signed

    cert, key = self_signed(tmp_path, ["localhost", "127.0.0.1"])
    assert oct(key.stat().st_mode & 0o777) == "0o600"
    pem = cert.read_bytes()
    assert self_signed(tmp_path, ["localhost", "127.0.0.1"])[0].read_bytes() == pem  # reused
    names = x509.load_pem_x509_certificate(pem).extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    assert "localhost" in names.get_values_for_type(x509.DNSName)
    assert self_signed(tmp_path, ["localhost", "127.0.0.1", "shuttle.local"])[0].read_bytes() != pem  # new names
    key.write_text("garbage")
    assert self_signed(tmp_path, ["localhost", "127.0.0.1", "shuttle.local"])[1].read_text() != "garbage"


@pytest.mark.timeout(60)
def test_real_uvicorn_over_https(tmp_path):
    db = tmp_path / "blackbox.sqlite"
    s = open_test_store(db)
    seed(s)
    add_user(
        s, Passwords(Argon2Settings(time_cost=1, memory_kib=64, parallelism=1)), "auditor", "auditor", PASSWORD, 10
    )
    s.close()
    port = free_port()
    server = start_api_process(tmp_path, db, port)
    try:
        wait_serving(server, port)
        cert = tmp_path / "state" / "tls" / "api_cert.pem"
        assert cert.exists() and (tmp_path / "state" / "api_secret").exists()
        tls = ssl.create_default_context(cafile=str(cert))
        for host in ("127.0.0.1", "localhost"):
            r = httpx.get(f"https://{host}:{port}/api/v1/health", verify=tls, timeout=5)
            assert r.status_code == 200 and r.json()["status"] == "ok"
            assert r.headers["strict-transport-security"].startswith("max-age=")
            assert "server" not in r.headers
        with httpx.Client(base_url=f"https://127.0.0.1:{port}/api/v1", verify=tls, timeout=5) as client:
            token = client.post("/auth/token", data={"username": "auditor", "password": PASSWORD}).json()[
                "access_token"
            ]
            r = client.get(f"/vehicles/{VEHICLE}/latest", headers=auth(token))
            assert r.status_code == 200 and r.json()["vehicle_id"] == VEHICLE
            r = client.get(f"/vehicles/{VEHICLE}/export", params={"format": "csv"}, headers=auth(token))
            assert r.status_code == 200 and r.text.count("\n") == 1 + 1800
        # without trusting that certificate the handshake fails
        with pytest.raises(httpx.ConnectError):
            httpx.get(f"https://127.0.0.1:{port}/api/v1/health", timeout=5)
        # plain HTTP on the HTTPS port gets no answer
        with pytest.raises(httpx.TransportError):
            httpx.get(f"http://127.0.0.1:{port}/api/v1/health", timeout=5)
        pem = cert.read_bytes()
    finally:
        stop_api_process(server)

    # a second start reuses the certificate; plain HTTP only with the explicit flag
    port2 = free_port()
    plain = start_api_process(tmp_path, db, port2, "--insecure-http")
    try:
        wait_serving(plain, port2)
        assert cert.read_bytes() == pem
        r = httpx.get(f"http://127.0.0.1:{port2}/api/v1/health", timeout=5)
        assert r.status_code == 200
        with pytest.raises(httpx.TransportError):
            httpx.get(
                f"https://127.0.0.1:{port2}/api/v1/health",
                verify=ssl.create_default_context(cafile=str(cert)),
                timeout=5,
            )
    finally:
        stop_api_process(plain)


def test_the_signing_key_from_a_secret_file(tmp_path):
    """A deployment hands the key over as a compose secret (api.auth.secret_file): it beats the
    environment and the state directory; a short or missing file is a clear error."""
    from blackbox.api.credentials import AuthSettings, load_secret

    key_file = tmp_path / "api_signing_key"
    key_file.write_text("k" * 64 + "\n")
    assert load_secret(AuthSettings(secret_file=str(key_file)), tmp_path / "state") == b"k" * 64
    assert not (tmp_path / "state").exists()  # nothing made beside it
    key_file.write_text("short")
    with pytest.raises(ValueError, match="too short"):
        load_secret(AuthSettings(secret_file=str(key_file)), tmp_path)
    with pytest.raises(ValueError, match="no-such-key"):
        load_secret(AuthSettings(secret_file=str(tmp_path / "no-such-key")), tmp_path)


def test_mongo_credentials_from_a_secret_file(tmp_path):
    from blackbox.register.store.mongo_store import MongoStore
    from blackbox.register.store.record_store import StoreSettings

    with pytest.raises(pydantic.ValidationError, match="mongo_user and mongo_password_file"):
        StoreSettings(mongo_user="ares")
    (tmp_path / "mongo_password").write_text("s3cret\n")
    settings = StoreSettings(mongo_user="ares", mongo_password_file=str(tmp_path / "mongo_password"))
    store = MongoStore("mongodb://127.0.0.1:1/", settings=settings)  # connects lazily: nothing is reached
    try:
        credentials = store._client.options.pool_options._credentials  # pymongo has no public accessor
        assert (credentials.username, credentials.password, credentials.source) == ("ares", "s3cret", "admin")
    finally:
        store.close()
    missing = StoreSettings(mongo_user="ares", mongo_password_file=str(tmp_path / "absent"))
    with pytest.raises(ValueError, match="absent"):
        MongoStore("mongodb://127.0.0.1:1/", settings=missing)
