"""The fleet's copy of a vehicle's incident snapshots (blackbox/fleet/snapshot_copy.py): a real
recorder and the fleet's sync node on one in-memory network and a manual clock, each with a store
and a snapshots folder of its own, on real files. A snapshot saved while the link is cut is
listed at the fleet once the link is back; a copy the link cuts midway goes on from where it
stopped, no byte asked for twice, paced to the bandwidth bound; the fleet's API serves the copy
to an auditor. A file that is not the one its event describes is not kept; copies older than the
retention go."""

from __future__ import annotations

import os
import time
from datetime import UTC, datetime

import numpy as np
from fastapi.testclient import TestClient

from ares.app import run_config
from ares.core import config
from ares.core.clock import ManualClock
from ares.core.messages import Event, EventLevel
from blackbox.api import create_app
from blackbox.fleet.snapshot_copy import PART_SUFFIX
from blackbox.fleet.sync_node import FleetSync
from blackbox.register import snapshot_files
from blackbox.register.recorder_node import Recorder
from tests.helpers.api import add_role_users, api_settings, auth, open_test_store, token_for
from tests.helpers.stack import NO_LIDARS, wait_until
from tests.test_fleet_sync import UTC_EPOCH, FleetNetwork, _events

VEHICLE = "shuttle01"
RATE = 2.0e6  # B/s
PART = 64 * 1024


def _cfg(vehicle_id: str, tmp_path, overrides: dict | None = None) -> dict:
    return run_config.build(
        (str(NO_LIDARS),),
        config.deep_merge(
            {
                "vehicle_id": vehicle_id,
                "blackbox_store": {"uri": str(tmp_path / f"{vehicle_id}.sqlite")},
                "recording": {"snapshots": {"dir": str(tmp_path / f"{vehicle_id}-snapshots")}},
            },
            overrides or {},
        ),
    )


def _snapshot(folder, name: str, data: bytes, *, sha256: str | None = None) -> Event:
    """A snapshot's file on the vehicle, and the event its recorder publishes."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / name).write_bytes(data)
    digest = sha256 or snapshot_files.sha256_of(folder / name)
    return Event(
        t=5.0,
        source="recorder",
        kind="snapshot",
        level=EventLevel.INFO,
        message=f"snapshot of emergency_stop at 5.0 s: {name}",
        data={"file": name, "cause": "emergency_stop", "bytes": len(data), "sha256": digest},
    )


def test_a_snapshot_saved_during_a_cut_link_is_copied_resuming_where_the_link_stopped_it(tmp_path):
    clock = ManualClock(utc_epoch=UTC_EPOCH)
    network = FleetNetwork()
    recorder = Recorder(_cfg(VEHICLE, tmp_path), clock=clock, bus=network.bus("blackbox", clock, vehicle_id=VEHICLE))
    fleet_cfg = _cfg(
        "fleet",
        tmp_path,
        {
            "fleet_sync": {
                "snapshot_bytes_per_s": RATE,
                "snapshot_part_bytes": PART,
                "snapshot_list_every_s": 0.2,
                "snapshot_retry_s": 0.2,
            }
        },
    )
    # copies older than the retention (7 days) at the fleet: deleted when the copier starts
    old_copies = tmp_path / "fleet-snapshots" / "shuttle02"
    old_copies.mkdir(parents=True)
    for old in ("20261101T000000Z_shuttle02_request_1.mcap", "20261101T000000Z_shuttle02_request_2.mcap.part"):
        (old_copies / old).write_bytes(b"old")
        os.utime(old_copies / old, (time.time() - 8 * 86400,) * 2)
    sync = FleetSync(fleet_cfg, clock=clock, bus=network.bus("fleet_sync", clock, vehicle_id="fleet"))
    vehicle_side = network.bus("supervisor", clock, vehicle_id=VEHICLE)  # where the snapshots' events come from
    for node in (recorder, sync):
        node.setup()
    sync.wall = lambda: UTC_EPOCH + clock.now()
    copier = sync.copier
    assert copier is not None

    # the link is cut when the third piece of the copy has been asked for (in the copier's thread)
    pieces = []

    def call(service, request, **kwargs):
        if service == "blackbox/snapshot_part":
            pieces.append(request.offset)
            if len(pieces) == 3:
                network.cut_link(VEHICLE)
        return sync.bus.call(service, request, **kwargs)

    copier.call = call

    def drive(seconds: float) -> None:
        until = clock.now() + seconds
        while clock.now() < until - 1e-9:
            clock.advance(0.2)
            for node in (recorder, sync):
                node.step_once(clock.now())
            time.sleep(0.01)  # the copier's thread runs on the wall's time

    drive(4.0)  # the fleet hears the vehicle
    network.cut_link(VEHICLE)
    rng = np.random.default_rng(7)
    good = rng.integers(0, 256, 600_000, dtype=np.uint8).tobytes()
    bad = rng.integers(0, 256, 100_000, dtype=np.uint8).tobytes()
    folder = tmp_path / f"{VEHICLE}-snapshots"
    good_name, bad_name = (
        "20261207T120000Z_shuttle01_emergency_stop_1.mcap",
        "20261207T120100Z_shuttle01_request_2.mcap",
    )
    vehicle_side.publish("events", _snapshot(folder, good_name, good))
    vehicle_side.publish("events", _snapshot(folder, bad_name, bad, sha256="0" * 64))  # not this file's
    drive(2.0)  # stored on the vehicle; the fleet hears nothing of it
    network.heal(VEHICLE)

    fleet_copy = tmp_path / "fleet-snapshots" / VEHICLE / good_name
    wait_until(lambda: copier.stats.interrupted >= 1, 60, "the link cut during the copy", interval_s=0.05)
    part = fleet_copy.with_name(good_name + PART_SUFFIX)
    assert part.is_file() and 0 < part.stat().st_size < len(good)  # what arrived is kept
    drive(1.0)
    network.heal(VEHICLE)

    def copied() -> bool:
        drive(0.2)
        return fleet_copy.is_file() and copier.stats.mismatched >= 2

    wait_until(copied, 120, "the copy done", interval_s=0.01)
    drive(1.0)  # the copier's events into the fleet's store
    for node in (recorder, sync):
        node.teardown()
        node.bus.close()

    assert fleet_copy.read_bytes() == good and not part.exists()
    # no byte asked for twice, but the damaged file's, copied twice then given up
    assert copier.stats.resumed >= 1 and copier.stats.bytes == len(good) + 2 * len(bad)
    assert copier.stats.mismatched == 2
    assert copier.stats.pruned == 2 and not list(old_copies.iterdir())
    assert all(offset % PART == 0 for offset in pieces)  # each piece from where the one before ended
    # the bound: the pieces came no faster than RATE on average (a lower bound on the waits, never a timing bound)
    assert copier.stats.paced_s >= (copier.stats.bytes - 3 * PART) / RATE - 0.05
    assert not (tmp_path / "fleet-snapshots" / VEHICLE / bad_name).exists()
    assert not (tmp_path / "fleet-snapshots" / VEHICLE / (bad_name + PART_SUFFIX)).exists()

    at_fleet = _events(tmp_path / "fleet.sqlite", VEHICLE)
    listed = [e["data"]["file"] for e in at_fleet if e["kind"] == "snapshot"]
    assert sorted(listed) == sorted([good_name, bad_name])  # from the listing: the live events never came, none twice
    assert [e["data"]["file"] for e in at_fleet if e["kind"] == "snapshot_copied"] == [good_name]
    failed = [e for e in at_fleet if e["kind"] == "snapshot_copy_failed"]
    assert [e["data"]["file"] for e in failed] == [bad_name, bad_name] and "given up" in failed[1]["message"]

    # the fleet's API serves the copy to an auditor
    store = open_test_store(tmp_path / "fleet.sqlite")
    app = create_app(store, api_settings(), "fleet", snapshots_dir=tmp_path / "fleet-snapshots")
    add_role_users(store, app)
    client = TestClient(app)
    auditor = auth(token_for(client, "auditor"))
    # the window from the test's hour on (the default one, the last hour, may begin after it)
    since = {"start": datetime.fromtimestamp(UTC_EPOCH - 3600, UTC).isoformat()}
    listed = client.get(f"/api/v1/vehicles/{VEHICLE}/snapshots", params=since, headers=auditor)
    entries = listed.json()["snapshots"]
    assert {e["data"]["file"]: e["available"] for e in entries} == {good_name: True, bad_name: False}
    got = client.get(f"/api/v1/vehicles/{VEHICLE}/snapshots/{good_name}", headers=auditor)
    assert got.status_code == 200 and got.content == good
    assert client.get(f"/api/v1/vehicles/{VEHICLE}/snapshots/{bad_name}", headers=auditor).status_code == 404
    store.close()
