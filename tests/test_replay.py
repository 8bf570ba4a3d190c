"""Process replay (after openpilot's): inputs recorded from a real run (tests/replay/, recorded with
`ares run --headless --speed max --seconds 45 --config tests/replay/record.yaml`) are fed back
through the localization, odometry and path managers, which must publish what they published in
that run. After an intended change of behaviour: `ares replay update tests/replay/*.jsonl.gz`."""

from __future__ import annotations

import gzip
from pathlib import Path

import orjson
import pytest

from ares.app import run_config
from ares.core import replay
from ares.core.clock import ManualClock
from ares.core.membus import MemoryNetwork
from ares.core.messages import Pose

FIXTURES = Path(__file__).resolve().parent / "replay"
RECORDED = ["localization", "odometry_manager", "path_manager"]


@pytest.mark.parametrize("node", RECORDED)
def test_a_recorded_run_replays_identically(node):
    result = replay.replay(FIXTURES / f"{node}.jsonl.gz")
    assert result.ok, "\n".join(map(str, result.mismatches[:5]))
    assert result.steps > 900 and result.outputs > 900


def test_the_recordings_span_the_loss_of_rtk_corrections():
    header, frames = replay.read(FIXTURES / "odometry_manager.jsonl.gz")
    scores = [msg["score"] for frame in frames for topic, msg in frame["out"] if topic == "odometry/score"]
    assert max(scores) > 0.99 and min(scores) < 0.05  # trusted, then not, then again
    assert scores[-1] > 0.99


def test_a_change_of_behaviour_shows_as_mismatches():
    result = replay.replay(FIXTURES / "odometry_manager.jsonl.gz", config_overrides={"odometry_manager": {"c": 2e-3}})
    assert not result.ok
    first = result.mismatches[0]
    assert first.where == "odometry/score.score" and first.got > first.expected


def test_a_node_records_what_it_latched_and_published(tmp_path):
    cfg = run_config.build(overrides={"replay": {"record": ["odometry_manager"], "dir": str(tmp_path)}})
    from managers.odometry_node import OdometryManager

    clock = ManualClock(0.0)
    network = MemoryNetwork()
    node = OdometryManager(cfg, clock=clock, bus=network.bus("odometry_manager", clock))
    node.setup()
    feeder = network.bus("localization", clock)
    for k in range(1, 6):
        t = k * 0.05
        feeder.publish(
            "localization/pose",
            Pose(
                t=t - 0.01,
                x=k,
                y=0.0,
                z=0.0,
                yaw=0.0,
                v=1.0,
                yaw_rate=0.0,
                cov_xx=1e-4 * k,
                cov_xy=0.0,
                cov_yy=1e-4,
                var_yaw=1e-4,
                var_v=1e-2,
                position_std_m=0.01 * k,
                rtk=True,
                gnss_age_s=0.1,
            ),
        )
        clock.set(t)
        node.step_once(t)
    node._recorder.close()
    lines = [orjson.loads(line) for line in gzip.open(tmp_path / "odometry_manager.jsonl.gz")]
    assert lines[0]["node"] == "odometry_manager" and lines[0]["class"] == "managers.odometry_node:OdometryManager"
    assert [frame["t"] for frame in lines[1:]] == pytest.approx([0.05, 0.1, 0.15, 0.2, 0.25])
    assert all(len(frame["in"]) == 1 and frame["out"][0][0] == "odometry/score" for frame in lines[1:])
    again = replay.replay(tmp_path / "odometry_manager.jsonl.gz")
    assert again.ok and again.steps == 5


def test_a_node_put_back_steps_again_as_it_did():
    """A replay from a recording of the bus tries a step latching different inputs, the node's
    state copied before and put back between tries: put back, it steps again as it did."""
    from managers.odometry_node import OdometryManager

    clock = ManualClock(0.0)
    network = MemoryNetwork()
    node = OdometryManager(run_config.build(), clock=clock, bus=network.bus("odometry_manager", clock))
    published = []
    node.tap_outputs(lambda topic, payload: published.append((topic, payload)))
    node.setup()
    feeder = network.bus("localization", clock)

    def step(k: int, position_std_m: float) -> list:
        t = round(k * 0.05, 9)
        feeder.publish("localization/pose", _pose(t - 0.01, x=k, position_std_m=position_std_m))
        clock.set(t)
        node.step_once(t)
        stepped = list(published)
        published.clear()
        return stepped

    for k in range(1, 4):
        step(k, 0.01)
    state = node.copy_state()
    trusted = step(4, 0.01)
    node.restore_state(state)
    doubted = step(4, 3.0)
    assert doubted != trusted and [topic for topic, _ in doubted] == ["odometry/score"]
    node.restore_state(state)
    assert step(4, 0.01) == trusted and node.pose.count == 4


def _pose(t: float, x: float, position_std_m: float) -> Pose:
    return Pose(
        t=t, x=x, y=0.0, z=0.0, yaw=0.0, v=1.0, yaw_rate=0.0, cov_xx=position_std_m**2, cov_xy=0.0,
        cov_yy=position_std_m**2, var_yaw=1e-4, var_v=1e-2, position_std_m=position_std_m, rtk=True, gnss_age_s=0.1,
    )  # fmt: skip


def test_a_restarted_process_records_to_a_file_of_its_own(tmp_path, monkeypatch):
    from ares.core.recording import INCARNATION_ENV
    from managers.odometry_node import OdometryManager

    cfg = run_config.build(overrides={"replay": {"record": ["odometry_manager"], "dir": str(tmp_path)}})
    clock = ManualClock(0.0)
    for incarnation in (0, 1, 2):
        monkeypatch.setenv(INCARNATION_ENV, str(incarnation))
        node = OdometryManager(cfg, clock=clock, bus=MemoryNetwork().bus("odometry_manager", clock))
        node._recorder.close()
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "odometry_manager.1.jsonl.gz",
        "odometry_manager.2.jsonl.gz",
        "odometry_manager.jsonl.gz",
    ]


def test_a_recording_cut_short_replays_up_to_its_last_whole_step(tmp_path):
    whole = gzip.decompress((FIXTURES / "odometry_manager.jsonl.gz").read_bytes())
    steps = whole.count(b"\n") - 1
    cut = tmp_path / "cut.jsonl.gz"
    packed = gzip.compress(whole)
    cut.write_bytes(packed[: len(packed) * 2 // 3])  # as a SIGKILL leaves it: no gzip trailer
    header, frames = replay.read(cut)
    assert header["node"] == "odometry_manager" and 0 < len(frames) < steps
    result = replay.replay(cut)
    assert result.ok and result.steps == sum(1 for f in frames if f["t"] is not None)
    cut.write_bytes(b"not gzip at all")
    with pytest.raises(ValueError, match="not a process replay recording"):
        replay.read(cut)
