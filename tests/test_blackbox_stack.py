"""The black box in the whole stack: `ares run --headless` with every process (recorder and REST
API included), the embedded store in the test's directory (`--store`), at five times real time.

- 300 s of vehicle time: one record per second of the drive, none duplicated, none missing,
  and the headless JSON's `blackbox_records` agrees with the store;
- the store made unreachable mid-run for 30 s of vehicle time (a helper process holds an
  exclusive SQLite transaction for 6 s of wall time): afterwards every second is there.

And the REST API as a supervised process: its heartbeat comes from the server's event loop,
and a taken port makes it wait (heartbeat going, one warning event) instead of crash-looping.
"""
from __future__ import annotations

import json
import math
import os
import socket
import subprocess
import sys
import time
from datetime import datetime, timezone

import httpx
import pytest

from ares.bus import Bus
from ares.clock import Clock
from blackbox.sqlite_store import SqliteStore
from tests.conftest import REPO, free_port, make_run_config, stop_process
from tests.test_recorder import assert_every_second_once, lock_store, wait_until

pytestmark = pytest.mark.stack

SPEED = 5
PAST, FUTURE = datetime(2000, 1, 1, tzinfo=timezone.utc), datetime(2100, 1, 1, tzinfo=timezone.utc)
VEHICLE = "shuttle01"


def start_headless(*args: str) -> subprocess.Popen:
    env = {**os.environ, "ARES_RUNS_DIR": os.environ.get("ARES_TEST_RUNS_DIR", "/tmp/ares-test-runs")}
    listen = f"tcp/127.0.0.1:{free_port()}"
    return subprocess.Popen([sys.executable, "-m", "ares.cli", "run", "--headless", "--listen", listen,
                             "--speed", str(SPEED), *args], cwd=REPO, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, stdin=subprocess.DEVNULL)


def finish(proc: subprocess.Popen, timeout_s: float = 180) -> dict:
    out, err = proc.communicate(timeout=timeout_s)
    assert proc.returncode == 0, f"exit {proc.returncode}\n{out[-2000:]}\n{err[-3000:]}"
    return json.loads(out.strip().splitlines()[-1])


def stored(path) -> tuple[list[int], list[dict]]:
    store = SqliteStore(str(path))
    try:
        ts = [int(r["t"]) for r in store.records(VEHICLE, PAST, FUTURE, limit=1_000_000)]
        return ts, store.events(VEHICLE, PAST, FUTURE, limit=1_000_000)
    finally:
        store.close()


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


@pytest.mark.timeout(240)
def test_300_s_of_vehicle_time_give_300_records_none_duplicated(tmp_path):
    path = tmp_path / "blackbox.sqlite"
    result = finish(start_headless("--seconds", "300", "--store", str(path)))
    assert result["ok"] and result["total_time_s"] >= 300
    ts, events = stored(path)
    assert_every_second_once(ts)                    # distinct seconds == count, no gap
    assert result["blackbox_records"] == len(ts)
    drive = [t for t in ts if result["t_start_s"] <= t < result["t_end_s"]]
    assert abs(len(drive) - 300) <= 1, f"{len(drive)} records during the 300 s drive"
    assert ts[-1] >= math.floor(result["t_end_s"]), "the last seconds were flushed when the stack stopped"
    assert not [e for e in events if e["kind"].startswith("blackbox_")], "the store never went down"
    print(f"\n300 s run: {len(drive)} records during the drive, {len(ts)} in the run "
          f"(t {ts[0]}..{ts[-1]}), wall {result['wall_time_s']} s")


@pytest.mark.timeout(240)
def test_a_30_s_store_outage_mid_run_loses_no_second(tmp_path):
    path = tmp_path / "blackbox.sqlite"
    run = start_headless("--seconds", "150", "--store", str(path))
    try:
        before = wait_until(lambda: (t := latest_t(path)) is not None and t >= 60 and t, 120,
                            "60 s of records", 0.2)
        locker = lock_store(str(path), 30 / SPEED)    # 6 s of wall time: 30 s of vehicle time
        assert locker.wait(timeout=30) == 0
        result = finish(run)
    finally:
        if run.poll() is None:
            run.kill()
            run.wait()
    ts, events = stored(path)
    assert_every_second_once(ts)
    assert result["blackbox_records"] == len(ts)
    outage = set(range(before + 1, before + 31))
    assert outage <= set(ts) and ts[-1] > before + 31
    kinds = [e["kind"] for e in events]
    assert kinds.count("blackbox_store_down") == 1 and kinds.count("blackbox_store_up") == 1
    down = next(e for e in events if e["kind"] == "blackbox_store_down")
    up = next(e for e in events if e["kind"] == "blackbox_store_up")
    assert before < down["t"] < up["t"] and up["data"]["flushed"] > 0
    print(f"\noutage run: store locked after t={before} for 30 s of vehicle time; down event at "
          f"t={down['t']:.1f}, up at t={up['t']:.1f} ({up['data']['flushed']} spooled items written); "
          f"{len(ts)} records t {ts[0]}..{ts[-1]}, none missing, none duplicated")


@pytest.fixture
def run_config(port, tmp_path) -> dict:
    """For the API process test (conftest's router and spawn_node use it): store and API port
    of its own."""
    return make_run_config(port, {"blackbox": {"store": str(tmp_path / "bb.sqlite")}, "api": {"port": free_port()}})


@pytest.mark.timeout(60)
def test_the_api_process_beats_from_its_event_loop_and_waits_for_a_taken_port(spawn_node, router):
    cfg = router
    api_port = cfg["api"]["port"]
    taken = socket.socket()
    taken.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    taken.bind(("127.0.0.1", api_port))
    taken.listen()
    bus = Bus(cfg, "test_probe", Clock())
    try:
        beats = bus.subscribe("heartbeat/api", queue=1000)
        events = bus.subscribe("events", queue=100)
        proc = spawn_node("blackbox.api_server", "api")
        kinds: list[str] = []

        def port_event() -> bool:
            kinds.extend(e.kind for _, e in events.drain())
            return "api_port_in_use" in kinds
        wait_until(port_event, 20, "the port-in-use event")
        time.sleep(1.0)
        assert proc.poll() is None and beats.rate_hz(1.0) >= 3.0, "waiting for the port, it keeps beating"
        taken.close()
        response = wait_until(lambda: _health(api_port), 15, "the API to serve once the port is free", 0.3)
        assert response.status_code == 200 and response.json()["status"] == "ok"
        seq = beats.latest.seq
        time.sleep(1.0)
        assert beats.latest.seq >= seq + 3 and beats.latest.pid == proc.pid
        stop_process(proc)
        assert proc.returncode == 0
    finally:
        taken.close()
        bus.close()


def _health(port: int):
    try:
        # the self-signed certificate of the embedded default: verification is not the point here
        return httpx.get(f"https://127.0.0.1:{port}/api/v1/health", verify=False, timeout=2.0)
    except httpx.HTTPError:
        return None
