"""Login limits beyond one address (issue 42): guesses at one account spread over many
addresses lock that account's logins; the blacklist and the account locks survive a restart
of the API (kept in its state directory)."""

from __future__ import annotations

from fastapi.testclient import TestClient

from blackbox.api import ApiSettings, create_app
from blackbox.api.security import BAN_FILE, BlacklistSettings, Guard, RateLimitSettings
from tests.helpers.api import PASSWORD, add_role_users, api_settings, open_test_store, seed, token_for

VEHICLE_ID = "shuttle01"
LOGIN = "/api/v1/auth/token"


def login(client: TestClient, name: str, password: str) -> int:
    return client.post(LOGIN, data={"username": name, "password": password}).status_code


def production_login_limits(**blacklist) -> ApiSettings:
    """The test settings but with the production failed-login limits (what the finding met)."""
    defaults = BlacklistSettings()
    return api_settings(
        rate_limit={"token_per_s": RateLimitSettings().token_per_s, "token_burst": RateLimitSettings().token_burst},
        blacklist={
            "failed_logins": defaults.failed_logins,
            "account_failed_logins": defaults.account_failed_logins,
            **blacklist,
        },
    )


def test_guesses_spread_over_addresses_lock_the_account(tmp_path):
    store = open_test_store(tmp_path / "blackbox.sqlite")
    seed(store)
    try:
        app = create_app(store, production_login_limits(), VEHICLE_ID)
        add_role_users(store, app)
        # 10 addresses, 4 guesses each: under every address's burst and failure count
        statuses = []
        for host in range(10):
            guesser = TestClient(app, client=(f"10.0.0.{host + 1}", 40000))
            statuses += [login(guesser, "admin", f"guess{host}-{i}") for i in range(4)]
        failed = BlacklistSettings().account_failed_logins
        assert statuses[:failed] == [401] * failed
        assert set(statuses[failed:]) == {429}, statuses
        # locked: even the right password, from an address that never guessed, until the lock ends
        fresh = TestClient(app, client=("10.0.1.1", 40000))
        r = fresh.post(LOGIN, data={"username": "admin", "password": PASSWORD})
        assert r.status_code == 429 and "failed logins for this user" in r.json()["detail"]
        assert 0 < int(r.headers["retry-after"]) <= BlacklistSettings().account_lock_s
        # another account is not affected
        assert token_for(fresh, "auditor")
    finally:
        store.close()


def test_bans_and_locks_survive_a_restart(tmp_path):
    store = open_test_store(tmp_path / "blackbox.sqlite")
    seed(store)
    try:
        settings = production_login_limits(account_failed_logins=3)
        first = create_app(store, settings, VEHICLE_ID)
        add_role_users(store, first)
        banned = TestClient(first, client=("10.0.2.1", 40000))
        for i in range(15):  # a password-guessing burst from one address: blacklisted
            login(banned, "operator", f"guess{i}")
        assert banned.get("/api/v1/health").status_code == 403
        assert (tmp_path / BAN_FILE).exists()

        restarted = create_app(store, settings, VEHICLE_ID)  # a new process's state: only the file carries over
        assert TestClient(restarted, client=("10.0.2.1", 40000)).get("/api/v1/health").status_code == 403
        other = TestClient(restarted, client=("10.0.2.2", 40000))
        assert other.get("/api/v1/health").status_code == 200
        assert login(other, "operator", PASSWORD) == 429  # the name locked by the burst's failures
        assert token_for(other, "auditor")
    finally:
        store.close()


def test_the_ban_file_keeps_what_still_holds(tmp_path):
    """Wall time carries a ban across a restart; one that ended while the API was down is gone,
    and an unreadable file starts the API with no bans rather than not at all."""
    limits, cfg = RateLimitSettings(), BlacklistSettings(failed_logins=1, duration_s=100, account_lock_s=50)
    cfg = cfg.model_copy(update={"account_failed_logins": 1})
    path = tmp_path / BAN_FILE
    mono, wall = [1000.0], [1_700_000_000.0]
    guard = Guard(limits, cfg, now=lambda: mono[0], ban_file=path, wall=lambda: wall[0])
    assert guard.login_failed("10.0.3.1") is not None
    assert guard.account_failed("admin") is not None

    wall[0] += 30  # restarted 30 s later, on a monotonic clock that began anew
    again = Guard(limits, cfg, now=lambda: 5.0, ban_file=path, wall=lambda: wall[0])
    assert 69 < again.blacklisted("10.0.3.1") <= 70
    locked = again.account_locked("admin")
    assert locked is not None and locked.retry_after_s == 21

    wall[0] += 30  # the account's lock (50 s) ended while down, the address's (100 s) not
    later = Guard(limits, cfg, now=lambda: 7.0, ban_file=path, wall=lambda: wall[0])
    assert later.blacklisted("10.0.3.1") is not None and later.account_locked("admin") is None

    path.write_text("{not json")
    assert Guard(limits, cfg, ban_file=path).blacklist == {}
