"""The event register (blackbox/register/recorder.py), without processes.

The Recorder node runs on the in-memory bus (ares.core.membus) with a ManualClock: a feeder bus of
the same network publishes its inputs at their rates, stamped with the manual time, and the
test steps the recorder itself (`step_once`) at its 5 Hz, so which record holds what is exact.
The writer thread is the real one; a test waits for it with a bounded poll on its counters.
The store is the embedded one in the test's directory, or a fake one that can be down, or
refuse a record, for the outage and spool cases. The whole stack with the recorder as a
process (and a real SQLite store made unreachable) is tests/test_blackbox_stack.py.
"""

from __future__ import annotations

import math
import threading
import time
from datetime import UTC, datetime

import pytest
import utm

from ares.app import run_config
from ares.core import config
from ares.core.clock import ManualClock
from ares.core.geodesy import LocalFrame
from ares.core.membus import MemoryNetwork
from ares.core.messages import (
    CanFrame,
    CarState,
    ControllerStatus,
    DriveMode,
    Event,
    EventLevel,
    GnssSentences,
    Imu,
    OdometryScore,
    Pose,
    ProcessState,
    ProcessStatus,
    Setpoint,
    StoredEvent,
    SupervisorState,
    VehicleRecord,
)
from blackbox.register import recorder as recorder_module
from blackbox.register import spool as spool_mod
from blackbox.register.recorder import (
    RecorderParams,
    Snapshot,
    StoreWriter,
    build_record,
    position_of,
    spool_path,
    store_uri,
)
from blackbox.register.recorder_node import Recorder
from blackbox.register.spool import Spool
from blackbox.register.store.record_store import StoreSettings, StoreUnavailable
from blackbox.register.store.sqlite_store import SqliteStore
from tests.helpers.records import assert_every_second_once
from tests.helpers.stack import wait_until

PAST, FUTURE = datetime(2000, 1, 1, tzinfo=UTC), datetime(2100, 1, 1, tzinfo=UTC)
POSE_X, POSE_Y, POSE_Z = 12.5, -7.25, 1.5
# the vehicle's calendar time at stack time 0: today (the store purges what is older than 7 days),
# and not on a whole second (a record stands for the whole second of vehicle time it falls in)
UTC_EPOCH = math.floor(time.time()) + 0.25

TICK_HZ = 20  # the feeder's time step; every rate below divides it
RECORDER_HZ = 5  # blackbox.rate_hz (its default)
RATES_HZ = {
    "pose": 10,
    "car": 10,
    "score": 10,
    "control": 10,
    "setpoint": 10,
    "supervisor": 2,
    "gnss": 5,
    "imu": 20,
    "can": 20,
}  # imu below its 30 Hz minimum on purpose


# ---- helpers -----------------------------------------------------------------------------------


def recorder_config(tmp_path, **blackbox) -> dict:
    """The validated run configuration: the embedded store in the test's directory (no fsync: the
    store's durability is test_store_contract's business), a writer that neither lingers nor backs
    off for long, so that the bounded waits below are short."""
    return run_config.build(
        overrides={
            "blackbox_store": {"uri": str(tmp_path / "blackbox.sqlite"), "synchronous": "OFF"},
            "blackbox": {"batch_wait_s": 0.05, "retry_min_s": 0.05, "retry_max_s": 0.2, **blackbox},
        }
    )


def message(kind: str, t: float):
    """(topic, message) of one of the recorder's inputs, stamped t."""
    if kind == "pose":
        return "localization/pose", Pose(
            t=t,
            x=POSE_X,
            y=POSE_Y,
            z=POSE_Z,
            yaw=0.3,
            v=2.0,
            yaw_rate=0.0,
            cov_xx=1e-5,
            cov_xy=0.0,
            cov_yy=1e-5,
            var_yaw=1e-4,
            var_v=1e-3,
            position_std_m=0.003,
            rtk=True,
            gnss_age_s=0.1,
        )
    if kind == "car":
        return "dbw/car_state", CarState(
            t=t,
            mode=DriveMode.AUTOMATIC,
            engaged=True,
            watchdog_tripped=False,
            setpoint_age_s=0.05,
            v_command=2.0,
            kappa_command=0.01,
            speed_mps=2.0,
            steering_wheel_deg=-35.0,
        )
    if kind == "score":
        return "odometry/score", OdometryScore(t=t, score=0.93, covariance=1e-5, pose_age_s=0.02)
    if kind == "control":
        return "control/status", ControllerStatus(
            t=t,
            controller="pure_pursuit",
            mode="odometry",
            reason="odometry score 0.93",
            s=10.0,
            xte=0.02,
            heading_error=0.0,
            target_speed=2.5,
        )
    if kind == "setpoint":  # the controller asks for more than the movement gate lets through (car: 2.0)
        return "control/setpoint", Setpoint(t=t, v=2.2, kappa=0.012, source="pure_pursuit")
    if kind == "supervisor":
        return "supervisor/state", SupervisorState(
            t=t,
            processes=[
                ProcessStatus(name="gnss", state=ProcessState.RUNNING, restarts=2),
                ProcessStatus(name="controller", state=ProcessState.RESTARTING, restarts=1),
            ],
        )
    if kind == "gnss":
        return "sensors/gnss", GnssSentences(t=t, sentences=["$GPGGA,dummy*00"])
    if kind == "imu":
        return "sensors/imu", Imu(
            t=t,
            yaw=0.0,
            roll=0.0,
            pitch=0.0,
            gyro_x=0.0,
            gyro_y=0.0,
            gyro_z=0.0,
            accel_x=0.0,
            accel_y=0.0,
            accel_z=9.81,
        )
    if kind == "can":
        return "sensors/can", CanFrame(
            t=t,
            wheel_speed_rad_s=7.1,
            speed_mps=2.0,
            steering_wheel_deg=-35.0,
            throttle_pedal=0.1,
            brake_pedal=0.0,
            steering_torque=False,
        )
    raise ValueError(kind)


class Rig:
    """One in-memory network and its manual clock: a feeder publishing the recorder's inputs and
    events, and the recorder under test, set up and stepped as its loop would."""

    def __init__(self, cfg: dict):
        self.cfg = cfg
        self.vehicle_id = cfg["vehicle_id"]
        self.clock = ManualClock(utc_epoch=UTC_EPOCH)
        self.network = MemoryNetwork(self.vehicle_id)
        self.feeder = self.network.bus("test_feeder", self.clock)
        self.silent: set[str] = set()  # inputs not published any more (or never)
        self.recorder: Recorder | None = None
        self._tick = 0

    def start_recorder(self) -> Recorder:
        self.recorder = Recorder(self.cfg, clock=self.clock, bus=self.network.bus("blackbox", self.clock))
        self.recorder.setup()
        return self.recorder

    def stop_recorder(self) -> None:
        """What the node's run() does on SIGTERM: teardown (the writer's final flush), bus closed."""
        recorder, self.recorder = self.recorder, None
        try:
            recorder.teardown()
        finally:
            recorder.bus.close()

    def drive(self, until: float, *, stepping: bool = True) -> None:
        """Move the clock to `until` tick by tick, publishing every input that is due and, unless
        the recorder is frozen (`stepping` False), stepping it on its 5 Hz grid."""
        while self._tick < round(until * TICK_HZ):
            self._tick += 1
            t = self._tick / TICK_HZ
            self.clock.set(t)
            for kind, rate in RATES_HZ.items():
                if kind not in self.silent and self._tick % (TICK_HZ // rate) == 0:
                    self.feeder.publish(*message(kind, t))
            if stepping and self.recorder is not None and self._tick % (TICK_HZ // RECORDER_HZ) == 0:
                self.recorder.step_once(t)

    def event(self, kind: str = "test_event", message: str = "hello", t: float | None = None) -> Event:
        ev = Event(
            t=self.clock.now() if t is None else t,
            source="test",
            kind=kind,
            level=EventLevel.WARNING,
            message=message,
            data={"n": 1},
        )
        self.feeder.publish("events", ev)
        return ev


@pytest.fixture
def rigs():
    """Rigs made by a test; any recorder still running is stopped (its writer thread ended)."""
    made: list[Rig] = []

    def make(cfg: dict) -> Rig:
        made.append(Rig(cfg))
        return made[-1]

    yield make
    for rig in made:
        if rig.recorder is not None:
            rig.stop_recorder()


def records(store, vehicle: str) -> list[dict]:
    return store.records(vehicle, PAST, FUTURE, limit=1_000_000)


def events(store, vehicle: str, kinds=None) -> list[dict]:
    return store.events(vehicle, PAST, FUTURE, kinds=kinds, limit=1_000_000)


def frame_of(cfg: dict) -> LocalFrame:
    return LocalFrame(config.core(cfg).origin_utm)


class FakeStore:
    """A store that can be down, and refuses records with t in `refuse` (a data error). Like the
    real ones it keeps the first record of a second and skips any later one; `submitted` lists
    the second of every record it was given, repeats included."""

    def __init__(self):
        self.down = False
        self.refuse: set[float] = set()
        self.records: dict[float, VehicleRecord] = {}
        self.events: list[StoredEvent] = []
        self.submitted: list[float] = []
        self._lock = threading.Lock()  # the writer thread inserts, the test reads

    def insert_records(self, records):
        with self._lock:
            if self.down:
                raise StoreUnavailable("down for the test")
            if any(r.t in self.refuse for r in records):
                raise ValueError("refused for the test")
            self.submitted.extend(r.t for r in records)
            new = [r for r in records if r.t not in self.records]
            self.records.update((r.t, r) for r in new)
            return len(new)

    def insert_events(self, events):
        with self._lock:
            if self.down:
                raise StoreUnavailable("down for the test")
            self.events.extend(events)
            return len(events)

    def seconds(self) -> list[int]:
        with self._lock:
            return sorted(int(t) for t in self.records)

    def event_kinds(self) -> list[str]:
        with self._lock:
            return [e.kind for e in self.events]

    def close(self):
        pass


@pytest.fixture
def fake_store(monkeypatch) -> FakeStore:
    """The configured store replaced by a FakeStore (store_writer opens it by this name)."""
    fake = FakeStore()
    monkeypatch.setattr(recorder_module, "open_configured_store", lambda _settings: fake)
    return fake


# ---- records, positions, spool, writer ---------------------------------------------------------


def test_position_is_the_pose_plus_the_gnss_origin_in_utm_and_lat_lon():
    cfg = run_config.build()
    pose = message("pose", 0.0)[1]
    p = position_of(pose, frame_of(cfg))
    o = cfg["origin_utm"]
    assert (p.easting, p.northing) == (o["easting"] + POSE_X, o["northing"] + POSE_Y)
    assert (p.x, p.y, p.z, p.zone, p.hemisphere) == (POSE_X, POSE_Y, POSE_Z, o["zone"], o["hemisphere"])
    lat, lon = utm.to_latlon(p.easting, p.northing, o["zone"], northern=True)
    assert (p.lat, p.lon) == pytest.approx((lat, lon), abs=1e-9)
    # and back: the GNSS node's projection of that lat/lon gives the same local x, y
    from perception.gnss import GnssParams, GnssProjector

    back = GnssProjector(frame_of(cfg), GnssParams()).project(p.lat, p.lon, 0.0)
    assert (back.x, back.y) == pytest.approx((POSE_X, POSE_Y), abs=1e-3)
    # a pose with no valid projection (beyond UTM's northings) has no position
    lost = pose.model_copy(update={"y": 2.0e7})
    assert position_of(lost, frame_of(cfg)) is None


def test_a_record_carries_what_is_known_and_null_for_what_is_not():
    cfg = run_config.build()
    clock = ManualClock(utc_epoch=UTC_EPOCH)
    empty = build_record(
        "v1", clock.utc(7), 7, Snapshot(sensor_rates={"gnss": 0.0}), frame_of(cfg), {"gnss": 4.0}, events=3
    )
    assert empty.time == datetime.fromtimestamp(UTC_EPOCH + 7, tz=UTC) and empty.t == 7.0
    assert empty.position is None and empty.speed_mps is None and empty.mode is None
    assert empty.controller is None and empty.scores == {} and empty.processes == {}
    assert empty.sensors["gnss"].ok is False and empty.events == 3
    assert empty.awareness_level is None and empty.mission_state is None and empty.corrections is None


def test_a_record_keeps_the_corrections_age_and_the_fix_type():
    from ares.core.messages import CorrectionsStatus
    from tests.helpers.gnss import fix

    cfg = run_config.build()
    status = CorrectionsStatus(t=6.5, source="ntrip 127.0.0.1:2101/BASE", link="down", age_s=12.5, frames=9)
    snap = Snapshot(corrections=status, fix=fix(6.8, rtk=False, var=0.25).model_copy(update={"quality": 5}))
    record = build_record("v1", ManualClock(utc_epoch=UTC_EPOCH).utc(7), 7, snap, frame_of(cfg), {}, 0)
    assert record.corrections is not None
    assert (record.corrections.link, record.corrections.age_s, record.corrections.fix_quality) == ("down", 12.5, 5)


@pytest.mark.parametrize(
    "state, action, recorded",
    [("DRIVING", None, "DRIVING"), ("AT_POI", "OPENING_DOORS", "OPENING_DOORS"), ("PAUSED", "OPENING_DOORS", "PAUSED")],
)
def test_the_record_keeps_the_mission_state_or_the_poi_action_running(state, action, recorded):
    from ares.core.messages import MissionStatus
    from blackbox.register.recorder import mission_state

    status = MissionStatus(
        t=1.0,
        goal_id=1,
        state=state,
        kind="tour",
        poi="Library",
        action=action,
        distance_m=None,
        eta_s=None,
        limit_mps=0.0,
        ready_to_move=True,
    )
    assert mission_state(status) == recorded and mission_state(None) is None


def bare_record(k: int, vehicle: str = "v1") -> VehicleRecord:
    """A record of second k that knows nothing but its time."""
    return build_record(
        vehicle, ManualClock(utc_epoch=UTC_EPOCH).utc(k), k, Snapshot(), frame_of(run_config.build()), {}, 0
    )


def test_spool_keeps_order_drops_the_oldest_beyond_its_bound_and_disappears_when_empty(tmp_path):
    path = tmp_path / "spool.sqlite"
    recs = [bare_record(k) for k in range(1, 8)]
    spool = Spool(path, max_entries=5)
    assert not spool.pending and not path.exists()
    assert spool.append(recs[:4]) == 0
    assert spool.append(recs[4:]) == 2  # 7 entries, bound 5: the two oldest go
    assert len(spool) == 5 and spool.dropped_total == 2
    spool.close()
    again = Spool(path, max_entries=5)  # a leftover is found by the next process
    assert len(again) == 5
    upto, chunk = again.peek(3)
    assert [r.t for r in chunk] == [3.0, 4.0, 5.0]
    again.ack(upto)
    assert [r.t for r in spool_mod.load_all(path)] == [6.0, 7.0]
    upto, chunk = again.peek(10)
    again.ack(upto)
    assert not again.pending and not path.exists()


def notices(writer) -> list[str]:
    out = []
    while not writer.notices.empty():
        out.append(writer.notices.get().kind)
    return out


def test_writer_spools_while_the_store_is_down_and_drops_only_what_the_store_refuses(tmp_path):
    fake = FakeStore()
    opened = []

    def open_fake():
        if not opened:  # the first attempt to open fails, like a store not up yet
            opened.append(1)
            raise ConnectionError("not yet")
        return fake

    writer = StoreWriter(
        open_fake,
        Spool(tmp_path / "spool.sqlite", max_entries=100),
        batch_wait_s=0.05,
        retry_min_s=0.1,
        retry_max_s=0.2,
    )
    writer.start()
    for k in range(1, 4):
        writer.submit(bare_record(k))
    # store_up is set once the writer has told (notices) that the store came up
    wait_until(lambda: len(fake.records) == 3 and writer.store_up, 5, "the first records after the store opened")
    assert notices(writer) == ["blackbox_store_down", "blackbox_store_up"]

    fake.down = True
    for k in range(4, 8):
        writer.submit(bare_record(k))
    wait_until(lambda: len(writer.spool) == 4, 5, "the spooled records")
    fake.refuse = {5.0}  # back, but one record is refused by the store
    fake.down = False
    wait_until(lambda: not writer.spool.pending, 5, "the flush")
    writer.close(1.0)
    assert sorted(fake.records) == [1.0, 2.0, 3.0, 4.0, 6.0, 7.0]
    assert notices(writer) == ["blackbox_store_down", "blackbox_rejected", "blackbox_store_up"]
    assert not (tmp_path / "spool.sqlite").exists()


def store_settings(overrides: dict | None = None) -> StoreSettings:
    return config.section(run_config.build(overrides=overrides), "blackbox_store", StoreSettings)


def test_store_and_spool_locations(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    params, vehicle = RecorderParams(), "shuttle07"
    spool_name = f"blackbox-spool-{vehicle}.sqlite"
    embedded = store_settings()
    assert store_uri(embedded) == str(tmp_path / "data" / "blackbox.sqlite")
    assert spool_path(params, embedded, vehicle) == tmp_path / "data" / spool_name
    mongo = store_settings({"blackbox_store": {"uri": "mongodb://db.example:27017"}})
    assert store_uri(mongo) == "mongodb://db.example:27017"
    assert spool_path(params, mongo, vehicle) == tmp_path / "data" / spool_name
    elsewhere = store_settings({"blackbox_store": {"uri": "elsewhere/bb.sqlite"}})
    assert store_uri(elsewhere) == str(tmp_path / "elsewhere" / "bb.sqlite")
    assert spool_path(params, elsewhere, vehicle) == tmp_path / "elsewhere" / spool_name
    assert (
        spool_path(RecorderParams(spool="spools/mine.sqlite"), elsewhere, vehicle)
        == tmp_path / "spools" / "mine.sqlite"
    )


# ---- the recorder node -------------------------------------------------------------------------


def test_one_record_per_second_with_the_latest_values_and_events_as_they_happen(tmp_path, rigs):
    cfg = recorder_config(tmp_path)
    rig = rigs(cfg)
    vehicle = rig.vehicle_id
    recorder = rig.start_recorder()
    store = SqliteStore(store_uri(config.section(cfg, "blackbox_store", StoreSettings)))
    try:
        rig.drive(5.3)
        ev = rig.event()
        rig.drive(5.4)  # the recorder's next step takes the event in
        wait_until(lambda: recorder.writer.events_written == 1, 10, "the event in the store")
        # in the store as it happened: before the record of its second was even built
        assert store.latest(vehicle)["t"] == 5.0
        stored = events(store, vehicle, kinds=["test_event"])
        assert stored[0]["time"] == rig.clock.utc(ev.t)
        assert stored[0]["t"] == ev.t and stored[0]["level"] == "warning" and stored[0]["data"] == {"n": 1}
        StoredEvent.model_validate(stored[0])

        rig.drive(12.0)
        rig.stop_recorder()

        recs = records(store, vehicle)
        ts = [int(r["t"]) for r in recs]
        assert ts == list(range(1, 13)), "every second once, the last one flushed at teardown"
        for r in recs:
            assert r["time"] == datetime.fromtimestamp(math.floor(UTC_EPOCH + r["t"]), tz=UTC)
            VehicleRecord.model_validate(r)

        o = cfg["origin_utm"]
        r = recs[len(recs) // 2]
        assert r["position"]["easting"] == o["easting"] + POSE_X
        assert r["position"]["northing"] == o["northing"] + POSE_Y
        lat, lon = utm.to_latlon(o["easting"] + POSE_X, o["northing"] + POSE_Y, o["zone"], northern=True)
        assert (r["position"]["lat"], r["position"]["lon"]) == pytest.approx((lat, lon), abs=1e-9)
        assert r["speed_mps"] == 2.0 and r["steering_wheel_deg"] == -35.0 and r["mode"] == "AUTOMATIC"
        assert r["scores"] == {"odometry": 0.93} and r["controller"] == "pure_pursuit"
        assert r["processes"] == {
            "gnss": {"state": "running", "restarts": 2},
            "controller": {"state": "restarting", "restarts": 1},
        }
        sensors = r["sensors"]
        assert sensors["gnss"] == {"rate_hz": pytest.approx(5.0), "ok": True}
        assert sensors["can"] == {"rate_hz": pytest.approx(20.0), "ok": True}
        assert sensors["imu"] == {"rate_hz": pytest.approx(20.0), "ok": False}  # 20 Hz < 30 Hz
        assert r["awareness_level"] is None and r["mission_state"] is None
        # what was asked beside what was done: the speed aimed at, the controller's output, the command
        assert r["command"] == {
            "target_speed_mps": 2.5,
            "controller": "pure_pursuit",
            "controller_speed_mps": 2.2,
            "controller_curvature": 0.012,
            "commanded_speed_mps": 2.0,
            "commanded_curvature": 0.01,
            "emergency": False,
        }
        # the event is counted once, in the record of the second it happened in: [k - 1, k)
        assert {int(r["t"]): r["events"] for r in recs if r["events"]} == {6: 1}
        assert len(events(store, vehicle)) == 1
    finally:
        store.close()


def test_missing_and_stale_inputs_are_recorded_as_null(tmp_path, rigs, fake_store):
    rig = rigs(recorder_config(tmp_path))
    rig.silent = {"control", "can"}  # never heard of
    rig.start_recorder()
    rig.drive(4.0)
    rig.silent |= {"pose", "car", "score", "supervisor", "gnss", "setpoint"}  # last heard at t = 4.0
    rig.drive(9.0)
    wait_until(lambda: fake_store.seconds() == list(range(1, 10)), 10, "the nine records in the store")
    rig.stop_recorder()

    assert fake_store.seconds() == list(range(1, 10))
    recs = fake_store.records
    for k in range(1, 10):
        assert recs[k].controller is None and recs[k].sensors["can"].ok is False
        assert recs[k].sensors["can"].rate_hz == 0.0
    # max_age_s = 2: a value 2 s old still counts, an older one is missing, not passed off as current
    for k in range(1, 7):
        r = recs[k]
        assert r.position is not None and r.speed_mps == 2.0 and r.mode == DriveMode.AUTOMATIC
        assert r.scores == {"odometry": 0.93} and set(r.processes) == {"gnss", "controller"}
        assert r.command is not None and r.command.target_speed_mps is None  # the control manager never heard
        assert (r.command.controller_speed_mps, r.command.commanded_speed_mps) == (2.2, 2.0)
    for k in (7, 8, 9):
        r = recs[k]
        assert r.position is None and r.speed_mps is None and r.steering_wheel_deg is None and r.mode is None
        assert r.command is None
        assert r.scores == {} and r.processes == {}
        assert r.sensors["gnss"].rate_hz == 0.0 and r.sensors["gnss"].ok is False


def test_a_silent_sensor_is_never_ok_whatever_minimums_are_configured(tmp_path, rigs, fake_store):
    # a run configuration that raises the IMU's minimum only: the GNSS keeps a minimum of its own
    rig = rigs(recorder_config(tmp_path, sensor_min_hz={"imu": 50.0}))
    rig.silent = {"gnss"}  # the receiver is dead
    rig.start_recorder()
    rig.drive(3.0)
    wait_until(lambda: fake_store.seconds() == [1, 2, 3], 10, "the three records in the store")
    rig.stop_recorder()
    gnss = fake_store.records[3].sensors["gnss"]
    assert gnss.rate_hz == 0.0 and gnss.ok is False


def test_each_event_is_counted_once_even_when_it_arrives_after_its_record(tmp_path, rigs, fake_store):
    rig = rigs(recorder_config(tmp_path))
    recorder = rig.start_recorder()
    rig.drive(2.5)
    rig.event("on_time")  # t = 2.5: the record of second 3
    rig.drive(6.1)  # the record of second 6 was built at t = 6.0 ...
    rig.event("late", t=5.5)  # ... so this one of [5, 6) goes to the next record
    rig.drive(7.2)
    rig.event("first_of_two")
    rig.event("second_of_two")  # both at t = 7.2: the record of second 8
    rig.drive(10.0)
    wait_until(
        lambda: recorder.writer.events_written == 4 and recorder.writer.records_written == 10,
        10,
        "the four events and ten records in the store",
    )
    rig.stop_recorder()

    counted = {int(t): r.events for t, r in fake_store.records.items() if r.events}
    assert counted == {3: 1, 7: 1, 8: 2}
    assert fake_store.event_kinds() == ["on_time", "late", "first_of_two", "second_of_two"]


def test_a_recorder_that_falls_behind_writes_every_missed_second(tmp_path, rigs, fake_store):
    rig = rigs(recorder_config(tmp_path))
    recorder = rig.start_recorder()
    rig.drive(3.0)
    rig.drive(11.0, stepping=False)  # frozen (a stopped process, a starved loop) for 8 s ...
    recorder.step_once(11.0)  # ... its next step crosses seconds 4 to 11 at once
    rig.drive(13.0)
    wait_until(lambda: recorder.writer.records_written == 13, 10, "the records up to second 13")
    rig.stop_recorder()
    assert fake_store.submitted == [float(k) for k in range(1, 14)], "each second built once, none skipped"


def test_a_store_outage_loses_no_second_and_duplicates_none(tmp_path, rigs, fake_store):
    cfg = recorder_config(tmp_path)
    rig = rigs(cfg)
    recorder = rig.start_recorder()
    writer = recorder.writer
    spool_file = spool_path(recorder.params, config.section(cfg, "blackbox_store", StoreSettings), rig.vehicle_id)
    rig.drive(3.0)
    wait_until(lambda: fake_store.seconds() == [1, 2, 3], 10, "the first records")

    fake_store.down = True
    rig.drive(4.0)
    # the recorder publishes the writer's notices from its own steps: let the writer see the
    # failure before stepping on, so that the warning is published (and recorded) mid-outage
    wait_until(lambda: not writer.store_up and not writer.notices.empty(), 10, "the writer to notice the outage")
    rig.drive(8.0)
    rig.event("during_outage")
    rig.drive(15.0)
    # records 4..15, the warning and the test's event
    wait_until(lambda: len(writer.spool) == 14, 10, "everything of the outage in the spool")
    assert spool_file.exists() and fake_store.seconds() == [1, 2, 3]

    fake_store.down = False
    wait_until(lambda: writer.store_up and not writer.spool.pending, 10, "the spool flushed once the store is back")
    assert not spool_file.exists()
    rig.drive(17.0)
    wait_until(
        lambda: "blackbox_store_up" in fake_store.event_kinds() and fake_store.seconds()[-1] == 17,
        10,
        "the store_up event and the last record in the store",
    )
    rig.stop_recorder()

    ts = fake_store.seconds()
    assert ts == list(range(1, 18))
    outage = set(range(4, 16))
    assert outage <= set(ts) and len(outage) >= 10
    kinds = fake_store.event_kinds()
    assert kinds.count("blackbox_store_down") == 1 and kinds.count("blackbox_store_up") == 1
    assert kinds.count("during_outage") == 1
    down = next(e for e in fake_store.events if e.kind == "blackbox_store_down")
    up = next(e for e in fake_store.events if e.kind == "blackbox_store_up")
    assert down.level == EventLevel.WARNING and down.source == "blackbox" and "down for the test" in down.message
    assert 4.0 < down.t < 8.0 and up.t > 15.0 and up.data["flushed"] == 14


def test_stopped_during_an_outage_the_spool_is_kept_and_flushed_by_the_next_start(tmp_path, rigs, fake_store):
    cfg = recorder_config(tmp_path)
    rig = rigs(cfg)
    first = rig.start_recorder()
    spool_file = spool_path(first.params, config.section(cfg, "blackbox_store", StoreSettings), rig.vehicle_id)
    rig.drive(3.0)
    wait_until(lambda: fake_store.seconds() == [1, 2, 3], 10, "the first records")
    fake_store.down = True
    rig.drive(4.0)
    wait_until(
        lambda: not first.writer.store_up and not first.writer.notices.empty(), 10, "the writer to notice the outage"
    )
    rig.drive(8.0)
    wait_until(lambda: len(first.writer.spool) == 6, 10, "records 4..8 and the warning in the spool")
    rig.stop_recorder()  # SIGTERM while the store is down: what is queued is spooled

    left = spool_mod.load_all(spool_file)
    spooled = sorted(int(i.t) for i in left if isinstance(i, VehicleRecord))
    assert spooled == [4, 5, 6, 7, 8]
    assert any(isinstance(i, StoredEvent) and i.kind == "blackbox_store_down" for i in left)

    fake_store.down = False
    rig.drive(12.0)  # nobody records seconds 9..12
    second = rig.start_recorder()
    # the notice follows the flush: wait for both before stepping on, or the steps could all pass
    # before there is anything to publish
    wait_until(
        lambda: not spool_file.exists() and not second.writer.notices.empty(), 10, "the leftover spool to be flushed"
    )
    rig.drive(15.0)
    wait_until(lambda: "blackbox_spool_flushed" in fake_store.event_kinds(), 10, "the spool_flushed event")
    wait_until(lambda: fake_store.seconds()[-3:] == [13, 14, 15], 10, "the second recorder's records")
    rig.stop_recorder()

    ts = fake_store.seconds()
    assert set(spooled) <= set(ts)
    # the seconds between the two recorders have no record (nobody was recording); the rest of
    # each recorder's span is complete, the second starting at the second after its start
    assert ts == [*range(1, 9), 13, 14, 15]
    assert_every_second_once([t for t in ts if t <= spooled[-1]])
    assert "blackbox_store_up" not in fake_store.event_kinds()  # a fresh writer never saw it down
