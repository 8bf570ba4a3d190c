"""The black box in the whole stack: `ares run --headless` with every process (recorder and REST
API included) and the embedded store in the test's directory (`--store`).

- at five times real time, the store made unreachable mid-run for 30 s of vehicle time (a helper
  process holds an exclusive SQLite transaction for 6 s of wall time, so the clock must be tied to
  the wall's): afterwards every second is there.

And the REST API as a process of its own (`python -m ares.core.launch blackbox.api.api_node:ApiServer`,
as the supervisor starts it): its heartbeat goes on from the server's event loop while a taken
port makes it wait (one warning event) instead of crash-looping, and it serves once the port is
free.

A record for every second of a drive at `--speed max` (the simulator waits for the recorder's step,
as for every process it feeds) and at `--speed 2` is checked by tests/test_stack.py's runs; the
recorder's logic (which second holds what, stale inputs, events, outages with the spool) without
processes in tests/test_recorder.py, and in the whole stack on the in-memory bus in
tests/test_in_process_stack.py.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
from datetime import UTC, datetime

import httpx
import pytest

from ares.core.bus import Bus
from ares.core.clock import WallClock
from ares.core.localhost import free_port, stop_process
from blackbox.register.store.sqlite_store import SqliteStore
from tests.helpers.records import assert_every_second_once, stored
from tests.helpers.stack import NO_LIDARS, REPO, make_run_config, wait_until

pytestmark = pytest.mark.stack

SPEED = 5
PAST, FUTURE = datetime(2000, 1, 1, tzinfo=UTC), datetime(2100, 1, 1, tzinfo=UTC)
VEHICLE = "shuttle01"

LOCK_SCRIPT = """
import sqlite3, sys, time
db = sqlite3.connect(sys.argv[1], isolation_level=None)
db.execute("BEGIN EXCLUSIVE")
print("locked", flush=True)
time.sleep(float(sys.argv[2]))
db.execute("COMMIT")
"""


def lock_store(path: str, seconds: float) -> subprocess.Popen:
    """Another process holding an exclusive transaction on the store's file for `seconds` (wall)."""
    proc = subprocess.Popen(
        [sys.executable, "-c", LOCK_SCRIPT, path, str(seconds)], stdout=subprocess.PIPE, text=True, process_group=0
    )
    assert proc.stdout.readline().strip() == "locked"
    return proc


def start_headless(*args: str, speed: str = str(SPEED)) -> subprocess.Popen:
    env = {**os.environ, "ARES_RUNS_DIR": os.environ.get("ARES_TEST_RUNS_DIR", "/tmp/ares-test-runs")}
    listen = f"tcp/127.0.0.1:{free_port()}"
    return subprocess.Popen(
        [
            sys.executable,
            "-m",
            "ares.cli",
            "run",
            "--headless",
            "--listen",
            listen,
            "--speed",
            speed,
            "--config",
            str(NO_LIDARS),
            *args,
        ],
        cwd=REPO,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        stdin=subprocess.DEVNULL,
    )


def finish(proc: subprocess.Popen, timeout_s: float = 180) -> dict:
    out, err = proc.communicate(timeout=timeout_s)
    assert proc.returncode == 0, f"exit {proc.returncode}\n{out[-2000:]}\n{err[-3000:]}"
    return json.loads(out.strip().splitlines()[-1])


def latest_t(path) -> int | None:
    if not path.exists():
        return None
    store = SqliteStore(str(path))
    try:
        latest = store.latest(VEHICLE)
    except Exception:
        return None
    finally:
        store.close()
    return int(latest["t"]) if latest else None


# ---- the REST API as a process ------------------------------------------------------------------


@pytest.fixture
def run_config(port, tmp_path) -> dict:
    """For the API process test (conftest's router and spawn_node use it): store and API port of
    its own."""
    return make_run_config(port, {"blackbox_store": {"uri": str(tmp_path / "bb.sqlite")}, "api": {"port": free_port()}})


def _health(port: int):
    try:
        # the self-signed certificate of the embedded default: verification is not the point here
        return httpx.get(f"https://127.0.0.1:{port}/api/v1/health", verify=False, timeout=2.0)
    except httpx.HTTPError:
        return None


@pytest.mark.timeout(90)
def test_the_api_process_beats_from_its_event_loop_and_waits_for_a_taken_port(router, spawn_node):
    cfg = router
    api_port = cfg["api"]["port"]
    taken = socket.socket()
    taken.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    taken.bind(("127.0.0.1", api_port))
    taken.listen()
    bus = Bus(cfg, "test_probe", WallClock())
    try:
        beats = bus.subscribe("heartbeat/api")
        events = bus.subscribe("events", queue=100)
        # as the supervisor starts it: `python -m ares.core.launch blackbox.api.api_node:ApiServer`
        proc = spawn_node("blackbox.api.api_node:ApiServer", "api")
        seen: list = []

        def port_events() -> list:
            seen.extend(e for _, e in events.drain())
            return [e for e in seen if e.kind == "api_port_in_use"]

        in_use = wait_until(port_events, 30, "the port-in-use event")[0]
        assert in_use.level == "warning" and in_use.source == "api" and in_use.data["port"] == api_port

        # waiting for the port, it stays up and keeps beating (heartbeat numbers go on)
        first = wait_until(lambda: beats.latest, 10, "a heartbeat of the API").seq
        wait_until(lambda: beats.latest.seq >= first + 3, 10, "heartbeats while the port is taken")
        assert proc.poll() is None, "a taken port must not end the process (a restart loop)"

        taken.close()
        response = wait_until(lambda: _health(api_port), 20, "the API to serve once the port is free", 0.3)
        assert response.status_code == 200 and response.json()["status"] == "ok"
        seq = beats.latest.seq
        wait_until(lambda: beats.latest.seq >= seq + 3, 10, "heartbeats while serving")
        assert beats.latest.pid == proc.pid and beats.latest.process == "api", "the same process, never restarted"
        assert len(port_events()) == 1, "one warning, not one per retry"
        stop_process(proc)
        assert proc.returncode == 0
    finally:
        taken.close()
        bus.close()


# ---- the whole stack ------------------------------------------------------------------------------


@pytest.mark.timeout(240)
@pytest.mark.whole_stack
def test_a_30_s_store_outage_mid_run_loses_no_second(tmp_path):
    path = tmp_path / "blackbox.sqlite"
    run = start_headless("--seconds", "50", "--store", str(path))
    try:
        before = wait_until(lambda: (t := latest_t(path)) is not None and t >= 10 and t, 120, "10 s of records", 0.2)
        locker = lock_store(str(path), 30 / SPEED)  # 6 s of wall time: 30 s of vehicle time
        assert locker.wait(timeout=30) == 0
        result = finish(run)
    finally:
        if run.poll() is None:
            run.kill()
            run.wait()
    ts, events = stored(path)
    assert_every_second_once(ts)
    assert result["blackbox_records"] == len(ts)
    # the recorder's own count after its final flush: every record it counted is in the store
    blackbox = result["blackbox"]
    assert blackbox["written"] == blackbox["in_store"] == len(ts) and blackbox["dropped"] == 0
    assert blackbox["store_faults"] > 0 and blackbox["store_up"]
    outage = set(range(before + 1, before + 31))
    assert outage <= set(ts) and ts[-1] > before + 31
    kinds = [e["kind"] for e in events]
    assert kinds.count("blackbox_store_down") == 1 and kinds.count("blackbox_store_up") == 1
    down = next(e for e in events if e["kind"] == "blackbox_store_down")
    up = next(e for e in events if e["kind"] == "blackbox_store_up")
    assert before < down["t"] < up["t"] and up["data"]["flushed"] > 0
    print(
        f"\noutage run: store locked after t={before} for 30 s of vehicle time; down event at "
        f"t={down['t']:.1f}, up at t={up['t']:.1f} ({up['data']['flushed']} spooled items written); "
        f"{len(ts)} records t {ts[0]}..{ts[-1]}, none missing, none duplicated"
    )
