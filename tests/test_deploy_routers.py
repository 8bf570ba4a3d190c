"""The deployment's router files, run by eclipse-zenoh in router mode as zenohd would run them:
the link between a vehicle's router and the fleet router is mutual TLS, Zenoh user/password and
access control (ares/deploy/router_config.py). Every negative case is paired with a positive
one sent after it over the same link, so "nothing arrived" is never judged by a timeout alone; a
refused link is judged by the fleet router's own word, the refusal it logs (a slow link logs none)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
import zenoh

from ares.core.localhost import free_port, stop_process
from ares.deploy import pki, router_config
from ares.deploy.router import localize, open_router

REPO = Path(__file__).resolve().parents[1]
FLEET_FILE = REPO / "deploy" / "fleet" / "zenoh-router.json5"
VEHICLE_FILE = REPO / "deploy" / "vehicle" / "zenoh-router.json5"
LINK_WAIT_S = 10.0
# what the fleet router logs as it refuses a link: the password (Zenoh's user/password extension,
# at debug level of its target) and the certificate (TLS, a warning)
REFUSAL_LOG = "warn,zenoh_transport::unicast::establishment::accept=debug"
WRONG_PASSWORD = "UsrPwd extension - Recv OpenSyn. Invalid password."
FOREIGN_CERTIFICATE = "invalid peer certificate: BadSignature"


def test_files_in_deploy_are_the_generators_output():
    fleet = router_config.load(FLEET_FILE)
    assert router_config.vehicles_of(fleet) == ["shuttle01", "shuttle02"]
    assert FLEET_FILE.read_text() == router_config.render(
        router_config.fleet_router(["shuttle01", "shuttle02"]), "fleet"
    )
    assert VEHICLE_FILE.read_text() == router_config.render(router_config.vehicle_router(), "vehicle")


def test_fleet_services_are_services_of_the_table():
    from ares.core.topics import SERVICES

    assert set(router_config.FLEET_SERVICES) <= set(SERVICES)
    # the fleet commands nothing: no mission, no re-arm, no doors, no automatic mode from afar
    commands = {"mission/goal", "mission/pause", "mission/resume", "mission/cancel", "mission/body"}
    assert not (commands | {"movement/rearm", "set_automatic_mode"}) & set(router_config.FLEET_SERVICES)


def _client(endpoint: str, user: str, password: str) -> zenoh.Session:
    cfg = {
        "mode": "client",
        "connect": {"endpoints": [endpoint]},
        "scouting": {"multicast": {"enabled": False}},
        "transport": {"auth": {"usrpwd": {"user": user, "password": password}}},
    }
    return zenoh.open(zenoh.Config.from_json5(json.dumps(cfg)))


def _linked(session: zenoh.Session, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if list(session.info.routers_zid()):
            return True
        time.sleep(0.05)
    return False


def _refusals(log: Path, text: str, at_least: int, timeout_s: float = LINK_WAIT_S) -> int:
    """How many times the router's log says `text`, once it says it `at_least` times (or the timeout)."""
    deadline = time.monotonic() + timeout_s
    while True:
        count = log.read_text(errors="replace").count(text)
        if count >= at_least or time.monotonic() > deadline:
            return count
        time.sleep(0.05)


def _wait_for(items: list, wanted, timeout_s: float = 5.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if wanted in items:
            return True
        time.sleep(0.02)
    return False


class Deployment:
    """A fleet router and vehicle routers from deploy/'s files, the secrets from a CA made here.
    `fleet_log`: the fleet router in a process of its own, as zenohd runs it (`ares deploy
    router`), what it logs in that file; else a session in this process."""

    def __init__(self, tmp: Path, fleet_log: Path | None = None):
        self.tmp = tmp
        self.fleet_log = fleet_log
        self.fleet_process: subprocess.Popen | None = None
        self.ca = tmp / "ca"
        for vehicle_id in ("shuttle01", "shuttle02"):
            pki.issue_vehicle(self.ca, vehicle_id, ["localhost", "127.0.0.1"])
        self.tls_port, self.local_port = free_port(), free_port()
        self.sessions: list[zenoh.Session] = []
        self.fleet_cfg = localize(
            router_config.load(FLEET_FILE),
            self.ca / "fleet",
            listen=[f"tls/127.0.0.1:{self.tls_port}", f"tcp/127.0.0.1:{self.local_port}"],
        )
        if fleet_log is None:
            self.fleet_router = self.keep(open_router(self.fleet_cfg))
        else:
            self._start_fleet_process(fleet_log)
        password = (self.ca / "fleet" / "zenoh_fleet_password").read_text()
        self.fleet = self.keep(_client(f"tcp/127.0.0.1:{self.local_port}", "fleet", password))

    def _start_fleet_process(self, log: Path) -> None:
        listen = [a for e in self.fleet_cfg["listen"]["endpoints"] for a in ("--listen", e)]
        with log.open("w") as out:
            self.fleet_process = subprocess.Popen(
                [sys.executable, "-m", "ares.cli", "deploy", "router", "--config", str(FLEET_FILE),
                 "--secrets", str(self.ca / "fleet"), *listen],
                cwd=REPO, stdout=out, stderr=subprocess.STDOUT, env={**os.environ, "RUST_LOG": REFUSAL_LOG},
            )  # fmt: skip
        deadline = time.monotonic() + 60.0  # an interpreter's start on a loaded machine
        while '"router"' not in log.read_text(errors="replace"):  # its first line: listening
            assert self.fleet_process.poll() is None, log.read_text(errors="replace")[-2000:]
            assert time.monotonic() < deadline, "the fleet router did not start"
            time.sleep(0.05)

    def keep(self, session: zenoh.Session) -> zenoh.Session:
        self.sessions.append(session)
        return session

    def vehicle_router(
        self, vehicle_id: str, secrets: Path | None = None, password: str | None = None, user: str = "dbw_bridge"
    ):
        """The vehicle's router (deploy/vehicle's file with the vehicle's credentials) and one of
        its processes logged in on it (`user`: the drive-by-wire bridge, which puts dbw/car_state)."""
        secrets = secrets or self.ca / "vehicles" / vehicle_id
        cfg = router_config.load(VEHICLE_FILE)
        cfg = router_config.with_credentials(
            cfg, (secrets / "zenoh_user").read_text(), password or (secrets / "zenoh_password").read_text()
        )
        port = free_port()
        cfg = localize(cfg, secrets, listen=[f"tcp/127.0.0.1:{port}"], connect=[f"tls/127.0.0.1:{self.tls_port}"])
        router = self.keep(open_router(cfg))
        self.local = (port, pki.read_users(secrets / "zenoh_local_users"))
        return router, self.login(user)

    def login(self, user: str) -> zenoh.Session:
        """A session of the last vehicle router's process `user`, with its own password."""
        port, passwords = self.local
        return self.keep(_client(f"tcp/127.0.0.1:{port}", user, passwords[user]))

    def close(self) -> None:
        for session in reversed(self.sessions):
            session.close()
        if self.fleet_process is not None:
            stop_process(self.fleet_process)


@pytest.fixture
def deployment(tmp_path):
    d = Deployment(tmp_path)
    yield d
    d.close()


def test_a_vehicle_reaches_the_fleet_only_under_its_own_id(deployment):
    router, process = deployment.vehicle_router("shuttle01")
    assert _linked(router, LINK_WAIT_S)
    seen: list[tuple[str, bytes]] = []
    deployment.fleet.declare_subscriber(
        "ares/*/dbw/car_state", lambda s: seen.append((str(s.key_expr), s.payload.to_bytes()))
    )
    # the subscription travels to the vehicle first: wait until its own data arrives
    deadline = time.monotonic() + LINK_WAIT_S
    while ("ares/shuttle01/dbw/car_state", b"own") not in seen and time.monotonic() < deadline:
        process.put("ares/shuttle01/dbw/car_state", b"own")
        time.sleep(0.1)
    assert ("ares/shuttle01/dbw/car_state", b"own") in seen
    process.put("ares/shuttle02/dbw/car_state", b"spoofed")  # another vehicle's id: denied
    process.put("ares/shuttle01/dbw/car_state", b"after")  # the same link, sent after it
    assert _wait_for(seen, ("ares/shuttle01/dbw/car_state", b"after"))
    assert all(payload != b"spoofed" for _, payload in seen)
    # a process outside its contract: the API may not put the car's state, under its own id either
    deployment.fleet.declare_subscriber("ares/*/events", lambda s: seen.append((str(s.key_expr), s.payload.to_bytes())))
    api = deployment.login("api")
    deadline = time.monotonic() + LINK_WAIT_S
    while ("ares/shuttle01/events", b"api") not in seen and time.monotonic() < deadline:
        api.put("ares/shuttle01/events", b"api")  # its own output: delivered
        time.sleep(0.1)
    api.put("ares/shuttle01/dbw/car_state", b"forged by the api")
    api.put("ares/shuttle01/events", b"api after")  # the same link, sent after it
    assert _wait_for(seen, ("ares/shuttle01/events", b"api after"))
    assert all(payload != b"forged by the api" for _, payload in seen)


def test_the_fleet_calls_only_its_services(deployment):
    router, _ = deployment.vehicle_router("shuttle01")
    assert _linked(router, LINK_WAIT_S)
    supervisor, movement, mission, api, recorder, observer = (
        deployment.login(user)
        for user in ("supervisor", "movement_manager", "mission_manager", "api", "blackbox", "observer")
    )
    supervisor.declare_queryable("ares/shuttle01/srv/supervisor/status", lambda q: q.reply(q.key_expr, b"status"))
    for copying in ("blackbox/snapshots", "blackbox/snapshot_part"):
        recorder.declare_queryable(f"ares/shuttle01/srv/{copying}", lambda q: q.reply(q.key_expr, b"snapshot"))
    movement.declare_queryable("ares/shuttle01/srv/movement/rearm", lambda q: q.reply(q.key_expr, b"rearmed"))
    commands = ("mission/goal", "mission/pause", "mission/resume", "mission/cancel")
    for command in commands:
        mission.declare_queryable(f"ares/shuttle01/srv/{command}", lambda q: q.reply(q.key_expr, b"commanded"))
    received: list[str] = []
    observer.declare_subscriber("ares/shuttle01/**", lambda s: received.append(str(s.key_expr)))

    def call(service: str) -> list[bytes]:
        replies = deployment.fleet.get(f"ares/shuttle01/srv/{service}", timeout=2.0)
        return [r.ok.payload.to_bytes() for r in replies if r.ok is not None]

    deadline = time.monotonic() + LINK_WAIT_S
    while not call("supervisor/status") and time.monotonic() < deadline:
        time.sleep(0.1)
    assert call("supervisor/status") == [b"status"]
    # the fleet copies the incident snapshots (blackbox/fleet/snapshot_copy.py)
    assert call("blackbox/snapshots") == [b"snapshot"] and call("blackbox/snapshot_part") == [b"snapshot"]
    assert call("movement/rearm") == []  # re-arming is for someone at the vehicle
    # the fleet's credentials start no mission, nor pause, resume or cancel one (the vehicle's API,
    # through the same router, is answered: the services are there)
    for command in commands:
        assert call(command) == [], command
        local = api.get(f"ares/shuttle01/srv/{command}", timeout=2.0)
        assert [r.ok.payload.to_bytes() for r in local if r.ok is not None] == [b"commanded"], command
    deployment.fleet.put("ares/shuttle01/movement/status", b"forged")  # the fleet never publishes to a vehicle
    assert call("supervisor/status") == [b"status"]
    assert received == []


@pytest.fixture
def refusing(tmp_path):
    """A deployment whose fleet router's refusals can be read in its log."""
    d = Deployment(tmp_path, fleet_log=tmp_path / "fleet-router.log")
    yield d
    d.close()


def test_a_wrong_password_is_refused(refusing):
    good, _ = refusing.vehicle_router("shuttle01")
    assert _linked(good, LINK_WAIT_S)
    assert _refusals(refusing.fleet_log, WRONG_PASSWORD, 0) == 0  # the right password: nothing refused
    bad, _ = refusing.vehicle_router("shuttle02", password="not-its-password")
    # refused, tried again and refused again: a link the fleet router turns away, not a slow one
    assert _refusals(refusing.fleet_log, WRONG_PASSWORD, 2) >= 2
    assert not list(bad.info.routers_zid()) and list(good.info.routers_zid())


def test_a_certificate_of_another_ca_is_refused(refusing, tmp_path):
    deployment = refusing
    other = tmp_path / "other-ca"
    pki.issue_vehicle(other, "shuttle02")
    # the right password and the fleet's CA to check the fleet router: only the certificate is foreign
    secrets = tmp_path / "foreign"
    shutil.copytree(other / "vehicles" / "shuttle02", secrets)
    shutil.copy(deployment.ca / "ca.pem", secrets / "zenoh_ca")
    for name in ("zenoh_user", "zenoh_password"):
        shutil.copy(deployment.ca / "vehicles" / "shuttle02" / name, secrets / name)
    good, _ = deployment.vehicle_router("shuttle02")
    assert _linked(good, LINK_WAIT_S)
    assert _refusals(deployment.fleet_log, FOREIGN_CERTIFICATE, 0) == 0  # its own certificate: nothing refused
    foreign, _ = deployment.vehicle_router("shuttle02", secrets=secrets)
    assert _refusals(deployment.fleet_log, FOREIGN_CERTIFICATE, 2) >= 2  # refused, tried again, refused again
    assert not list(foreign.info.routers_zid()) and list(good.info.routers_zid())


def test_a_restarted_fleet_router_gets_its_vehicles_and_subscriptions_back(deployment):
    """The fleet router killed and started again on its address: the vehicle's router reconnects by
    itself (connect retries forever, exit_on_failure false) and the fleet's subscription is heard
    again, with no vehicle process restarted (stale sessions after a router restart are a known
    weakness of Zenoh deployments)."""
    router, process = deployment.vehicle_router("shuttle01")
    assert _linked(router, LINK_WAIT_S)

    def heard(fleet: zenoh.Session, tag: bytes) -> float:
        seen: list[bytes] = []
        sub = fleet.declare_subscriber("ares/*/dbw/car_state", lambda s: seen.append(s.payload.to_bytes()))
        started = time.monotonic()
        while tag not in seen and time.monotonic() - started < 20.0:
            process.put("ares/shuttle01/dbw/car_state", tag)
            time.sleep(0.05)
        sub.undeclare()
        assert tag in seen, f"{tag!r} not heard within 20 s"
        return time.monotonic() - started

    heard(deployment.fleet, b"before")
    deployment.fleet_router.close()
    time.sleep(1.0)
    restarted = deployment.keep(open_router(deployment.fleet_cfg))
    assert _linked(router, LINK_WAIT_S)  # the same vehicle router session, linked again
    assert list(router.info.routers_zid()) == [restarted.info.zid()]
    # the fleet's own client session (the API's, on the fleet host) comes back too, unopened again
    assert heard(deployment.fleet, b"after") < 20.0
