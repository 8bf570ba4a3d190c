"""The event register (blackbox/recorder.py): a real router, the recorder as its own process,
an embedded store in the test's directory, and a feeder publishing the inputs from this process.

The clock runs at SPEED times real time for the recorder and the feeder alike (the epoch and
speed reach the recorder through the environment, as the supervisor passes them). The store is
made unreachable the way a real one can be: another process holds an exclusive SQLite
transaction on its file, so every insert waits out the busy timeout and fails.
"""
from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import threading
import time
from datetime import datetime, timezone

import pytest
import utm

from ares.bus import Bus
from ares.clock import Clock
from ares.messages import (CanFrame, CarState, ControllerStatus, DriveMode, Event, EventLevel, GnssSentences, Imu,
                           OdometryScore, Pose, ProcessState, ProcessStatus, StoredEvent, SupervisorState,
                           VehicleRecord)
from blackbox import spool as spool_mod
from blackbox.recorder import Snapshot, build_record, origin_from_config, position_of, spool_path, store_uri
from blackbox.spool import Spool
from blackbox.sqlite_store import SqliteStore
from tests.conftest import make_run_config, stop_process

SPEED = 4.0
PAST, FUTURE = datetime(2000, 1, 1, tzinfo=timezone.utc), datetime(2100, 1, 1, tzinfo=timezone.utc)
POSE_X, POSE_Y, POSE_Z = 12.5, -7.25, 1.5

LOCK_SCRIPT = """
import sqlite3, sys, time
db = sqlite3.connect(sys.argv[1], isolation_level=None)
db.execute("BEGIN EXCLUSIVE")
print("locked", flush=True)
time.sleep(float(sys.argv[2]))
db.execute("COMMIT")
"""


# ---- fixtures ----------------------------------------------------------------------------------

@pytest.fixture
def run_config(port, tmp_path) -> dict:
    """The conftest's run config (router, child_env, spawn_node use it), with the black box's
    store and spool in the test's directory and a short retry backoff."""
    return make_run_config(port, {"blackbox": {"store": str(tmp_path / "blackbox.sqlite"),
                                               "retry_max_s": 1.0}})


@pytest.fixture
def clock() -> Clock:
    return Clock(speed=SPEED)


class Feeder:
    """Publishes the recorder's inputs at their stack rates from a thread of the test process."""

    RATES = {"pose": 10.0, "car": 10.0, "score": 10.0, "control": 10.0, "supervisor": 2.0,
             "gnss": 5.0, "imu": 20.0, "can": 20.0}    # imu below its 30 Hz minimum on purpose

    def __init__(self, cfg: dict, clock: Clock):
        self.clock = clock
        self.bus = Bus(cfg, "test_feeder", clock)
        for topic in ("localization/pose", "dbw/car_state", "odometry/score", "control/status",
                      "supervisor/state", "sensors/gnss", "sensors/imu", "sensors/can", "events"):
            self.bus.publisher(topic)       # declared up front: the thread and the test both publish
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    @staticmethod
    def messages(kind: str, t: float):
        if kind == "pose":
            return "localization/pose", Pose(t=t, x=POSE_X, y=POSE_Y, z=POSE_Z, yaw=0.3, v=2.0, yaw_rate=0.0,
                                             cov_xx=1e-5, cov_xy=0.0, cov_yy=1e-5, var_yaw=1e-4, var_v=1e-3,
                                             position_std_m=0.003, rtk=True, gnss_age_s=0.1)
        if kind == "car":
            return "dbw/car_state", CarState(t=t, mode=DriveMode.AUTOMATIC, engaged=True, watchdog_tripped=False,
                                             setpoint_age_s=0.05, v_command=2.0, kappa_command=0.01,
                                             speed_mps=2.0, steering_wheel_deg=-35.0)
        if kind == "score":
            return "odometry/score", OdometryScore(t=t, score=0.93, covariance=1e-5, pose_age_s=0.02)
        if kind == "control":
            return "control/status", ControllerStatus(t=t, controller="pure_pursuit", s=10.0, xte=0.02,
                                                      heading_error=0.0, lookahead_m=3.0, target_speed=2.0)
        if kind == "supervisor":
            return "supervisor/state", SupervisorState(t=t, processes=[
                ProcessStatus(name="gnss", state=ProcessState.RUNNING, restarts=2),
                ProcessStatus(name="controller", state=ProcessState.RESTARTING, restarts=1)])
        if kind == "gnss":
            return "sensors/gnss", GnssSentences(t=t, sentences=["$GPGGA,dummy*00"])
        if kind == "imu":
            return "sensors/imu", Imu(t=t, yaw=0.0, roll=0.0, pitch=0.0, gyro_x=0.0, gyro_y=0.0, gyro_z=0.0,
                                      accel_x=0.0, accel_y=0.0, accel_z=9.81)
        return "sensors/can", CanFrame(t=t, wheel_speed_rad_s=7.1, speed_mps=2.0, steering_wheel_deg=-35.0,
                                       throttle_pedal=0.1, brake_pedal=0.0, steering_torque=False)

    def _run(self) -> None:
        due = {kind: self.clock.now() for kind in self.RATES}
        while not self._stop.is_set():
            now = self.clock.now()
            for kind, rate in self.RATES.items():
                if now >= due[kind]:
                    self.bus.publish(*self.messages(kind, now))
                    due[kind] += 1.0 / rate
                    if due[kind] < now:         # fell behind: don't burst
                        due[kind] = now + 1.0 / rate
            self._stop.wait(0.002)

    def event(self, kind: str = "test_event", message: str = "hello") -> Event:
        ev = Event(t=self.clock.now(), source="test", kind=kind, level=EventLevel.WARNING, message=message,
                   data={"n": 1})
        self.bus.publish("events", ev)
        return ev

    def start(self) -> "Feeder":
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2)
        self.bus.close()


@pytest.fixture
def feeder(router, clock):
    f = Feeder(router, clock).start()
    yield f
    f.close()


@pytest.fixture
def start_recorder(spawn_node, clock, router):
    def start() -> subprocess.Popen:
        return spawn_node("blackbox.recorder", "blackbox", **clock.env())
    return start


@pytest.fixture
def store(run_config):
    s = SqliteStore(store_uri(run_config))
    yield s
    s.close()


def records(store, vehicle: str) -> list[dict]:
    return store.records(vehicle, PAST, FUTURE, limit=1_000_000)


def events(store, vehicle: str, kinds=None) -> list[dict]:
    return store.events(vehicle, PAST, FUTURE, kinds=kinds, limit=1_000_000)


def wait_until(condition, timeout_s: float, what: str, interval_s: float = 0.1):
    deadline = time.monotonic() + timeout_s
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")
        time.sleep(interval_s)


def stored_seconds(store, vehicle: str) -> list[int]:
    try:
        return [int(r["t"]) for r in records(store, vehicle)]
    except Exception:           # the store may be locked by the test itself
        return []


def assert_every_second_once(ts: list[int]) -> None:
    assert ts, "no records"
    assert len(ts) == len(set(ts)), f"duplicated seconds: {sorted(t for t in set(ts) if ts.count(t) > 1)}"
    missing = sorted(set(range(ts[0], ts[-1] + 1)) - set(ts))
    assert not missing, f"missing seconds: {missing}"


def lock_store(path: str, seconds: float) -> subprocess.Popen:
    """Another process holding an exclusive transaction on the store's file for `seconds`."""
    proc = subprocess.Popen([sys.executable, "-c", LOCK_SCRIPT, path, str(seconds)], stdout=subprocess.PIPE,
                            text=True, process_group=0)
    assert proc.stdout.readline().strip() == "locked"
    return proc


def stop_recorder(proc: subprocess.Popen) -> None:
    stop_process(proc, timeout_s=5.0)
    assert proc.returncode == 0, f"recorder exited with {proc.returncode}"


# ---- without processes -----------------------------------------------------------------------

def test_position_is_the_pose_plus_the_gnss_origin_in_utm_and_lat_lon():
    cfg = make_run_config(7447)
    origin = origin_from_config(cfg)
    pose = Feeder.messages("pose", 0.0)[1]
    p = position_of(pose, origin)
    o = cfg["sim"]["gnss"]["origin_utm"]
    assert (p.easting, p.northing) == (o["easting"] + POSE_X, o["northing"] + POSE_Y)
    assert (p.x, p.y, p.z, p.zone, p.hemisphere) == (POSE_X, POSE_Y, POSE_Z, o["zone"], o["hemisphere"])
    lat, lon = utm.to_latlon(p.easting, p.northing, o["zone"], northern=True)
    assert (p.lat, p.lon) == pytest.approx((lat, lon), abs=1e-9)
    # and back: the GNSS node's projection of that lat/lon gives the same local x, y
    from perception.gnss import GnssProjector
    back = GnssProjector.from_config(cfg).project(p.lat, p.lon, 0.0)
    assert (back.x, back.y) == pytest.approx((POSE_X, POSE_Y), abs=1e-3)
    assert position_of(pose, None) is None


def test_a_record_carries_what_is_known_and_null_for_what_is_not():
    cfg = make_run_config(7447)
    epoch = 1_700_000_000.25
    empty = build_record("v1", epoch, 7, Snapshot(sensor_rates={"gnss": 0.0}), origin_from_config(cfg),
                         {"gnss": 4.0}, events=3)
    assert empty.time == datetime.fromtimestamp(epoch + 7, tz=timezone.utc) and empty.t == 7.0
    assert empty.position is None and empty.speed_mps is None and empty.mode is None
    assert empty.controller is None and empty.scores == {} and empty.processes == {}
    assert empty.sensors["gnss"].ok is False and empty.events == 3
    assert empty.awareness_level is None and empty.mission_state is None


def test_spool_keeps_order_drops_the_oldest_beyond_its_bound_and_disappears_when_empty(tmp_path):
    path = tmp_path / "spool.sqlite"
    epoch = time.time()
    recs = [build_record("v1", epoch, k, Snapshot(), None, {}, 0) for k in range(1, 8)]
    spool = Spool(path, max_entries=5)
    assert not spool.pending and not path.exists()
    assert spool.append(recs[:4]) == 0
    assert spool.append(recs[4:]) == 2             # 7 entries, bound 5: the two oldest go
    assert len(spool) == 5 and spool.dropped_total == 2
    spool.close()
    again = Spool(path, max_entries=5)             # a leftover is found by the next process
    assert len(again) == 5
    upto, chunk = again.peek(3)
    assert [r.t for r in chunk] == [3.0, 4.0, 5.0]
    again.ack(upto)
    assert [r.t for r in spool_mod.load_all(path)] == [6.0, 7.0]
    upto, chunk = again.peek(10)
    again.ack(upto)
    assert not again.pending and not path.exists()


class FakeStore:
    """A store that can be down, and refuses records with t in `refuse` (a data error)."""

    def __init__(self):
        self.down = False
        self.refuse: set[float] = set()
        self.records: dict[float, VehicleRecord] = {}
        self.events: list[StoredEvent] = []

    def insert_records(self, records):
        from blackbox.store import StoreUnavailable
        if self.down:
            raise StoreUnavailable("down for the test")
        if any(r.t in self.refuse for r in records):
            raise ValueError("refused for the test")
        new = [r for r in records if r.t not in self.records]
        self.records.update((r.t, r) for r in records)
        return len(new)

    def insert_events(self, events):
        from blackbox.store import StoreUnavailable
        if self.down:
            raise StoreUnavailable("down for the test")
        self.events.extend(events)
        return len(events)

    def close(self):
        pass


def notices(writer) -> list[str]:
    out = []
    while not writer.notices.empty():
        out.append(writer.notices.get().kind)
    return out


def test_writer_spools_while_the_store_is_down_and_drops_only_what_the_store_refuses(tmp_path):
    from blackbox.recorder import StoreWriter
    fake = FakeStore()
    opened = []

    def open_fake():
        if not opened:                  # the first attempt to open fails, like a store not up yet
            opened.append(1)
            raise ConnectionError("not yet")
        return fake
    writer = StoreWriter(open_fake, Spool(tmp_path / "spool.sqlite"), batch_wait_s=0.05, retry_min_s=0.1,
                         retry_max_s=0.2)
    writer.start()
    epoch = time.time()
    for k in range(1, 4):
        writer.submit(build_record("v1", epoch, k, Snapshot(), None, {}, 0))
    wait_until(lambda: len(fake.records) == 3, 5, "the first records after the store opened")
    assert notices(writer) == ["blackbox_store_down", "blackbox_store_up"]

    fake.down = True
    for k in range(4, 8):
        writer.submit(build_record("v1", epoch, k, Snapshot(), None, {}, 0))
    wait_until(lambda: len(writer.spool) == 4, 5, "the spooled records")
    fake.refuse = {5.0}                 # back, but one record is refused by the store
    fake.down = False
    wait_until(lambda: not writer.spool.pending, 5, "the flush")
    writer.close(1.0)
    assert sorted(fake.records) == [1.0, 2.0, 3.0, 4.0, 6.0, 7.0]
    assert notices(writer) == ["blackbox_store_down", "blackbox_rejected", "blackbox_store_up"]
    assert not (tmp_path / "spool.sqlite").exists()


def test_store_and_spool_locations(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    cfg = make_run_config(7447)
    assert store_uri(cfg) == str(tmp_path / "data" / "blackbox.sqlite")
    assert spool_path(cfg) == tmp_path / "data" / f"blackbox-spool-{cfg['vehicle_id']}.sqlite"
    cfg["blackbox"]["store"] = "mongodb://db.example:27017"
    assert store_uri(cfg) == "mongodb://db.example:27017"
    assert spool_path(cfg) == tmp_path / "data" / f"blackbox-spool-{cfg['vehicle_id']}.sqlite"
    cfg["blackbox"]["store"] = "elsewhere/bb.sqlite"
    assert spool_path(cfg) == tmp_path / "elsewhere" / f"blackbox-spool-{cfg['vehicle_id']}.sqlite"


# ---- the recorder process -------------------------------------------------------------------

@pytest.mark.stack
@pytest.mark.timeout(90)
def test_one_record_per_second_with_the_latest_values_and_events_as_they_happen(
        run_config, clock, feeder, start_recorder, store):
    vehicle = run_config["vehicle_id"]
    proc = start_recorder()
    wait_until(lambda: len(stored_seconds(store, vehicle)) >= 3, 20, "the first records")

    ev = feeder.event()
    sent = time.monotonic()
    stored = wait_until(lambda: events(store, vehicle, kinds=["test_event"]), 3, "the event in the store", 0.02)
    assert time.monotonic() - sent < 2.0, "events are written as they happen"
    assert stored[0]["time"] == datetime.fromtimestamp(clock.epoch + ev.t, tz=timezone.utc)
    assert stored[0]["t"] == ev.t and stored[0]["level"] == "warning" and stored[0]["data"] == {"n": 1}
    StoredEvent.model_validate(stored[0])

    time.sleep(8 / SPEED)           # some more seconds of vehicle time
    stopped_at = clock.now()
    stop_recorder(proc)

    recs = records(store, vehicle)
    ts = [int(r["t"]) for r in recs]
    assert_every_second_once(ts)
    assert len(ts) >= 10
    assert ts[-1] >= math.floor(stopped_at) - 1, "the last seconds were flushed on SIGTERM"
    for r in recs:
        assert r["time"] == datetime.fromtimestamp(math.floor(clock.epoch + r["t"]), tz=timezone.utc)
        VehicleRecord.model_validate(r)

    o = run_config["sim"]["gnss"]["origin_utm"]
    r = recs[len(recs) // 2]
    assert r["position"]["easting"] == o["easting"] + POSE_X and r["position"]["northing"] == o["northing"] + POSE_Y
    lat, lon = utm.to_latlon(o["easting"] + POSE_X, o["northing"] + POSE_Y, o["zone"], northern=True)
    assert (r["position"]["lat"], r["position"]["lon"]) == pytest.approx((lat, lon), abs=1e-9)
    assert r["speed_mps"] == 2.0 and r["steering_wheel_deg"] == -35.0 and r["mode"] == "AUTOMATIC"
    assert r["scores"] == {"odometry": 0.93} and r["controller"] == "pure_pursuit"
    assert r["processes"] == {"gnss": {"state": "running", "restarts": 2},
                              "controller": {"state": "restarting", "restarts": 1}}
    sensors = r["sensors"]
    assert sensors["gnss"]["ok"] and 4.0 <= sensors["gnss"]["rate_hz"] <= 6.5
    assert sensors["can"]["ok"] and 16.0 <= sensors["can"]["rate_hz"] <= 25.0
    assert not sensors["imu"]["ok"] and 16.0 <= sensors["imu"]["rate_hz"] <= 25.0   # 20 Hz < 30 Hz
    assert r["awareness_level"] is None and r["mission_state"] is None
    # the event is counted once, in the record of the second it happened in: [k - 1, k)
    # (or the next one, should it arrive after that record was written)
    counted = {int(r["t"]): r["events"] for r in recs if r["events"]}
    assert list(counted.values()) == [1] and next(iter(counted)) - math.floor(ev.t) in (1, 2)
    assert len(events(store, vehicle)) == 1


@pytest.mark.stack
@pytest.mark.timeout(90)
def test_an_unreachable_store_loses_no_second_and_duplicates_none(run_config, clock, feeder, start_recorder, store,
                                                                  tmp_path):
    vehicle = run_config["vehicle_id"]
    spool_file = spool_path(run_config)
    proc = start_recorder()
    wait_until(lambda: len(stored_seconds(store, vehicle)) >= 3, 20, "the first records")

    locker = lock_store(store_uri(run_config), 3.0)     # 3 s wall = 12 s of vehicle time
    locked_from = clock.now()
    wait_until(spool_file.exists, 5, "the spool file")
    feeder.event(kind="during_outage")
    assert locker.wait(timeout=10) == 0
    locked_until = clock.now()
    wait_until(lambda: not spool_file.exists(), 10, "the spool to be flushed and removed")
    time.sleep(2 / SPEED)
    stop_recorder(proc)

    ts = stored_seconds(store, vehicle)
    assert_every_second_once(ts)
    assert ts[0] < locked_from and ts[-1] > locked_until
    outage = set(range(math.ceil(locked_from), math.floor(locked_until) + 1))
    assert outage <= set(ts) and len(outage) >= 10
    kinds = [e["kind"] for e in events(store, vehicle)]
    assert kinds.count("blackbox_store_down") == 1 and kinds.count("blackbox_store_up") == 1
    assert kinds.count("during_outage") == 1
    down = events(store, vehicle, kinds=["blackbox_store_down"])[0]
    assert down["level"] == "warning" and down["source"] == "blackbox" and "locked" in down["message"]


@pytest.mark.stack
@pytest.mark.timeout(90)
def test_a_recorder_that_falls_behind_writes_every_missed_second(run_config, clock, feeder, start_recorder, store):
    vehicle = run_config["vehicle_id"]
    proc = start_recorder()
    wait_until(lambda: len(stored_seconds(store, vehicle)) >= 3, 20, "the first records")
    os.kill(proc.pid, signal.SIGSTOP)       # frozen: its loop crosses ~8 s at once when it wakes
    frozen_at = clock.now()
    time.sleep(2.0)
    os.kill(proc.pid, signal.SIGCONT)
    thawed_at = clock.now()
    wait_until(lambda: max(stored_seconds(store, vehicle) or [0]) >= thawed_at + 1, 10, "records after the freeze")
    stop_recorder(proc)
    ts = stored_seconds(store, vehicle)
    assert_every_second_once(ts)
    assert set(range(math.ceil(frozen_at), math.floor(thawed_at) + 1)) <= set(ts)


@pytest.mark.stack
@pytest.mark.timeout(120)
def test_stopped_during_an_outage_the_spool_is_kept_and_flushed_by_the_next_start(
        run_config, clock, feeder, start_recorder, store):
    vehicle = run_config["vehicle_id"]
    spool_file = spool_path(run_config)
    first = start_recorder()
    wait_until(lambda: len(stored_seconds(store, vehicle)) >= 3, 20, "the first records")
    locker = lock_store(store_uri(run_config), 60.0)
    try:
        wait_until(spool_file.exists, 5, "the spool file")
        time.sleep(6 / SPEED)
        stopped_at = clock.now()
        stop_recorder(first)        # SIGTERM while the store is locked: what is queued is spooled
    finally:
        locker.kill()
        locker.wait()
    left = spool_mod.load_all(spool_file)
    spooled = sorted(int(i.t) for i in left if isinstance(i, VehicleRecord))
    assert spooled and spooled[-1] >= math.floor(stopped_at) - 1
    assert any(isinstance(i, StoredEvent) and i.kind == "blackbox_store_down" for i in left)

    second = start_recorder()
    wait_until(lambda: not spool_file.exists(), 20, "the leftover spool to be flushed")
    wait_until(lambda: events(store, vehicle, kinds=["blackbox_spool_flushed"]), 10, "the spool_flushed event")
    stop_recorder(second)
    ts = stored_seconds(store, vehicle)
    assert len(ts) == len(set(ts))
    assert set(spooled) <= set(ts)
    # the seconds between the two recorders have no record (nobody was recording); the rest
    # of each recorder's span is complete
    first_part = [t for t in ts if t <= spooled[-1]]
    assert_every_second_once(first_part)
