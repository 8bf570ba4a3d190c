"""Incident snapshots (ares/app/bus_record/snapshots.py, blackbox/register/snapshot_files.py,
blackbox/api/routes/snapshots.py): the ring of the last seconds of the bus saved with the seconds
after, once per triggering event; the files listed beside their events in the black box and
downloaded through the API by an auditor, an operator refused another vehicle's; a full disk (a
real 1 MB tmpfs) a clear failure with nothing half-written left. In memory: a MemoryNetwork."""

from __future__ import annotations

import os
import subprocess
from datetime import UTC, datetime, timedelta

import pytest
from fastapi.testclient import TestClient

from ares.app import run_config
from ares.app.bus_record import mcap_replay
from ares.app.bus_record.snapshots import EVENT_KIND, FAILED_KIND, REQUEST_TOPIC, SnapshotKeeper, matches
from ares.core import schema
from ares.core.clock import ManualClock
from ares.core.config import SnapshotSettings, SnapshotTrigger
from ares.core.membus import MemoryNetwork
from ares.core.messages import Event, EventLevel, PointCloud, SnapshotRequest, StoredEvent, VehicleRecord
from blackbox.api import create_app
from blackbox.register import snapshot_files
from tests.helpers.api import OTHER, VEHICLE, VEHICLE_ID, add_role_users, api_settings, auth, open_test_store, token_for
from tests.helpers.recording import on_grid_cloud, pose

UTC_EPOCH = 1_790_000_000.0


@pytest.fixture(scope="module")
def cfg():
    return run_config.build((), {"lidars": True})


def sweep(t: float) -> PointCloud:
    return on_grid_cloud(t, n=640)


def event(t: float, kind: str, **data) -> Event:
    return Event(t=t, source="test", kind=kind, level=EventLevel.FAULT, message=kind, data=data)


def drive(folder, cfg, settings: SnapshotSettings, seconds: float, happenings: dict[float, object]):
    """`seconds` of poses (20 Hz) and sweeps (10 Hz) through a MemoryNetwork, the happenings
    (events, requests) at their stamps; the keeper closed at the end. (keeper, payloads sent by
    stamp, the snapshot events heard on the bus)."""
    clock = ManualClock()
    network = MemoryNetwork(cfg["vehicle_id"])
    keeper = SnapshotKeeper(cfg, settings, folder, utc_epoch=UTC_EPOCH)
    keeper.attach(network.bus("recorder", clock))
    keeper.start()
    listener = network.bus("listener", clock).subscribe("events", queue=100)
    feeder = network.bus("sim", clock)
    sent: list[tuple[float, str, bytes]] = []
    for k in range(1, round(seconds * 20) + 1):
        t = round(k * 0.05, 9)
        clock.set(t)
        outgoing: list[tuple[str, object]] = [("localization/pose", pose(t))]
        if k % 2 == 0:
            outgoing.append(("lidar/roof/points", sweep(t)))
        if t in happenings:
            what = happenings[t]
            outgoing.append((REQUEST_TOPIC if isinstance(what, SnapshotRequest) else "events", what))
        for topic, msg in outgoing:
            feeder.publish(topic, msg)
            sent.append((t, topic, bytes(schema.encode(msg))))
    keeper.close()
    heard = [e for _, e in listener.drain() if e.kind in (EVENT_KIND, FAILED_KIND) and e.source == "recorder"]
    return keeper, sent, heard


def test_each_triggering_event_is_covered_by_one_snapshot_of_the_seconds_around_it(tmp_path, cfg):
    settings = SnapshotSettings(enabled=True, before_s=4.0, after_s=2.0)
    happenings = {
        5.0: event(5.0, "mode_change", **{"from": "MANUAL", "to": "READY"}),  # not a takeover: nothing
        8.0: event(8.0, "awareness", level_from=0, level_to=1),
        8.05: event(8.05, "emergency_stop", cause="lidar_blocked"),  # the same incident: the same snapshot
        9.0: event(9.0, "awareness", level_from=1, level_to=1),  # still level 1, another cause: nothing
        9.5: event(9.5, "awareness", level_from=1, level_to=2),  # level 2: nothing
        12.5: event(12.5, "controller_switch", **{"from": "mpc", "to": "stop"}),  # later: a snapshot of its own
        13.0: event(13.0, "snapshot", file="someone_elses.mcap"),  # a snapshot's own event triggers nothing
    }
    keeper, sent, heard = drive(tmp_path, cfg, settings, 16.0, happenings)
    assert (keeper.stats.triggered, keeper.stats.saved, keeper.stats.failed) == (3, 2, 0), keeper.stats
    assert [e.data["cause"] for e in heard] == ["awareness", "controller_switch"]
    assert heard[0].data["also"] == "emergency_stop at 8.05 s" and heard[1].data["also"] == ""
    for announced, cause_t, end in zip(heard, (8.0, 12.5), (10.05, 14.5), strict=True):
        assert announced.data["cause_t"] == cause_t and announced.data["ring_short"] is False
        assert (announced.data["from_t"], announced.data["to_t"]) == (cause_t - 4.0, end)
        recording = mcap_replay.open_recording(tmp_path / str(announced.data["file"]))
        # the bus as it was, less the recorder's own events (an earlier snapshot's, when it came)
        got = [(round(m.stamp, 9), m.topic, m.payload) for m in recording.messages() if b'"recorder"' not in m.payload]
        expected = [item for item in sent if cause_t - 4.0 <= item[0] <= end]
        assert got == expected  # every message of the window, the sweeps given back exactly
        assert announced.data["messages"] >= len(expected)
        file = tmp_path / str(announced.data["file"])  # the fleet's copy is checked against its digest
        assert (
            announced.data["sha256"] == snapshot_files.sha256_of(file)
            and announced.data["bytes"] == file.stat().st_size
        )
    channels = {c["topic"]: c for c in mcap_replay.info(tmp_path / str(heard[0].data["file"]))["channels"]}
    assert channels[f"ares/{cfg['vehicle_id']}/lidar/roof/points"]["message_encoding"] == "ares.cloud-grid"
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(str(e.data["file"]) for e in heard)


def test_an_operators_request_is_answered_with_its_id_and_one_at_the_end_is_saved_short(tmp_path, cfg):
    settings = SnapshotSettings(enabled=True, before_s=2.0, after_s=5.0)
    request = SnapshotRequest(t=4.0, requested_by="olga", reason="a strange noise", request_id="abc123")
    keeper, sent, heard = drive(tmp_path, cfg, settings, 6.0, {4.0: request})
    assert keeper.stats.saved == 1
    (announced,) = heard
    assert announced.data["cause"] == "request" and announced.data["request_id"] == "abc123"
    assert "olga" in announced.message and "a strange noise" in announced.message
    assert announced.data["to_t"] == 6.0  # the run ended 3 s short of the window's end: saved as it is


def test_the_rings_memory_bound_keeps_the_newest_and_the_snapshot_says_it_is_short(tmp_path, cfg):
    settings = SnapshotSettings(enabled=True, before_s=4.0, after_s=1.0, max_ring_mb=0.05)
    keeper, _, heard = drive(tmp_path, cfg, settings, 8.0, {6.0: event(6.0, "emergency_stop")})
    (announced,) = heard
    assert announced.data["ring_short"] is True and keeper.stats.evicted_early > 0
    assert announced.data["from_t"] > 2.5  # far less than the 4 s before asked for
    assert keeper.stats.ring_bytes <= 0.05e6


@pytest.fixture
def small_disk(tmp_path):
    """A 1 MB filesystem of its own for the snapshots, unmounted after the test."""
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    mount = tmp_path / "snapshot-disk"
    mount.mkdir()
    subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(mount)], check=True)
    try:
        yield mount
    finally:
        subprocess.run(["umount", "-l", str(mount)], check=False)


def test_a_full_disk_is_a_clear_failure_and_leaves_no_half_written_file(small_disk, cfg):
    settings = SnapshotSettings(enabled=True, before_s=4.0, after_s=1.0)
    filler = small_disk / "filler"
    with open(filler, "wb", buffering=0) as f:  # the disk full but for a few kB
        try:
            while True:
                f.write(b"\0" * 4096)
        except OSError:
            pass
    os.truncate(filler, filler.stat().st_size - 16 * 1024)
    folder = small_disk / "snapshots"
    keeper, _, heard = drive(folder, cfg, settings, 7.0, {5.0: event(5.0, "emergency_stop")})
    (announced,) = heard
    assert announced.kind == FAILED_KIND and announced.level == EventLevel.WARNING
    assert "No space left" in str(announced.data["reason"])
    assert keeper.stats.failed == 1 and keeper.stats.saved == 0
    assert list(folder.iterdir()) == []  # the partial file removed


@pytest.mark.parametrize(
    ("kind", "data", "saves"),
    [
        ("emergency_stop", {"cause": "anything"}, True),
        ("mode_change", {"from": "AUTOMATIC", "to": "MANUAL"}, True),
        ("mode_change", {"from": "READY", "to": "MANUAL"}, False),
        ("mode_change", {"from": "MANUAL", "to": "AUTOMATIC"}, False),
        ("awareness", {"level_from": 0, "level_to": 1}, True),
        ("awareness", {"level_from": 1, "level_to": 2}, False),
        ("awareness", {"level_from": 1, "level_to": 1}, False),  # at level 1 already: another cause
        ("awareness", {"level_from": 1, "level_to": 0}, False),
        ("controller_switch", {"from": "mpc", "to": "stop"}, True),
        ("controller_switch", {"from": "mpc", "to": "rrc"}, False),
        ("collision", {"obstacle": "crate1", "obstacle_kind": "crate"}, True),  # the simulator's
        ("controlled_stop", {}, False),
        ("snapshot", {"file": "x.mcap"}, False),
    ],
)
def test_the_default_triggers(kind, data, saves):
    assert any(matches(t, kind, data) for t in SnapshotSettings().triggers) is saves


def test_a_trigger_needs_every_value_it_names():
    trigger = SnapshotTrigger(kind="mode_change", where={"from": "AUTOMATIC", "to": "MANUAL"})
    assert matches(trigger, "mode_change", {"from": "AUTOMATIC", "to": "MANUAL", "cause": "BUTTON"})
    assert not matches(trigger, "mode_change", {"to": "MANUAL"})


def test_names_are_checked_and_old_snapshots_go(tmp_path):
    for bad in ("../etc/passwd.mcap", "a/b.mcap", "x.txt", ".hidden.mcap", ""):
        with pytest.raises(snapshot_files.SnapshotNameError):
            snapshot_files.path_of(tmp_path, bad)
    name = snapshot_files.file_name("shuttle 01", datetime(2026, 12, 4, 8, 0, tzinfo=UTC), "emergency_stop", 3)
    assert name == "20261204T080000Z_shuttle_01_emergency_stop_3.mcap"
    assert snapshot_files.path_of(tmp_path, name) == tmp_path / name
    old, new = tmp_path / "old.mcap", tmp_path / "new.mcap"
    old.write_bytes(b"x")
    new.write_bytes(b"x")
    os.utime(old, (0, 8 * 86400.0))
    assert snapshot_files.prune(tmp_path, 7.0, now=16 * 86400.0) == ["old.mcap"] and new.exists()


# ---- the black box's API ----------------------------------------------------------------------------


@pytest.fixture
def api(tmp_path):
    """An API over a real embedded store holding a snapshot event of this vehicle and one of another
    (both files kept), a third listed whose file is gone; {role: token}."""
    store = open_test_store(tmp_path / "blackbox.sqlite")
    folder = tmp_path / "snapshots"
    folder.mkdir()
    now = datetime.now(UTC)
    files = {
        (VEHICLE, "mine.mcap"): os.urandom(3 << 20),
        (OTHER, "theirs.mcap"): b"their bytes",
        (VEHICLE, "gone.mcap"): None,
    }
    events = []
    for k, ((vehicle, name), content) in enumerate(files.items()):
        if content is not None:
            (folder / name).write_bytes(content)
        events.append(
            StoredEvent(
                vehicle_id=vehicle, time=now - timedelta(minutes=10 - k), t=100.0 + k, source="recorder",
                kind="snapshot", level=EventLevel.INFO, message=f"snapshot of emergency_stop: {name}",
                data={"file": name, "cause": "emergency_stop", "cause_t": 99.0 + k},
            )
        )  # fmt: skip
    events.append(
        StoredEvent(
            vehicle_id=VEHICLE, time=now - timedelta(minutes=11), t=99.0, source="movement_manager",
            kind="emergency_stop", level=EventLevel.FAULT, message="emergency stop: lidar blocked",
        )
    )  # fmt: skip
    store.insert_events(events)
    store.insert_records(
        [
            VehicleRecord(vehicle_id=v, time=now - timedelta(minutes=12), t=1.0, mode="AUTOMATIC")
            for v in (VEHICLE, OTHER)
        ]
    )
    app = create_app(store, api_settings(), VEHICLE_ID, snapshots_dir=folder)
    add_role_users(store, app)
    client = TestClient(app)
    tokens = {role: token_for(client, role) for role in ("auditor", "operator", "fleet")}
    yield client, tokens, files
    store.close()


def test_an_auditor_lists_the_snapshots_beside_their_events_and_downloads_one(api):
    client, tokens, files = api
    h = auth(tokens["auditor"])
    listed = client.get(f"/api/v1/vehicles/{VEHICLE}/snapshots", headers=h)
    assert listed.status_code == 200
    entries = {s["data"]["file"]: s for s in listed.json()["snapshots"]}
    assert set(entries) == {"mine.mcap", "gone.mcap"}
    assert entries["mine.mcap"]["available"] and not entries["gone.mcap"]["available"]
    assert entries["mine.mcap"]["data"]["cause"] == "emergency_stop"
    download = client.get(entries["mine.mcap"]["download"], headers=h)
    assert download.status_code == 200 and download.content == files[(VEHICLE, "mine.mcap")]
    assert download.headers["content-disposition"] == 'attachment; filename="mine.mcap"'
    assert int(download.headers["content-length"]) == 3 << 20
    theirs = client.get(f"/api/v1/vehicles/{OTHER}/snapshots/theirs.mcap", headers=h)
    assert theirs.status_code == 200 and theirs.content == b"their bytes"


def test_an_operator_reads_its_own_vehicles_snapshots_and_is_refused_anothers(api):
    client, tokens, files = api
    h = auth(tokens["operator"])
    assert client.get(f"/api/v1/vehicles/{VEHICLE}/snapshots/mine.mcap", headers=h).status_code == 200
    for path in (f"/api/v1/vehicles/{OTHER}/snapshots/theirs.mcap", f"/api/v1/vehicles/{OTHER}/snapshots"):
        refused = client.get(path, headers=h)
        assert refused.status_code == 403 and VEHICLE in refused.json()["detail"]
    fleet = client.get(f"/api/v1/vehicles/{VEHICLE}/snapshots/mine.mcap", headers=auth(tokens["fleet"]))
    assert fleet.status_code == 403
    assert client.get(f"/api/v1/vehicles/{VEHICLE}/snapshots/mine.mcap").status_code == 401


def test_a_snapshot_not_in_the_black_box_or_no_longer_kept_is_not_served(api):
    client, tokens, _ = api
    h = auth(tokens["auditor"])
    # the file of another vehicle, asked for as this vehicle's: its event is not this vehicle's
    assert client.get(f"/api/v1/vehicles/{VEHICLE}/snapshots/theirs.mcap", headers=h).status_code == 404
    gone = client.get(f"/api/v1/vehicles/{VEHICLE}/snapshots/gone.mcap", headers=h)
    assert gone.status_code == 404 and "not kept here" in gone.json()["detail"]
    assert client.get(f"/api/v1/vehicles/{VEHICLE}/snapshots/..%2Fblackbox.sqlite", headers=h).status_code in (
        404,
        422,
    )
    assert client.get(f"/api/v1/vehicles/{VEHICLE}/snapshots/notes.txt", headers=h).status_code == 422
