"""The vehicle router's per-process access control (ares/deploy/local_acl.py) on a real router
(eclipse-zenoh in router mode, default deny, each process logged in as its own name): a declared
key is delivered, a key outside the process's contract is not (judged by a declared key sent after
it over the same link), and the supervisor sees the processes' liveliness tokens."""

from __future__ import annotations

import json
import time

import pytest
import zenoh

from ares.core import config
from ares.core.localhost import free_port
from ares.deploy import local_acl, pki
from ares.deploy.router import open_router

USERS = ("api", "blackbox", "supervisor", "observer")


def _router_config(port: int, dictionary: str) -> dict:
    cfg = config.core_defaults()
    ids = local_acl.rule_ids(cfg)
    return {
        "mode": "router",
        "listen": {"endpoints": [f"tcp/127.0.0.1:{port}"]},
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
        "transport": {"auth": {"usrpwd": {"dictionary_file": dictionary}}},
        "access_control": {
            "enabled": True,
            "default_permission": "deny",
            "rules": local_acl.rules(cfg),
            "subjects": [{"id": p, "link_protocols": ["tcp"], "usernames": [p]} for p in ids],
            "policies": [{"id": p, "rules": ids[p], "subjects": [p]} for p in ids],
        },
    }


def _client(port: int, user: str, password: str) -> zenoh.Session:
    cfg = {
        "mode": "client",
        "connect": {"endpoints": [f"tcp/127.0.0.1:{port}"]},
        "scouting": {"multicast": {"enabled": False}},
        "transport": {"auth": {"usrpwd": {"user": user, "password": password}}},
    }
    return zenoh.open(zenoh.Config.from_json5(json.dumps(cfg)))


def _wait_for(check, timeout_s: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if check():
            return True
        time.sleep(0.05)
    return False


@pytest.fixture
def bus(tmp_path):
    passwords = {u: f"{u}-password" for u in USERS}
    pki.write_users(tmp_path / "users", passwords)
    port = free_port()
    sessions = [open_router(_router_config(port, str(tmp_path / "users")))]
    for user in USERS:
        sessions.append(_client(port, user, passwords[user]))
    yield dict(zip(USERS, sessions[1:]))
    for session in reversed(sessions):
        session.close()


def test_a_declared_key_is_delivered_and_an_undeclared_one_is_not(bus):
    allowed = local_acl.allowed_topics(config.core_defaults())
    outside = sorted(allowed["blackbox"]["subscribe"] - allowed["api"]["put"] - {"events"})
    assert "dbw/car_state" in outside  # the recorder reads it; the API may not forge it
    seen: list[tuple[str, bytes]] = []
    for topic in ("events", "dbw/car_state"):
        bus["blackbox"].declare_subscriber(
            f"ares/v1/{topic}", lambda s: seen.append((str(s.key_expr), s.payload.to_bytes()))
        )

    def delivered(tag: bytes) -> bool:
        bus["api"].put("ares/v1/events", tag)
        return ("ares/v1/events", tag) in seen

    assert _wait_for(lambda: delivered(b"first"))
    for n in range(20):  # more than the first samples a publisher sends before it hears the subscribers
        bus["api"].put("ares/v1/events", b"n%d" % n)
    bus["api"].put("ares/v1/dbw/car_state", b"forged")  # outside its contract
    bus["api"].put("ares/v1/events", b"after")  # the same link, sent after it
    assert _wait_for(lambda: ("ares/v1/events", b"after") in seen)
    assert all(("ares/v1/events", b"n%d" % n) in seen for n in range(20))
    assert all(payload != b"forged" for _, payload in seen)


def test_the_supervisor_sees_the_processes_liveliness(bus):
    alive: list[str] = []
    bus["supervisor"].liveliness().declare_subscriber(
        "ares/v1/alive/*", lambda s: alive.append(str(s.key_expr)), history=True
    )
    token = bus["api"].liveliness().declare_token("ares/v1/alive/api")
    forged = bus["api"].liveliness().declare_token("ares/v1/alive/mission_manager")  # another's name: refused
    own = bus["blackbox"].liveliness().declare_token("ares/v1/alive/blackbox")  # declared after it
    assert _wait_for(lambda: "ares/v1/alive/api" in alive and "ares/v1/alive/blackbox" in alive)

    def answered() -> list[str]:
        replies = bus["supervisor"].liveliness().get("ares/v1/alive/*", timeout=2.0)
        return sorted(str(r.ok.key_expr) for r in replies if r.ok is not None)

    # asked again when a loaded machine lets the query lapse before the router's answer (seen once: [])
    assert _wait_for(lambda: answered() == ["ares/v1/alive/api", "ares/v1/alive/blackbox"], 20), answered()
    assert "ares/v1/alive/mission_manager" not in alive
    for t in (token, forged, own):
        t.undeclare()


def test_the_supervisor_hears_every_heartbeat_through_its_wildcard_subscription(bus):
    """A subscriber's key wider than the publisher's output (heartbeat/* against heartbeat/api): the
    publisher is told of it and keeps sending (with only its own outputs' declarations passed, a
    whole stack's heartbeats stopped after their first and the supervisor restarted everything)."""
    beats: list[bytes] = []
    bus["supervisor"].declare_subscriber("ares/v1/heartbeat/*", lambda s: beats.append(s.payload.to_bytes()))
    assert _wait_for(lambda: bus["api"].put("ares/v1/heartbeat/api", b"first") or b"first" in beats)
    for n in range(40):
        bus["api"].put("ares/v1/heartbeat/api", b"beat %d" % n)
        time.sleep(0.01)
    assert _wait_for(lambda: b"beat 39" in beats)
    assert all(b"beat %d" % n in beats for n in range(40))


def test_the_supervisor_taps_every_key_and_may_not_forge_one(bus):
    tapped: list[tuple[str, bytes]] = []
    bus["supervisor"].declare_subscriber("ares/v1/**", lambda s: tapped.append((str(s.key_expr), s.payload.to_bytes())))
    recorded: list[bytes] = []
    for topic in ("dbw/car_state", "supervisor/state"):
        bus["blackbox"].declare_subscriber(f"ares/v1/{topic}", lambda s: recorded.append(s.payload.to_bytes()))
    assert _wait_for(lambda: bus["api"].put("ares/v1/events", b"tapped") or ("ares/v1/events", b"tapped") in tapped)
    # reading everything is not writing it (its own tap hears it: a session delivers to itself)
    assert _wait_for(lambda: bus["supervisor"].put("ares/v1/supervisor/state", b"own") or b"own" in recorded)
    bus["supervisor"].put("ares/v1/dbw/car_state", b"forged")
    bus["supervisor"].put("ares/v1/supervisor/state", b"after")  # its own output, sent after it
    assert _wait_for(lambda: b"after" in recorded)
    assert b"forged" not in recorded


def test_the_observer_reads_but_cannot_write(bus):
    watched: list[bytes] = []
    bus["observer"].declare_subscriber("ares/v1/**", lambda s: watched.append(s.payload.to_bytes()))
    assert _wait_for(lambda: bus["api"].put("ares/v1/events", b"seen") or b"seen" in watched)
    recorded: list[bytes] = []
    bus["blackbox"].declare_subscriber("ares/v1/events", lambda s: recorded.append(s.payload.to_bytes()))
    assert _wait_for(lambda: bus["api"].put("ares/v1/events", b"api") or b"api" in recorded)
    bus["observer"].put("ares/v1/events", b"forged")
    bus["api"].put("ares/v1/events", b"after")  # sent after it, on another link: the router has both
    assert _wait_for(lambda: b"after" in recorded)
    assert b"forged" not in recorded
