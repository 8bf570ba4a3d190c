"""The REST API against its own OpenAPI schema, live: schemathesis' command line against a real
`ares api` server (uvicorn, HTTPS with its self-signed certificate, verified) over a store that
holds records, with every check schemathesis has (`--checks all`: conformance of status codes,
content types, headers and bodies, negative data rejected, positive data accepted, missing
required headers, unsupported methods and their Allow header, authentication not ignored, ...)
in all four phases: the schema's examples, coverage (boundary values and undeclared methods),
fuzzing, and stateful sequences that follow the schema's links.

The auditor's token goes with every request (the admin's for /users, which is the admin's only),
paced at 45 requests/s (the production limit is 50/s), against the production rate limits and
blacklist: the run must find nothing, and afterwards the client must not be blacklisted. One
operation is left out of that run: the login form, because every generated login is a wrong
password and a burst of those gets a client blacklisted by design (test_api_security proves it).
The form is checked the same way in a run of its own, against a server whose failed-login limits
are raised. An API over a store alone does not offer the commands, the live streams and the
route (they need a vehicle's bus): they are not in its schema, and asking for them is a 404
(tests/test_live.py, tests/test_api_commands.py).

The API inside a vehicle's stack is run the same way (test_the_api_in_a_vehicles_stack_as_its_schema_says):
the commands answered by the real mission and movement managers, the route, the live gateway.
The fleet server's (test_the_fleet_servers_api_as_its_schema_says): every vehicle's black box
from the fleet's store and the fleet's live view; no commands, no route.

A failure fails the test with schemathesis' report (each failure with a curl line to reproduce
it, and the seed of the run).
"""

from __future__ import annotations

import contextlib
import json
import shutil
import ssl
import subprocess
import sys
import time
from datetime import timedelta
from pathlib import Path

import httpx
import pytest

from ares.core.localhost import free_port
from ares.core.messages import EventLevel, StoredEvent
from blackbox.api.credentials import Argon2Settings, Passwords, add_user
from blackbox.api.models import LoginForm
from tests.helpers.api import (
    PASSWORD,
    VEHICLE_ID,
    open_test_store,
    seed,
    start_api_process,
    stop_api_process,
    wait_serving,
)

PHASES = "examples,coverage,fuzzing,stateful"
RATE = "45/s"
MAX_EXAMPLES = 30  # per operation and phase: ~1,000 requests, ~25 s at 45/s
LOGIN = "/api/v1/auth/token"
REVOKE = "/api/v1/auth/revoke"  # revoking the run's own token would end the run: tests/test_users.py
USERS = "/api/v1/users"
# the admin's routes on one user: always on a user of the run's own (the example's, which the run
# makes), never on the accounts whose tokens the run uses, whichever names a link would give
ONE_USER = (
    "/api/v1/users/{name}",
    *(f"/api/v1/users/{{name}}/{what}" for what in ("role", "password", "disable", "enable")),
)
ONE_USER_PINNED = {path: {"path.name": "carol"} for path in ONE_USER}
# the incident snapshot the seeded black box lists (its file beside the store: each test's)
SNAPSHOT = "20261204T080000Z_shuttle01_emergency_stop_1.mcap"
SNAPSHOT_PATH = "/api/v1/vehicles/{vehicle_id}/snapshots/{name}"
SNAPSHOT_PINNED = {SNAPSHOT_PATH: {"path.vehicle_id": VEHICLE_ID, "path.name": SNAPSHOT}}
RUN_TIMEOUT_S = 240


@pytest.fixture(scope="module")
def seeded(tmp_path_factory) -> Path:
    """A store file with 30 min of records and events of two vehicles, an auditor, an admin, the
    user of the login form's example in the schema (whose login then works), and the user the
    admin's routes on one user work on."""
    db = tmp_path_factory.mktemp("api-schema") / "blackbox.sqlite"
    store = open_test_store(db)
    seed(store)
    passwords = Passwords(Argon2Settings(time_cost=1, memory_kib=64, parallelism=1))
    for role in ("auditor", "admin"):
        add_user(store, passwords, role, role, PASSWORD, 10)
    example = LoginForm.model_json_schema()["examples"][0]
    add_user(store, passwords, example["username"], "fleet", example["password"], 10)
    add_user(store, passwords, ONE_USER_PINNED[ONE_USER[0]]["path.name"], "auditor", PASSWORD, 10)  # the admin's
    now = store.now()
    store.insert_events(
        [
            StoredEvent(
                vehicle_id=VEHICLE_ID, time=now - timedelta(minutes=5), t=100.0, source="recorder", kind="snapshot",
                level=EventLevel.INFO, message="snapshot of emergency_stop",
                data={"file": SNAPSHOT, "cause": "emergency_stop"},
            )
        ]
    )  # fmt: skip
    store.close()
    return db


def copy_of(seeded: Path, tmp_path: Path) -> Path:
    """The seeded store in the test's folder, the snapshot's file beside it."""
    db = tmp_path / "blackbox.sqlite"
    shutil.copy(seeded, db)
    (tmp_path / "snapshots").mkdir()
    (tmp_path / "snapshots" / SNAPSHOT).write_bytes(b"\x89MCAP0\r\n" + bytes(4096))
    return db


def schemathesis(
    tmp_path: Path,
    schema_url: str,
    cert: Path,
    headers: dict[str, str],
    per_path_headers: dict[str, dict[str, str]],
    *args: str,
    pinned: dict[str, dict[str, str]] | None = None,
    rate: str = RATE,
    max_examples: int = MAX_EXAMPLES,
) -> subprocess.CompletedProcess:
    """`st run` with every check in every phase at RATE, verifying the server's certificate;
    failing on warnings too (e.g. rate_limited: a 429 seen, missing_auth: a token refused).
    `pinned`: per path, parameters given rather than generated (`path.vehicle_id`, `path.name`)."""

    def table(values: dict[str, str]) -> str:
        return "{ " + ", ".join(f"{json.dumps(k)} = {json.dumps(v)}" for k, v in values.items()) + " }"

    lines = [f"headers = {table(headers)}", "warnings = { fail-on = true }"]
    for path in {**per_path_headers, **(pinned or {})}:
        lines += ["[[operations]]", f"include-path = {json.dumps(path)}"]
        if path in per_path_headers:
            lines.append(f"headers = {table(per_path_headers[path])}")
        if pinned and path in pinned:
            lines.append(f"parameters = {table(pinned[path])}")
    cfg = tmp_path / "schemathesis.toml"
    cfg.write_text("\n".join(lines) + "\n")
    command = [
        sys.executable,
        "-m",
        "schemathesis.cli",
        "--config-file",
        str(cfg),
        "--no-color",
        "run",
        schema_url,
        "--checks",
        "all",
        "--phases",
        PHASES,
        "--rate-limit",
        rate,
        "--max-examples",
        str(max_examples),
        "--tls-verify",
        str(cert),
        "--workers",
        "1",
        # a pinned path parameter names the resource an operation acts on whatever a link from a
        # POST would give: "the resource just created is then found" is not for those operations
        # to say (the check counts a pinned parameter as the link's; schemathesis 4.32 applies it
        # in the stateful phase whatever an operation's own configuration says)
        *(("--exclude-checks", "ensure_resource_availability") if pinned else ()),
        *args,
    ]  # one worker: the rate is the bound anyway
    return subprocess.run(command, cwd=tmp_path, capture_output=True, text=True, timeout=RUN_TIMEOUT_S)


def report(run: subprocess.CompletedProcess) -> str:
    return f"schemathesis exited {run.returncode}:\n{run.stdout}\n{run.stderr}"


def login(client: httpx.Client, name: str) -> str:
    r = client.post(LOGIN, data={"username": name, "password": PASSWORD})
    assert r.status_code == 200, r.text
    return r.json()["access_token"]


def blacklistings(db: Path) -> list[dict]:
    store = open_test_store(db)
    try:
        now = store.now()
        return store.events(VEHICLE_ID, now - timedelta(hours=1), now + timedelta(hours=1), kinds=["ip_blacklisted"])
    finally:
        store.close()


@pytest.mark.timeout(RUN_TIMEOUT_S + 60)
def test_live_api_as_its_schema_says_at_45_per_s(tmp_path, seeded):
    db = copy_of(seeded, tmp_path)
    port = free_port()
    server = start_api_process(tmp_path, db, port)  # the production rate limits and blacklist
    base = f"https://127.0.0.1:{port}"
    cert = tmp_path / "state" / "tls" / "api_cert.pem"
    try:
        wait_serving(server, port)
        with httpx.Client(base_url=base, verify=ssl.create_default_context(cafile=str(cert)), timeout=10) as client:
            auditor, admin = login(client, "auditor"), login(client, "admin")
            run = schemathesis(
                tmp_path,
                f"{base}/openapi.json",
                cert,
                {"Authorization": f"Bearer {auditor}"},
                {path: {"Authorization": f"Bearer {admin}"} for path in (USERS, *ONE_USER)},
                "--exclude-path",
                LOGIN,
                "--exclude-path",
                REVOKE,
                pinned=ONE_USER_PINNED | SNAPSHOT_PINNED,
            )
            assert run.returncode == 0, report(run)
            summary = run.stdout[run.stdout.index("Test Phases:") :]
            for phase in ("Examples", "Coverage", "Fuzzing", "Stateful"):
                assert f"✅ {phase}" in summary, report(run)  # ran, and found nothing
            assert "No issues found" in run.stdout, report(run)
            # the client is not blacklisted: it is still served, and no blacklisting was recorded
            r = client.get("/api/v1/health")
            assert r.status_code == 200, r.text
    finally:
        stop_api_process(server)
    assert blacklistings(db) == []
    assert "blacklisted" not in server.log_path.read_text()


@pytest.mark.timeout(RUN_TIMEOUT_S + 60)
def test_login_form_as_its_schema_says(tmp_path, seeded):
    db = copy_of(seeded, tmp_path)
    port = free_port()
    # every generated login is a failed one: the failed-login limits are raised out of the way
    server = start_api_process(
        tmp_path,
        db,
        port,
        api={
            "blacklist": {"failed_logins": 1_000_000, "account_failed_logins": 1_000_000},
            "rate_limit": {"token_per_s": 1000, "token_burst": 1000},
        },
    )
    cert = tmp_path / "state" / "tls" / "api_cert.pem"
    try:
        wait_serving(server, port)
        run = schemathesis(tmp_path, f"https://127.0.0.1:{port}/openapi.json", cert, {}, {}, "--include-path", LOGIN)
        assert run.returncode == 0, report(run)
        assert "No issues found" in run.stdout, report(run)
        for phase in ("Examples", "Coverage", "Fuzzing"):
            assert f"{phase}" in run.stdout[run.stdout.index("Test Phases:") :], report(run)
    finally:
        stop_api_process(server)
    assert blacklistings(db) == []


@pytest.mark.timeout(RUN_TIMEOUT_S + 60)
def test_the_api_in_a_vehicles_stack_as_its_schema_says(tmp_path, seeded, run_config):
    """The API as a vehicle's stack runs it: on the vehicle's bus (the mission and movement
    managers answer its commands: here real nodes on the in-memory bus, at a stand-still), with
    the live gateway and the route. The operator's token goes with the commands. The live streams
    are left out of this run only because an event stream lasts until its token expires
    (tests/test_live.py checks them against their schema's statuses)."""

    from ares.core import config
    from ares.core.clock import ManualClock
    from ares.core.membus import MemoryNetwork
    from ares.core.signed_command import load_command_key
    from blackbox.api import create_app
    from blackbox.api.api_node import route_view
    from blackbox.console.live_hub import LiveHub, LiveSettings
    from managers.mission_node import MissionManager
    from managers.movement_node import MovementManager
    from tests.helpers.api import add_role_users, api_settings
    from tests.helpers.commands import with_command_key

    cfg = config.deep_merge(run_config, {"lidars": False, "mission_manager": {"autostart": "none"}})
    cfg = with_command_key(cfg, tmp_path)  # the key the API signs with and the managers check
    clock, network = ManualClock(), MemoryNetwork()
    managers = [
        MissionManager(cfg, clock=clock, bus=network.bus("mission_manager", clock)),
        MovementManager(cfg, clock=clock, bus=network.bus("movement_manager", clock)),
    ]
    for node in managers:
        node.setup()
    db = copy_of(seeded, tmp_path)
    store = open_test_store(db)
    # the production limits are the store-only run's to prove; here the limits are out of the way
    # and the pace faster, so that this run costs the test command less
    settings = api_settings(state_dir=str(tmp_path / "state"))
    api_bus = network.bus("api", clock)
    app = create_app(
        store,
        settings,
        VEHICLE_ID,
        call=api_bus.call,
        live=LiveHub(LiveSettings()),
        route=route_view(config.core(cfg)),
        command_key=load_command_key(config.core(cfg).commands),
        snapshots_dir=tmp_path / "snapshots",
        request_snapshot=lambda request: api_bus.publish("recording/snapshot_request", request),
    )
    add_role_users(store, app)
    try:
        with (
            serving_in_thread(app, settings, tmp_path) as (base, cert),
            httpx.Client(base_url=base, verify=ssl.create_default_context(cafile=str(cert)), timeout=10) as client,
        ):
            auditor, admin, operator = (login(client, name) for name in ("auditor", "admin", "operator"))
            paths = client.get("/openapi.json").json()["paths"]
            commands = [
                p
                for p in paths
                if p.startswith("/api/v1/vehicles/{vehicle_id}/") and any(m == "post" for m in paths[p])
            ]
            assert len(commands) == 5 and "/api/v1/route" in paths  # and an operator's snapshot request
            run = schemathesis(
                tmp_path,
                f"{base}/openapi.json",
                cert,
                {"Authorization": f"Bearer {auditor}"},
                {path: {"Authorization": f"Bearer {admin}"} for path in (USERS, *ONE_USER)}
                | {path: {"Authorization": f"Bearer {operator}"} for path in commands},
                "--exclude-path",
                LOGIN,
                "--exclude-path",
                REVOKE,
                "--exclude-path-regex",
                "^/api/v1/live/",
                # a command to another vehicle is a 404 whatever its body: the bodies are what to explore
                pinned={path: {"path.vehicle_id": VEHICLE_ID} for path in commands} | ONE_USER_PINNED | SNAPSHOT_PINNED,
                rate="150/s",
            )
            assert run.returncode == 0, report(run)
            assert "No issues found" in run.stdout, report(run)
    finally:
        store.close()


@contextlib.contextmanager
def serving_in_thread(app, settings, tmp_path: Path):
    """The app under uvicorn over HTTPS on a free port, in a thread of this process: (base URL,
    the certificate to verify)."""
    import threading

    import uvicorn

    from blackbox.api import uvicorn_config

    port = free_port()
    server = uvicorn.Server(uvicorn_config(app, settings, host="127.0.0.1", port=port))
    serving = threading.Thread(target=server.run, name="api", daemon=True)
    serving.start()
    try:
        deadline = time.monotonic() + 20
        while not server.started and time.monotonic() < deadline:
            time.sleep(0.05)
        assert server.started
        yield f"https://127.0.0.1:{port}", tmp_path / "state" / "tls" / "api_cert.pem"
    finally:
        server.should_exit = True
        serving.join(10)


@pytest.mark.timeout(RUN_TIMEOUT_S + 60)
def test_the_fleet_servers_api_as_its_schema_says(tmp_path, seeded):
    """The API as the fleet server runs it (blackbox.api.api_node.FleetApiServer): every vehicle's
    black box from the fleet's store, the fleet's live view (two vehicles heard on the bus), no
    commands and no route. The event streams are left out as in the vehicle's run."""
    from ares.core.messages import CarState, DriveMode
    from blackbox.api import create_app
    from blackbox.console.live_hub import LiveHub, LiveSettings
    from tests.helpers.api import add_role_users, api_settings

    db = copy_of(seeded, tmp_path)
    store = open_test_store(db)
    settings = api_settings(state_dir=str(tmp_path / "state"))
    live = LiveHub(LiveSettings())
    for vehicle_id in (VEHICLE_ID, "shuttle02"):
        car = CarState(
            t=1.0,
            mode=DriveMode.AUTOMATIC,
            engaged=True,
            watchdog_tripped=False,
            setpoint_age_s=0.02,
            v_command=2.0,
            kappa_command=0.0,
            speed_mps=2.0,
            steering_wheel_deg=0.0,
        )
        live.put(vehicle_id, "dbw/car_state", car)
    app = create_app(store, settings, "fleet", live=live, snapshots_dir=tmp_path / "snapshots")
    add_role_users(store, app)
    try:
        with (
            serving_in_thread(app, settings, tmp_path) as (base, cert),
            httpx.Client(base_url=base, verify=ssl.create_default_context(cafile=str(cert)), timeout=10) as client,
        ):
            auditor, admin = login(client, "auditor"), login(client, "admin")
            paths = client.get("/openapi.json").json()["paths"]
            assert "/api/v1/fleet" in paths and "/api/v1/route" not in paths
            assert not [p for p in paths if any(m == "post" for m in paths[p]) and "/vehicles/" in p]
            fleet = client.get("/api/v1/fleet", headers={"Authorization": f"Bearer {auditor}"}).json()
            assert [v["vehicle_id"] for v in fleet["vehicles"]] == [VEHICLE_ID, "shuttle02"]
            run = schemathesis(
                tmp_path,
                f"{base}/openapi.json",
                cert,
                {"Authorization": f"Bearer {auditor}"},
                {path: {"Authorization": f"Bearer {admin}"} for path in (USERS, *ONE_USER)},
                "--exclude-path",
                LOGIN,
                "--exclude-path",
                REVOKE,
                "--exclude-path-regex",
                "^/api/v1/live/",
                pinned=ONE_USER_PINNED | SNAPSHOT_PINNED,
                rate="150/s",
                max_examples=15,  # the same read operations as the store-only run, which explores them at 30
            )
            assert run.returncode == 0, report(run)
            assert "No issues found" in run.stdout, report(run)
    finally:
        store.close()
