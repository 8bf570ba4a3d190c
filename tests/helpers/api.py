"""The REST API's tests share these: a store seeded with records and events, users of every role,
tokens, and `ares api` as a process of its own."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from datetime import datetime, timedelta
from pathlib import Path

from fastapi.testclient import TestClient

from ares.app import run_config
from ares.core import config
from ares.core.localhost import wait_for_port
from ares.core.messages import (
    CommandRecord,
    EventLevel,
    Position,
    ProcessHealth,
    SensorHealth,
    StoredEvent,
    VehicleRecord,
)
from blackbox.api import ApiSettings
from blackbox.api.credentials import ROLES, add_user
from blackbox.register.store.record_store import StoreSettings
from tests.helpers.stack import REPO

FAST_ARGON2 = {"time_cost": 1, "memory_kib": 64, "parallelism": 1}

VEHICLE = "shuttle01"


OTHER = "shuttle02"


PASSWORD = "correct horse battery"


N_RECORDS = 1800  # the last 30 min at 1 Hz


FAULT_AT = 1200  # seconds into the window: a FAULT, 60 s in MANUAL, back in AUTOMATIC


VEHICLE_ID = "shuttle01"  # the stack's own (its API events are this vehicle's)


def api_settings(**overrides) -> ApiSettings:
    """Test settings: cheap hashing, and limits out of the way unless a test sets them."""
    base = {
        "auth": {"argon2": FAST_ARGON2},
        "rate_limit": {"client_per_s": 10_000, "client_burst": 10_000, "token_per_s": 100, "token_burst": 100},
        "blacklist": {"failed_logins": 1000, "abuse_requests_per_s": 100_000, "account_failed_logins": 1000},
    }
    for key, value in overrides.items():
        base[key] = {**base.get(key, {}), **value} if isinstance(value, dict) else value
    return ApiSettings.model_validate(base)


def seed(store, now: datetime | None = None) -> datetime:
    """N_RECORDS of VEHICLE ending one second before `now`, events, one record of OTHER; the
    time of the first record."""
    now = (now or store.now()).replace(microsecond=0)
    first = now - timedelta(seconds=N_RECORDS)
    procs = {"controller": ProcessHealth(state="running"), "dbw_bridge": ProcessHealth(state="running")}
    records = []
    for i in range(N_RECORDS):
        manual = FAULT_AT <= i < FAULT_AT + 60
        records.append(
            VehicleRecord(
                vehicle_id=VEHICLE,
                time=first + timedelta(seconds=i),
                t=float(i),
                position=Position(
                    x=float(i),
                    y=-2.5,
                    z=0.0,
                    easting=440000.0 + i,
                    northing=4474000.0,
                    zone=30,
                    hemisphere="N",
                    lat=40.4,
                    lon=-3.7,
                ),
                speed_mps=0.0 if manual else 3.0,
                steering_wheel_deg=1.5,
                mode="MANUAL" if manual else "AUTOMATIC",
                scores={"odometry": 0.9},
                controller="pure_pursuit",
                sensors={"gnss": SensorHealth(rate_hz=5.0, ok=True)},
                processes=procs,
                command=None if manual else CommandRecord(commanded_speed_mps=3.0, commanded_curvature=0.002),
                events=0,
            )
        )
    store.insert_records(records)
    store.insert_records([VehicleRecord(vehicle_id=OTHER, time=first, t=0.0, mode="READY")])
    events = [
        StoredEvent(
            vehicle_id=VEHICLE,
            time=first + timedelta(seconds=FAULT_AT, milliseconds=300),
            t=FAULT_AT + 0.3,
            source="dbw_bridge",
            kind="watchdog",
            level=EventLevel.FAULT,
            message="setpoint timeout",
        )
    ]
    for i in range(0, N_RECORDS, 60):  # 30 mode_change events
        events.append(
            StoredEvent(
                vehicle_id=VEHICLE,
                time=first + timedelta(seconds=i, milliseconds=500),
                t=i + 0.5,
                source="dbw_bridge",
                kind="mode_change",
                level=EventLevel.INFO,
                message=f"event {i}",
                data={"i": i},
            )
        )
    store.insert_events(events)
    return first


def add_role_users(store, app) -> None:
    for role in ROLES:
        if store.get_user(role) is None:
            add_user(store, app.state.services.passwords, role, role, PASSWORD, 10)


def token_for(client: TestClient, name: str, password: str = PASSWORD) -> str:
    r = client.post("/api/v1/auth/token", data={"username": name, "password": password})
    assert r.status_code == 200, r.text
    return r.json()["access_token"]


def auth(token: str) -> dict:
    return {"Authorization": f"Bearer {token}"}


def open_test_store(path: Path):
    from blackbox.register.store.sqlite_store import SqliteStore

    # no fsync per commit: durability across power cuts is the store's own tests' business
    return SqliteStore(str(path), settings=StoreSettings(synchronous="OFF"))


def start_api_process(tmp_path: Path, db: Path, port: int, *extra: str, api: dict | None = None) -> subprocess.Popen:
    """`ares api` on `port` over the store file `db`, state (key, certificate) in tmp_path/state,
    the `api` section's defaults but for cheap hashing and what `api` overrides; its output in
    tmp_path/api_<port>.log."""
    fast_hashing = {"argon2": {"time_cost": 1, "memory_kib": 64, "parallelism": 1}}
    section = config.deep_merge(
        {"state_dir": str(tmp_path / "state"), "log_level": "warning", "auth": fast_hashing}, api or {}
    )
    cfg = run_config.build(overrides={"api": section})
    run_cfg = config.write_run_config(cfg, tmp_path / f"run_{port}.json")
    env = {**os.environ, config.RUN_CONFIG_ENV: str(run_cfg), "PYTHONPATH": str(REPO)}
    env.pop("ARES_API_SECRET", None)
    log = tmp_path / f"api_{port}.log"
    with log.open("w") as out:
        proc = subprocess.Popen(
            [sys.executable, "-m", "ares.cli", "api", "--port", str(port), "--store", str(db), *extra],
            env=env,
            stdout=out,
            stderr=subprocess.STDOUT,
            text=True,
        )
    proc.log_path = log  # type: ignore[attr-defined]
    return proc


def wait_serving(proc: subprocess.Popen, port: int, timeout_s: float = 20.0) -> None:
    try:
        wait_for_port(port, timeout_s, proc)
    except RuntimeError:
        raise AssertionError(f"server exited {proc.returncode}: {proc.log_path.read_text()}") from None


def stop_api_process(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
