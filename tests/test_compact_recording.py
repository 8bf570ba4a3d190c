"""Recordings a fleet can keep (docs/recording.md): a LiDAR's sweep stored as integers on its sensor's
grid and given back byte for byte (ares.core.cloud_grid, ares.app.bus_record.cloud_payload), the
recorder's compact clouds and Foxglove previews, and the light profile's decimation. In memory."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ares.app import run_config
from ares.app.bus_record import cloud_payload, mcap_replay
from ares.app.bus_record.foxglove_views import FoxgloveViews
from ares.app.bus_record.recorder import McapRecorder, lidar_grids, light_rate
from ares.core import cloud_grid, schema
from ares.core.clock import ManualClock
from ares.core.config import RecordingSettings, load_vehicle
from ares.core.membus import MemoryNetwork
from ares.core.messages import ClockDone, ClockTick, Event, PointCloud
from ares.core.route import Route
from simulator.lidar import LidarSimParams, SimulatedLidar, vehicle_pose
from simulator.params import SimParams
from simulator.road import roughness_for
from simulator.world import World
from tests.helpers.recording import ROOF_GRID, on_grid_cloud, payload_of, pose

UTC_EPOCH = 1_790_000_000.0
# ---- the grid and the payload ---------------------------------------------------------------------


@pytest.fixture(scope="module")
def tour_world() -> tuple[Route, World]:
    tour = Route.from_tour("default")
    return tour, World(tour, roughness_for(tour, SimParams(), 2.8))


def simulated_frame(tour_world, s: float, t: float, decimation: int = 4, names=("roof",)) -> dict[str, PointCloud]:
    """The simulated shuttle's LiDARs at `s` along the default tour, ghosts and all, stamped t."""
    tour, world = tour_world
    shuttle = load_vehicle("ares_shuttle")
    params = LidarSimParams(azimuth_decimation=decimation)
    x, y, _, yaw = tour.point_at(s)
    rotation, position = vehicle_pose(x, y, float(world.centre_height(s)), yaw, 0.0)
    frame = {}
    for k, name in enumerate(names):
        sensor = SimulatedLidar(name, shuttle.lidars[name], shuttle, params, np.random.default_rng(int(t * 10) + k))
        sweep = sensor.sweep(world.scene, rotation, position, None, world.material_of)
        frame[name] = PointCloud(
            t=t, sensor=name, frame=f"lidar/{name}", x=sweep.x, y=sweep.y, z=sweep.z, intensity=sweep.intensity,
            ring=sweep.ring,
        )  # fmt: skip
    return frame


@pytest.fixture(scope="module")
def simulated_sweep(tour_world) -> tuple[PointCloud, cloud_grid.SensorGrid]:
    """A roof sweep of the simulated shuttle on the default tour, ghosts and all."""
    cloud = simulated_frame(tour_world, 120.0, 1.0)["roof"]
    return cloud, lidar_grids(run_config.build((), {"lidars": True}))["lidar/roof/points"]


def test_a_simulated_sweep_is_stored_on_its_grid_and_comes_back_byte_for_byte(simulated_sweep):
    cloud, grid = simulated_sweep
    payload = payload_of(cloud)
    stored, off_grid = cloud_payload.compact(payload, grid)
    assert cloud.size > 5000 and off_grid == 0  # the simulator places every point on the sensor's grid
    assert stored[:4] == cloud_payload.GRID_MAGIC and len(stored) < len(payload) / 2.5
    assert cloud_payload.restore(stored, grid) == payload


def test_points_off_the_grid_are_kept_as_they_are_and_come_back_too():
    cloud = on_grid_cloud(1.0)
    moved = np.array(cloud.x)
    moved[[3, 700, 1999]] += np.float32(1e-3)  # a driver's calibration, say: off the grid
    payload = payload_of(cloud.model_copy(update={"x": moved}))
    stored, off_grid = cloud_payload.compact(payload, ROOF_GRID)
    assert off_grid == 3 and stored[:4] == cloud_payload.GRID_MAGIC
    assert cloud_payload.restore(stored, ROOF_GRID) == payload


def test_a_cloud_mostly_off_the_grid_or_not_a_cloud_is_stored_as_it_travelled():
    rng = np.random.default_rng(0)
    n = 300
    scattered = PointCloud(
        t=1.0, sensor="roof", frame="lidar/roof", x=rng.normal(size=n).astype("<f4"),
        y=rng.normal(size=n).astype("<f4"), z=rng.normal(size=n).astype("<f4"),
        intensity=rng.random(n).astype("<f4"), ring=rng.integers(0, 64, n).astype("u1"),
    )  # fmt: skip
    for payload in (payload_of(scattered), b'{"t": 1.0}', b"ARB1\x05\x00\x00\x00{bad}", b""):
        stored, _ = cloud_payload.compact(payload, ROOF_GRID)
        assert stored == payload and cloud_payload.restore(stored, ROOF_GRID) == payload


def test_an_empty_sweep_and_a_ring_the_grid_does_not_have_come_back_exactly():
    empty = on_grid_cloud(1.0, n=0)
    stored, _ = cloud_payload.compact(payload_of(empty), ROOF_GRID)
    assert cloud_payload.restore(stored, ROOF_GRID) == payload_of(empty)
    small_grid = cloud_grid.SensorGrid(ROOF_GRID.elevations_deg[:16])
    stored, off_grid = cloud_payload.compact(payload_of(on_grid_cloud(2.0, n=64)), small_grid)
    assert off_grid == 48  # rings 16..63 are not the small sensor's: kept as float32 (too many: as is)
    assert cloud_payload.restore(stored, small_grid) == payload_of(on_grid_cloud(2.0, n=64))


def test_a_damaged_compact_cloud_is_a_clear_error():
    stored, _ = cloud_payload.compact(payload_of(on_grid_cloud(1.0)), ROOF_GRID)
    with pytest.raises(cloud_payload.CloudPayloadError, match="names no grid"):
        cloud_payload.restore(stored, None)
    with pytest.raises(cloud_payload.CloudPayloadError, match="malformed"):
        cloud_payload.restore(stored[: len(stored) // 2], ROOF_GRID)


@settings(max_examples=60, deadline=None)
@given(
    ring=st.lists(st.integers(0, 63), min_size=1, max_size=80),
    seed=st.integers(0, 2**32 - 1),
)
def test_any_point_placed_on_the_grid_comes_back_with_the_same_bits(ring, seed):
    rng = np.random.default_rng(seed)
    n = len(ring)
    rings = np.asarray(ring, dtype=np.uint8)
    azimuth = rng.integers(0, cloud_grid.AZIMUTH_STEPS, n).astype(np.uint16)
    range_ = rng.integers(0, cloud_grid.MAX_RANGE_STEPS + 1, n).astype(np.uint16)
    x, y, z = cloud_grid.place(ROOF_GRID, rings, azimuth, range_)
    intensity = cloud_grid.intensity_of(rng.integers(0, 256, n).astype(np.uint8))
    on_grid = cloud_grid.to_grid(ROOF_GRID, x, y, z, intensity, rings)
    back = cloud_grid.from_grid(ROOF_GRID, on_grid)
    for before, after in zip((x, y, z, intensity), back, strict=True):
        assert before.view(np.uint32).tolist() == after.view(np.uint32).tolist()


def test_the_azimuth_of_any_angle_is_a_step_of_one_turn():
    steps = cloud_grid.azimuth_steps(np.array([-math.pi, -1e-9, 0.0, 2 * math.pi - 1e-9, 7 * math.pi]))
    assert steps.tolist() == [18000, 0, 0, 0, 18000]


# ---- the recorder ------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def cfg():
    return run_config.build((), {"lidars": True})


def record(path, cfg, settings: RecordingSettings, seconds: float = 3.0, jump_back_at: float | None = None):
    """Poses at 20 Hz, roof sweeps at 10 Hz, an event a second, through a MemoryNetwork; the
    payloads published, by topic."""
    clock = ManualClock()
    network = MemoryNetwork(cfg["vehicle_id"])
    recorder = McapRecorder(path, cfg, utc_epoch=UTC_EPOCH, views=FoxgloveViews(cfg, UTC_EPOCH), settings=settings)
    recorder.attach(network.bus("recorder", clock))
    recorder.start()
    feeder = network.bus("sim", clock)
    sent: dict[str, list[bytes]] = {}
    for k in range(1, round(seconds * 20) + 1):
        t = round(k * 0.05, 9)
        clock.set(t)
        if jump_back_at is not None and t > jump_back_at:
            t = round(t - 1.0, 9)  # the stamps stepped back a second (a clock set back)
        outgoing: list[tuple[str, object]] = [("localization/pose", pose(t))]
        if k % 2 == 0:
            outgoing.append(("lidar/roof/points", on_grid_cloud(t)))
        if k % 20 == 0:
            outgoing.append(("events", Event(t=t, source="test", kind="tick", message="a second")))
        for topic, msg in outgoing:
            feeder.publish(topic, msg)
            sent.setdefault(topic, []).append(bytes(schema.encode(msg)))
    return recorder.close(), sent


def test_the_full_profile_stores_each_sweep_once_on_its_grid_and_replays_it_exactly(tmp_path, cfg):
    path = tmp_path / "full.mcap"
    stats, sent = record(path, cfg, RecordingSettings(), seconds=3.0)
    assert stats.dropped == 0 and stats.off_grid_points == 0
    channels = {c["topic"]: c for c in mcap_replay.info(path)["channels"]}
    raw = channels[f"ares/{cfg['vehicle_id']}/lidar/roof/points"]
    assert (raw["schema"], raw["message_encoding"], raw["messages"]) == ("PointCloud", "ares.cloud-grid", 30)
    assert channels["foxglove/lidar/roof/points"]["messages"] == 3  # a preview a second
    assert stats.stored_by_topic["lidar/roof/points"] < sum(map(len, sent["lidar/roof/points"])) / 2.5
    recorded: dict[str, list[bytes]] = {}
    for message in mcap_replay.open_recording(path).messages():
        recorded.setdefault(message.topic, []).append(message.payload)
    assert recorded == sent


def test_float32_clouds_and_no_previews_when_asked(tmp_path, cfg):
    path = tmp_path / "float.mcap"
    stats, sent = record(path, cfg, RecordingSettings(cloud_encoding="float32", cloud_view_every_s=0), seconds=1.0)
    channels = {c["topic"]: c for c in mcap_replay.info(path)["channels"]}
    assert channels[f"ares/{cfg['vehicle_id']}/lidar/roof/points"]["message_encoding"] == "ares.bulk"
    assert "foxglove/lidar/roof/points" not in channels
    assert stats.stored_by_topic["lidar/roof/points"] == sum(map(len, sent["lidar/roof/points"]))


def test_the_light_profile_keeps_each_topic_at_its_rate_and_no_clouds(tmp_path, cfg):
    path = tmp_path / "light.mcap"
    settings = RecordingSettings(profile="light")
    stats, sent = record(path, cfg, settings, seconds=3.0)
    recorded: dict[str, list[bytes]] = {}
    for message in mcap_replay.open_recording(path).messages():
        recorded.setdefault(message.topic, []).append(message.payload)
    assert set(recorded) == {"localization/pose", "events"}
    assert recorded["events"] == sent["events"]  # every event
    assert settings.light_rates_hz["localization/pose"] == 5
    assert recorded["localization/pose"] == sent["localization/pose"][::4]  # 20 Hz kept at 5 Hz
    assert stats.skipped == 30 + 45 and stats.dropped == 0


def test_the_light_profile_starts_its_count_again_after_the_clock_went_back(tmp_path, cfg):
    path = tmp_path / "light.mcap"
    _, sent = record(path, cfg, RecordingSettings(profile="light"), seconds=2.0, jump_back_at=1.0)
    stamps = [m.stamp for m in mcap_replay.open_recording(path).messages() if m.topic == "localization/pose"]
    assert stamps == [0.05, 0.25, 0.45, 0.65, 0.85, 0.05, 0.25, 0.45, 0.65, 0.85]


def test_light_rates_name_topics_or_families_and_leave_out_the_rest(cfg):
    settings = RecordingSettings()
    assert light_rate(settings, "heartbeat/path_manager") == 0.2
    assert light_rate(settings, "events") == 0
    assert light_rate(settings, "lidar/roof/points") is None and light_rate(settings, "perception/grid") is None


def test_every_lidar_of_the_profile_has_its_grid(cfg):
    grids = lidar_grids(cfg)
    assert set(grids) == {"lidar/roof/points", "lidar/front_left/points", "lidar/front_right/points"}
    assert grids["lidar/roof/points"].rings == 64 and grids["lidar/front_left/points"].rings == 16


def test_the_record_option_names_a_profile_a_file_or_both():
    from ares.app.bus_record.in_run import record_target

    assert record_target("") == (None, "")
    assert record_target("full") == ("full", "")
    assert record_target("light") == ("light", "")
    assert record_target("light:/tmp/day.mcap") == ("light", "/tmp/day.mcap")
    assert record_target("run.mcap") == (None, "run.mcap")
    assert record_target("weird:name.mcap") == (None, "weird:name.mcap")


def test_the_lidar_perception_replays_identically_from_a_compact_recording(tmp_path, cfg, tour_world):
    """As at --speed max: the node steps at its ticks, the simulator's sweeps of a tick reach it
    after its step (it perceives them at the next and stamps its grid with the sweep's time); the
    clouds recorded on their grid, the node replayed from the file."""
    from perception.lidar_perception_node import LidarPerception

    run_cfg = {**cfg, "lockstep": {**cfg["lockstep"], "participants": ["lidar_perception"]}}
    path = tmp_path / "perception.mcap"
    clock = ManualClock()
    network = MemoryNetwork(run_cfg["vehicle_id"])
    recorder = McapRecorder(path, run_cfg, utc_epoch=UTC_EPOCH, settings=RecordingSettings())
    recorder.attach(network.bus("recorder", clock))
    recorder.start()
    node = LidarPerception(run_cfg, clock=clock, bus=network.bus("lidar_perception", clock))
    feeder = network.bus("sim", clock)
    node.setup()
    feeder.publish("clock/done", ClockDone(t=0.0, process="lidar_perception", next_due=0.1))
    names = ("roof", "front_left", "front_right")
    for k in range(1, 7):
        t = round(k * 0.1, 9)
        clock.set(t)
        feeder.publish("sim/clock/lidar_perception", ClockTick(t=t))
        node.step_once(t)
        feeder.publish("clock/done", ClockDone(t=t, process="lidar_perception", next_due=round(t + 0.1, 9)))
        for name, sweep in simulated_frame(tour_world, 200.0 + 0.3 * k, t, decimation=8, names=names).items():
            feeder.publish(f"lidar/{name}/points", sweep)
    node.teardown()
    stats = recorder.close()
    assert stats.off_grid_points == 0 and stats.dropped == 0
    result = mcap_replay.replay_node(path, "lidar_perception")
    assert result.ok, result.mismatches[:3]
    assert result.steps == 6 and result.outputs == 5 * 3  # grid, road and status from the second step on


# ---- a driver's clouds: real captures ----------------------------------------------------------------

LIDAR_CAPTURES = Path(__file__).parent / "data" / "lidar"


def driver_rotations(name: str, model: str, count: int = 2) -> list[PointCloud]:
    """Whole rotations of a real capture (tests/data/lidar), decoded by the driver's own assembler,
    as the driver publishes them."""
    from ares.core.wire.pcap import udp_datagrams
    from ares.core.wire.velodyne import RotationAssembler, load_calibration

    assembler = RotationAssembler(load_calibration(model), rate_hz=5.0)
    clouds: list[PointCloud] = []
    for datagram in udp_datagrams(LIDAR_CAPTURES / name):
        if datagram.port != 2368:
            continue
        for rotation in assembler.add(datagram.payload, datagram.time):
            if not rotation.truncated and len(clouds) < count:
                p = rotation.points
                clouds.append(
                    PointCloud(t=float(len(clouds)), sensor="roof", frame="lidar/roof", x=p.x, y=p.y, z=p.z,
                               intensity=p.intensity, ring=p.ring)
                )  # fmt: skip
        if len(clouds) >= count:
            break
    return clouds


@pytest.mark.parametrize(
    ("name", "model"),
    [("VLP-16_dual.pcap", "VLP-16"), ("HDL-32E.pcap", "HDL-32E"), ("VLP-32C_fov.pcap", "VLP-32C"),
     ("VLS-128.pcap", "VLS-128")],
)  # fmt: skip
def test_a_drivers_clouds_of_real_captures_are_stored_as_their_packets_integers(name, model):
    from ares.core.wire.velodyne import load_calibration
    from ares.core.wire.velodyne_grid import VelodyneGrid

    grid = VelodyneGrid(load_calibration(model))
    again = cloud_payload.grid_from(grid.describe())  # as a recording's channel describes it
    for cloud in driver_rotations(name, model):
        payload = payload_of(cloud)
        stored, off_grid = cloud_payload.compact(payload, grid)
        assert cloud.size > 10_000 and off_grid == 0, (cloud.size, off_grid)
        assert len(stored) < len(payload) / 2.5
        assert cloud_payload.restore(stored, again) == payload


@pytest.mark.parametrize(
    ("payload", "stamp"),
    [
        (b'{"t":1.25,"x":1.0}', 1.25),
        (b'{"t":3}', 3.0),
        (b'{"t":null,"x":1}', None),
        (b'{"t":"soon","x":1}', None),
        (b'{"x":1.0,"t":2.5}', 2.5),  # not first: the whole message read
        (b'{"t":1.0', None),  # cut short
        (b"not json", None),
    ],
)
def test_a_payloads_stamp_is_read_without_decoding_it(payload, stamp):
    from ares.app.bus_record.recorder import stamp_of

    assert stamp_of(payload) == stamp
