"""MCAP recordings of the bus (ares.app.bus_record): a channel per key with its schema, Foxglove's
views of poses, clouds and the grid, a file cut short still read, and one node replayed from a
recording of the whole bus against its recorded outputs. In memory: a MemoryNetwork, a ManualClock."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from foxglove.messages import FrameTransform, FrameTransforms
from mcap.records import Schema as McapSchema
from mcap_protobuf.decoder import DecoderFactory

from ares.app import run_config
from ares.app.bus_record import mcap_replay
from ares.app.bus_record.foxglove_views import SCHEMAS, FoxgloveViews, View
from ares.app.bus_record.recorder import McapRecorder, stamp_of
from ares.core import config
from ares.core.clock import ManualClock
from ares.core.membus import MemoryNetwork
from ares.core.messages import ClockDone, ClockTick, OccupancyGrid, PointCloud, Pose
from ares.core.node import Input, Node
from ares.core.route import load_route
from managers.path_node import PathManager

UTC_EPOCH = 1_790_000_000.0


@pytest.fixture(scope="module")
def cfg():
    return run_config.build((), {"lidars": True})


@pytest.fixture(scope="module")
def route(cfg):
    return load_route(config.core(cfg))


def pose_on(route, s: float, t: float) -> Pose:
    x, y, z, yaw = route.point_at(s)
    return Pose(
        t=t, x=x, y=y, z=z, yaw=yaw, v=2.0, yaw_rate=0.0, cov_xx=0.01, cov_xy=0.0, cov_yy=0.01,
        var_yaw=1e-4, var_v=0.01, position_std_m=0.1, rtk=True, gnss_age_s=0.1,
    )  # fmt: skip


def cloud(t: float, n: int = 500) -> PointCloud:
    rng = np.random.default_rng(int(t * 10))
    return PointCloud(
        t=t,
        sensor="roof",
        frame="lidar/roof",
        x=rng.normal(size=n).astype("<f4"),
        y=rng.normal(size=n).astype("<f4"),
        z=rng.normal(size=n).astype("<f4"),
        intensity=rng.random(n).astype("<f4"),
        ring=rng.integers(0, 64, n).astype("u1"),
    )


def record_drive(path, cfg, route, *, node_cfg=None, lockstep=False, steps=40, stopped_at_a_tick=False):
    """A path manager driven along the route on the in-memory bus, everything recorded; the
    simulator's part (poses, a cloud, the grid, the ticks) played by a feeder."""
    clock = ManualClock()
    network = MemoryNetwork(cfg["vehicle_id"])
    recorder = McapRecorder(path, cfg, utc_epoch=UTC_EPOCH, views=FoxgloveViews(cfg, UTC_EPOCH), route=route)
    recorder.attach(network.bus("recorder", clock))
    recorder.start()
    node = PathManager(node_cfg or cfg, clock=clock, bus=network.bus("path_manager", clock))
    feeder = network.bus("sim", clock)
    node.setup()
    if lockstep:  # the node joins the lockstep: its first step is due at the first tick
        feeder.publish("clock/done", ClockDone(t=0.0, process="path_manager", next_due=0.05))
    for k in range(1, steps + 1):
        t = round(k * 0.05, 9)
        clock.set(t)
        feeder.publish("localization/pose", pose_on(route, 2.0 + 0.1 * k, t))
        if k % 10 == 0:
            feeder.publish("lidar/roof/points", cloud(t))
            feeder.publish(
                "perception/grid",
                OccupancyGrid(t=t, frame="vehicle", resolution_m=0.2, origin_x=-10, origin_y=-10,
                              cells=np.full((100, 100), 255, "u1")),
            )  # fmt: skip
        if lockstep:
            feeder.publish("sim/clock/path_manager", ClockTick(t=t))
        node.step_once(t)
        if lockstep:
            feeder.publish("clock/done", ClockDone(t=t, process="path_manager", next_due=round(t + 0.05, 9)))
    if stopped_at_a_tick:  # the run stopped (`--seconds`) with the last tick recorded, not the step's outputs
        t = round((steps + 1) * 0.05, 9)
        clock.set(t)
        feeder.publish("localization/pose", pose_on(route, 2.0 + 0.1 * (steps + 1), t))
        feeder.publish("sim/clock/path_manager", ClockTick(t=t))
    node.teardown()
    return recorder.close()


def test_a_channel_per_key_with_its_schema_and_foxglove_views(tmp_path, cfg, route):
    path = tmp_path / "run.mcap"
    stats = record_drive(path, cfg, route)
    assert stats.dropped == 0
    found = mcap_replay.info(path)
    assert found["complete"] and found["vehicle_id"] == cfg["vehicle_id"]
    channels = {c["topic"]: c for c in found["channels"]}
    prefix = f"ares/{cfg['vehicle_id']}"
    pose = channels[f"{prefix}/localization/pose"]
    assert (pose["schema"], pose["schema_encoding"], pose["message_encoding"]) == ("Pose", "jsonschema", "json")
    assert pose["messages"] == 40
    points = channels[f"{prefix}/lidar/roof/points"]
    assert (points["schema"], points["message_encoding"], points["messages"]) == ("PointCloud", "ares.cloud-grid", 4)
    assert channels[f"{prefix}/path/match"]["messages"] == 40
    known = {
        "foxglove/pose/location": "foxglove.LocationFix",
        "foxglove/tf": "foxglove.FrameTransforms",
        "foxglove/lidar/roof/points": "foxglove.PointCloud",
        "foxglove/perception/grid": "foxglove.Grid",
        "foxglove/path/ahead": "foxglove.SceneUpdate",
        "foxglove/route": "foxglove.SceneUpdate",
    }
    for topic, schema_name in known.items():
        assert (channels[topic]["schema"], channels[topic]["message_encoding"]) == (schema_name, "protobuf"), topic
    assert channels["foxglove/route"]["messages"] == 1


def test_raw_channels_give_back_the_payloads_exactly(tmp_path, cfg, route):
    path = tmp_path / "run.mcap"
    record_drive(path, cfg, route)
    recording = mcap_replay.open_recording(path)
    assert recording.cfg == cfg
    clouds = [r for r in recording.messages() if r.topic == "lidar/roof/points"]
    assert [round(r.stamp, 9) for r in clouds] == [0.5, 1.0, 1.5, 2.0]
    again = PointCloud.model_validate(
        {name: getattr(mcap_replay.schema.decode(clouds[0].payload, PointCloud), name) for name in PointCloud.ARRAYS}
        | {"t": 0.5, "sensor": "roof", "frame": "lidar/roof"}
    )
    expected = cloud(0.5)
    assert np.array_equal(again.x, expected.x) and np.array_equal(again.ring, expected.ring)
    assert stamp_of(clouds[0].payload) == 0.5


_decoders = DecoderFactory()


def decoded(view):
    """A view's protobuf bytes decoded with the schema it travels with (as Foxglove reads them)."""
    schema = McapSchema(id=hash(view.schema.name) & 0xFFFF, name=view.schema.name, encoding="protobuf",
                        data=bytes(view.schema.data))  # fmt: skip
    return _decoders.decoder_for("protobuf", schema)(view.data)


def test_the_views_put_the_shuttle_on_the_map_and_its_lidars_on_it(cfg, route):
    views = FoxgloveViews(cfg, UTC_EPOCH)
    pose = pose_on(route, 10.0, 3.25)
    made = {v.topic: v for v in views.views("localization/pose", pose)}
    fix = decoded(made["foxglove/pose/location"])
    lat, lon = views.frame.to_latlon(pose.x, pose.y)
    assert (fix.latitude, fix.longitude) == (lat, lon)
    assert math.isclose(fix.heading, (math.pi / 2 - pose.yaw) % (2 * math.pi))
    assert (fix.timestamp.seconds, fix.timestamp.nanos) == (1_790_000_003, 250_000_000)
    tf = decoded(made["foxglove/tf"]).transforms
    body, mounts = tf[0], tf[1:]
    assert (body.parent_frame_id, body.child_frame_id) == ("local", "vehicle")
    assert (body.translation.x, body.translation.y) == (pose.x, pose.y)
    assert math.isclose(2 * math.atan2(body.rotation.z, body.rotation.w), pose.yaw)
    lidars = config.core(cfg).vehicle_profile.lidars
    assert sorted(m.child_frame_id for m in mounts) == sorted(f"lidar/{n}" for n in lidars)
    roof = next(m for m in mounts if m.child_frame_id == "lidar/roof")
    assert roof.translation.z == lidars["roof"].xyz_m[2]


def test_clouds_and_the_grid_as_foxglove_draws_them():
    cfg = config.core_defaults()
    views = FoxgloveViews(cfg, UTC_EPOCH)
    sweep = cloud(1.0, n=7)
    (view,) = views.views("lidar/roof/points", sweep)
    points = decoded(view)
    assert (view.topic, points.frame_id, points.point_stride) == ("foxglove/lidar/roof/points", "lidar/roof", 16)
    assert [(f.name, f.offset) for f in points.fields] == [("x", 0), ("y", 4), ("z", 8), ("intensity", 12)]
    packed = np.frombuffer(points.data, dtype="<f4").reshape(-1, 4)
    assert np.array_equal(packed[:, 0], sweep.x) and np.array_equal(packed[:, 3], sweep.intensity)
    cells = np.arange(100 * 120, dtype=np.uint32).astype("u1").reshape(100, 120)
    grid = OccupancyGrid(t=1.0, frame="vehicle", resolution_m=0.2, origin_x=-10, origin_y=-12, cells=cells)
    (view,) = views.views("perception/grid", grid)
    decoded_grid = decoded(view)
    assert (decoded_grid.column_count, decoded_grid.row_stride, decoded_grid.cell_size.x) == (120, 120, 0.2)
    assert (decoded_grid.pose.position.x, decoded_grid.pose.position.y) == (-10, -12)
    assert decoded_grid.data == cells.tobytes()


def test_a_lidar_mount_rotates_as_the_profile_says():
    """ZYX: a LiDAR pitched 90 degrees nose down looks along -z of the vehicle."""
    from ares.app.bus_record.foxglove_views import quaternion_rpy

    view = View("q", SCHEMAS["FrameTransforms"], FrameTransforms(transforms=[
        FrameTransform(rotation=quaternion_rpy(0.0, math.pi / 2, 0.0))]).encode())  # fmt: skip
    q = decoded(view).transforms[0].rotation
    # rotate the sensor's x axis (1, 0, 0) by q
    x_axis = (1 - 2 * (q.y**2 + q.z**2), 2 * (q.x * q.y + q.w * q.z), 2 * (q.x * q.z - q.w * q.y))
    assert np.allclose(x_axis, (0.0, 0.0, -1.0))


def test_a_recording_cut_short_is_read_up_to_its_last_complete_chunk(tmp_path, cfg, route):
    path = tmp_path / "run.mcap"
    clock = ManualClock()
    network = MemoryNetwork(cfg["vehicle_id"])
    recorder = McapRecorder(path, cfg, utc_epoch=UTC_EPOCH, chunk_size=4096)  # small chunks: several written
    recorder.attach(network.bus("recorder", clock))
    recorder.start()
    feeder = network.bus("sim", clock)
    for k in range(400):
        feeder.publish("localization/pose", pose_on(route, 2.0 + 0.1 * k, k * 0.05))
    recorder.close()
    whole = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(whole[: len(whole) // 2])  # as a writer killed in mid-file leaves it
    found = mcap_replay.info(cut)
    assert not found["complete"] and found["cut_short"]
    poses = [r for r in mcap_replay.open_recording(cut).messages() if r.topic == "localization/pose"]
    assert 80 <= len(poses) < 400  # the chunks wholly in the first half (the summary fills much of the end)
    assert [round(r.stamp, 9) for r in poses] == [round(k * 0.05, 9) for k in range(len(poses))]


@pytest.mark.parametrize("lockstep", [False, True], ids=["by output stamps", "by lockstep ticks"])
def test_replaying_a_node_reproduces_its_recorded_outputs(tmp_path, cfg, route, lockstep):
    run_cfg = {**cfg, "lockstep": {**cfg["lockstep"], "participants": ["path_manager"] if lockstep else []}}
    path = tmp_path / "run.mcap"
    record_drive(path, run_cfg, route, lockstep=lockstep)
    result = mcap_replay.replay_node(path, "path_manager")
    assert result.ok, [str(m) for m in result.mismatches[:3]]
    assert result.steps == 40 and result.outputs >= 40


def test_a_recording_stopped_at_a_tick_replays_without_a_mismatch(tmp_path, cfg, route):
    """A run stopped by `--seconds` records the last tick but not the step's outputs: that step
    could not have been recorded, so it is stepped and counted, not compared."""
    run_cfg = {**cfg, "lockstep": {**cfg["lockstep"], "participants": ["path_manager"]}}
    path = tmp_path / "run.mcap"
    record_drive(path, run_cfg, route, lockstep=True, steps=20, stopped_at_a_tick=True)
    result = mcap_replay.replay_node(path, "path_manager")
    assert result.ok, [str(m) for m in result.mismatches[:3]]
    assert result.unrecorded_steps == 1 and result.outputs >= 20


@pytest.mark.parametrize("lockstep", [False, True], ids=["by output stamps", "by lockstep ticks"])
def test_replay_shows_a_node_that_behaves_otherwise(tmp_path, cfg, route, lockstep):
    """The recorded outputs came from a path manager sending a shorter path ahead than the run's
    configuration says: replayed with that configuration, its path ahead differs, whichever inputs
    the replay tries to latch."""
    run_cfg = {**cfg, "lockstep": {**cfg["lockstep"], "participants": ["path_manager"] if lockstep else []}}
    half = cfg["path_manager"]["ahead_length_m"] / 2
    shorter = {**run_cfg, "path_manager": {**cfg["path_manager"], "ahead_length_m": half}}
    path = tmp_path / "run.mcap"
    record_drive(path, run_cfg, route, node_cfg=shorter, lockstep=lockstep)
    result = mcap_replay.replay_node(path, "path_manager")
    assert not result.ok
    assert result.mismatches[0].where.startswith("path/match.ahead_")


def test_playing_a_recording_into_a_bus(tmp_path, cfg, route):
    path = tmp_path / "run.mcap"
    record_drive(path, cfg, route)
    clock = ManualClock()
    network = MemoryNetwork(cfg["vehicle_id"])
    listener = network.bus("listener", clock)
    poses = listener.subscribe("localization/pose", queue=100)
    clouds = listener.subscribe("lidar/roof/points", queue=10)
    sent = mcap_replay.play(mcap_replay.open_recording(path), network.bus("replay", clock), speed=None)
    assert sent["localization/pose"] == 40 and sent["path/match"] == 40
    assert [round(m.t, 9) for _, m in poses.drain()] == [round(k * 0.05, 9) for k in range(1, 41)]
    assert len(clouds.drain()) == 4


def test_replay_finds_what_the_node_latched_when_the_recorder_heard_it_late(tmp_path, cfg, route):
    """On a loaded machine a pose reaches the node before its step but the recorder only after
    the step's output: the replay tries the step latching it too, and the outputs decide."""
    run_cfg = {**cfg, "lockstep": {**cfg["lockstep"], "participants": ["path_manager"]}}
    clock = ManualClock()
    network = MemoryNetwork(cfg["vehicle_id"])
    heard: list[tuple[str, str, bytes]] = []
    network.bus("tap", clock).subscribe_raw("**", lambda *message: heard.append(message))
    node = PathManager(run_cfg, clock=clock, bus=network.bus("path_manager", clock))
    feeder = network.bus("sim", clock)
    node.setup()
    feeder.publish("clock/done", ClockDone(t=0.0, process="path_manager", next_due=0.05))
    late = set()
    for k in range(1, 41):
        t = round(k * 0.05, 9)
        clock.set(t)
        feeder.publish("localization/pose", pose_on(route, 2.0 + 0.1 * k, t - 0.01))
        if k % 3 == 0:  # this pose reached the recorder after the step's output
            late.add(len(heard) - 1)
        feeder.publish("sim/clock/path_manager", ClockTick(t=t))
        node.step_once(t)
        feeder.publish("clock/done", ClockDone(t=t, process="path_manager", next_due=round(t + 0.05, 9)))
    order = [i for i in range(len(heard)) if i not in late]
    for i in sorted(late):  # after the step's own output (path/match), before its done
        done_at = next(j for j in range(i, len(heard)) if heard[j][0] == "clock/done")
        order.insert(order.index(done_at), i)
    recorder = McapRecorder(tmp_path / "run.mcap", run_cfg, utc_epoch=UTC_EPOCH)
    recorder.start()
    for i in order:
        recorder.offer(*heard[i])
    recorder.close()
    result = mcap_replay.replay_node(tmp_path / "run.mcap", "path_manager")
    assert result.ok, [str(m) for m in result.mismatches[:3]]
    assert result.steps == 40 and result.latched_otherwise == len(late)


def test_the_command_line_lists_and_replays_a_recording(tmp_path, cfg, route, capsys):
    from ares.cli import main

    run_cfg = {**cfg, "lockstep": {**cfg["lockstep"], "participants": ["path_manager"]}}
    path = tmp_path / "run.mcap"
    record_drive(path, run_cfg, route, lockstep=True, steps=10)
    assert main(["replay", str(path), "--info", "--json"]) == 0
    listed = json.loads(capsys.readouterr().out)
    assert listed["complete"] and f"ares/{cfg['vehicle_id']}/path/match" in {c["topic"] for c in listed["channels"]}
    assert main(["replay", str(path), "--node", "path_manager", "--json"]) == 0
    replayed = json.loads(capsys.readouterr().out)
    assert (replayed["steps"], replayed["mismatches"]) == (10, 0)
    assert main(["replay", str(path), "--node", "no_such_process"]) == 1
    assert "unknown process" in capsys.readouterr().err
    assert main(["replay", str(tmp_path / "missing.mcap")]) == 1


class _TwoInputs(Node):
    """A node that says which pose and which car state it latched: its outputs tell the latchings apart."""

    name = "two_inputs"
    rate = 20.0
    pose = Input("localization/pose")
    car = Input("dbw/car_state")

    def step(self, now: float) -> None:
        pose, car = self.pose.latest, self.car.latest
        self.event("latched", f"pose {pose and pose.t} car {car and car.t}")


def test_a_step_that_latched_the_topics_in_another_order_than_the_recorder_heard_is_found(cfg, route):
    """The recorder heard a pose, then a car state; the node latched the car state but not the
    pose (it reached the node after the step): no prefix of the arrival order explains the step,
    a prefix of each topic's does, and the pose is left to the next step."""
    from ares.core.messages import CarState, DriveMode
    from ares.core.replay import LatchedInput, NodeReplay, ReplayResult
    from ares.core.schema import encode_json

    def car(t: float) -> CarState:
        return CarState(
            t=t, mode=DriveMode.AUTOMATIC, engaged=True, watchdog_tripped=False, setpoint_age_s=0.02,
            v_command=2.0, kappa_command=0.0, speed_mps=2.0, steering_wheel_deg=0.0,
        )  # fmt: skip

    pose = LatchedInput("localization/pose", encode_json(pose_on(route, 5.0, 0.04)))
    state = LatchedInput("dbw/car_state", encode_json(car(0.04)))

    def engine() -> NodeReplay:
        one = NodeReplay(_TwoInputs, cfg, "two_inputs", ReplayResult(node="two_inputs", steps=0, outputs=0))
        one.set_up()
        return one

    expected = engine().step(0.05, [state])  # what the node published in the run: the car state alone
    searched = engine().step_latching_a_prefix(0.05, [pose, state], 2, expected)
    assert searched.outputs == expected and searched.per_topic and searched.left == [pose]
    assert searched.latched == 1 and not searched.undecided
