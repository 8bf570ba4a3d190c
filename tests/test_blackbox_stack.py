"""The black box in the whole stack: `ares run --headless` with every process (recorder and REST
API included) and the embedded store in the test's directory (`--store`).

- at five times real time, the store and its spool on a 16 MB filesystem that fills up mid-run for
  25 s of vehicle time (the clock tied to the wall's): the writer holds the seconds in memory, the
  shuttle drives on, and once the disk has room every second is there (the headless run's
  `blackbox` object: written == in_store, store_faults > 0; blackbox_store_down and _up events).
  A store locked by another process is refused alike (tests/test_store_contract.py).

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

import errno
import json
import os
import socket
import subprocess
import sys
import time
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


@pytest.fixture
def small_disk(tmp_path):
    """A 16 MB filesystem of its own for the store and its spool (room for SQLite's write-ahead log,
    up to 4 MB before a checkpoint), unmounted after the test."""
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    mount = tmp_path / "disk"
    mount.mkdir()
    subprocess.run(["mount", "-t", "tmpfs", "-o", "size=16m", "tmpfs", str(mount)], check=True)
    try:
        yield mount
    finally:
        subprocess.run(["umount", "-l", str(mount)], check=False)


def fill(folder):
    """The filesystem filled to its last byte by one file (remove it to free the disk)."""
    filler = folder / "filler"
    with open(filler, "wb", buffering=0) as out:
        try:
            while True:
                out.write(b"\0" * 65536)
        except OSError as exc:
            assert exc.errno == errno.ENOSPC
    return filler


@pytest.mark.timeout(240)
@pytest.mark.whole_stack
def test_a_store_on_a_disk_that_fills_up_keeps_every_second_and_the_shuttle_drives_on(small_disk):
    """The store and its spool on a 16 MB filesystem filled mid-run: the writer holds the seconds in
    memory, says the store is down, the shuttle drives on (a store down holding every record is no
    awareness cause), and once the disk has room again every second of the run is in the store."""
    path = small_disk / "blackbox.sqlite"

    def driving_since() -> int | None:  # the newest second, once the records show the shuttle under way
        latest = path.exists() and records_of(path)[-1:]
        if run.poll() is not None:  # the run ended before the shuttle was seen under way: say how
            out, err = run.communicate()
            last = latest[0] if latest else None
            raise AssertionError(
                f"the run ended (exit {run.returncode}), last record {last}\n{out[-1500:]}\n{err[-3000:]}"
            )
        return int(latest[0]["t"]) if latest and (latest[0]["speed_mps"] or 0.0) > 1.0 else None

    run = start_headless("--seconds", "60", "--store", str(path))
    try:
        try:
            before = wait_until(driving_since, 120, "records of the shuttle driving", 0.2)
        except AssertionError as timed_out:  # still running: what the store holds, what the machine does
            busiest = subprocess.run(["ps", "-eo", "pcpu,etimes,args", "--sort=-pcpu"], capture_output=True, text=True)
            last = path.exists() and records_of(path)[-1:]
            raise AssertionError(f"{timed_out}; last record {last}\n{busiest.stdout[:2500]}") from None
        filler = fill(small_disk)
        full_since = time.monotonic()
        # the full disk for 25 s of vehicle time (5 s of wall time at SPEED): nothing reaches the store
        time.sleep(25 / SPEED)
        stuck = latest_t(path)
        os.unlink(filler)
        full_s = time.monotonic() - full_since
        # room again: the writer's next retry (at most retry_max_s of wall time) writes the backlog
        wait_until(lambda: (t := latest_t(path)) is not None and t > (stuck or before) + 5, 60, "the backlog", 0.2)
        result = finish(run)
    finally:
        if run.poll() is None:
            run.kill()
            run.wait()
    ts, events = stored(path)
    assert_every_second_once(ts)
    blackbox = result["blackbox"]
    assert blackbox["written"] == blackbox["in_store"] == len(ts) == result["blackbox_records"]
    assert blackbox["dropped"] == 0 and blackbox["store_faults"] > 0 and blackbox["store_up"]
    kinds = [e["kind"] for e in events]
    assert "blackbox_store_down" in kinds and "blackbox_store_up" in kinds
    down = next(e for e in events if e["kind"] == "blackbox_store_down")
    assert "full" in down["message"] or "full" in json.dumps(down["data"])
    # the shuttle drove on through the full disk: its records of those seconds show it moving
    with_speed = {int(r["t"]): r["speed_mps"] for r in records_of(path)}
    full = [k for k in ts if before + 2 < k <= (stuck or before) + 20]
    # (a second whose speed input was stale on a loaded machine holds none: not a second of standing)
    assert full and max(with_speed[k] or 0.0 for k in full) > 0.5
    assert result["ok"] and not [e for e in events if e["kind"] == "emergency_stop"]
    print(
        f"\nfull disk: filled after t={before} for {full_s:.1f} s of wall time; "
        f"{blackbox['store_faults']} store faults, {len(ts)} records t {ts[0]}..{ts[-1]}, none missing"
    )


def records_of(path) -> list[dict]:
    store = SqliteStore(str(path))
    try:
        return store.records(VEHICLE, PAST, FUTURE, limit=1_000_000)
    finally:
        store.close()
