"""`ares bench stack`'s probes on the in-memory bus and on a real child process; the bench itself
runs a whole lap, which is a command (`ares bench stack`), not a test."""

from __future__ import annotations

import subprocess
import sys
import time

import numpy as np

from ares.core.clock import ManualClock
from ares.core.membus import MemoryNetwork
from ares.core.messages import MovementCommand, ObstacleState, OccupancyGrid, PointCloud
from ares.tools.bench.stack import BusLoad, CpuSampler, RotationToCommand


def cloud(t: float, n: int = 100) -> PointCloud:
    zeros = np.zeros(n, np.float32)
    return PointCloud(
        t=t, sensor="roof", frame="roof", x=zeros, y=zeros, z=zeros, intensity=zeros, ring=np.zeros(n, np.uint8)
    )


def grid(t: float) -> OccupancyGrid:
    return OccupancyGrid(
        t=t, frame="base_link", resolution_m=0.2, origin_x=0.0, origin_y=0.0, cells=np.zeros((4, 4), np.uint8)
    )


def obstacle(t: float) -> ObstacleState:
    return ObstacleState(
        t=t, score=1.0, band="clear", nearest_m=None, limit_mps=5.0, length_m=10.0, cells=0, area_x=[], area_y=[]
    )


def command(t: float) -> MovementCommand:
    return MovementCommand(t=t, v=1.0, kappa=0.0, source="mpc")


def test_a_rotation_counts_once_its_grid_its_obstacle_state_and_then_a_command_have_followed():
    clock, network = ManualClock(), MemoryNetwork()
    probe_bus, stack_bus = network.bus("bench", clock), network.bus("stack", clock)
    lag = RotationToCommand(probe_bus, clock)

    stack_bus.publish("lidar/roof/points", cloud(0.0))
    clock.set(0.02)
    stack_bus.publish("movement/command", command(0.02))  # before the rotation reached the grid: not its command
    stack_bus.publish("obstacle/state", obstacle(0.02))  # nor is an obstacle state before its grid
    clock.set(0.04)
    stack_bus.publish("perception/grid", grid(0.04))
    clock.set(0.05)
    stack_bus.publish("lidar/roof/points", cloud(0.05))  # the next rotation, still waiting for its grid
    clock.set(0.06)
    stack_bus.publish("obstacle/state", obstacle(0.06))
    clock.set(0.08)
    stack_bus.publish("movement/command", command(0.08))

    figures = lag.figures()
    assert figures["rotations"] == 1 and figures["stack_p50_ms"] == 80.0  # 0.00 -> 0.08
    assert figures["wall_p50_ms"] is not None and figures["wall_p50_ms"] >= 0

    for t, topic, msg in (
        (0.1, "perception/grid", grid),
        (0.12, "obstacle/state", obstacle),
        (0.14, "movement/command", command),
    ):
        clock.set(t)
        stack_bus.publish(topic, msg(t))
    assert lag.figures()["rotations"] == 2
    assert [round(ms, 6) for ms in lag.stack_ms] == [80.0, 90.0]  # the second: 0.05 -> 0.14


def test_the_bus_load_counts_every_key_of_the_vehicle_with_its_bytes():
    clock, network = ManualClock(), MemoryNetwork()
    load = BusLoad(network.bus("bench", clock))
    stack_bus = network.bus("stack", clock)
    for k in range(3):
        stack_bus.publish("lidar/roof/points", cloud(k * 0.1, n=1000))
        stack_bus.publish("movement/command", command(k * 0.1))
    assert load.messages == {"lidar/roof/points": 3, "movement/command": 3}
    assert load.bytes["lidar/roof/points"] > 3 * 1000 * 13  # x, y, z, intensity (4 bytes each) and ring: binary
    figures = load.figures()
    assert figures["keys"] == 2 and list(figures["busiest_kb_per_s"])[0] == "lidar/roof/points"


def test_the_cpu_sampler_names_each_child_by_the_node_it_runs():
    busy = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import time\nend = time.time() + 30\nwhile time.time() < end: pass",
            "ares.core.launch",
            "managers.x:Busy",
        ]
    )
    idle = subprocess.Popen(
        [sys.executable, "-c", "import time; time.sleep(30)", "ares.core.launch", "managers.y:Idle"]
    )
    try:
        sampler = CpuSampler({"managers.x:Busy": "busy_node", "managers.y:Idle": "idle_node"})
        sampler.sample(1.0)  # the baseline
        deadline = time.monotonic() + 60  # a loaded machine gives the busy child its CPU slowly
        while sampler.cpu_s["busy_node"] < 0.3 and time.monotonic() < deadline:
            time.sleep(0.2)
            sampler.sample(0.2)
        assert set(sampler.samples) >= {"busy_node", "idle_node"}
        assert sampler.cpu_s["busy_node"] > sampler.cpu_s["idle_node"]
        figures = sampler.figures()
        assert list(figures)[0] in ("busy_node", "host (supervisor, router, measurements)")
        assert set(figures["busy_node"]) == {"mean_cores", "p95_cores"}
    finally:
        busy.kill()
        idle.kill()
        busy.wait()
        idle.wait()


def test_the_bench_runs_ares_run_at_the_speed_asked_on_ports_and_a_store_of_its_own(tmp_path):
    from ares.cli import build_parser
    from ares.cli.run import run_options as ares_run_options
    from ares.tools.bench.stack import run_options

    for speed in ("max", "paced", "1"):
        bench = build_parser().parse_args(["bench", "stack", "--speed", speed, "--seconds", "60"])
        options = run_options(bench.laps, bench.seconds, (), False, tmp_path, bench.speed)
        as_ares_run = ares_run_options(build_parser().parse_args(["run", "--speed", speed]))
        assert options.headless and options.speed == as_ares_run.speed
        assert (options.seconds, options.laps, options.run_dir) == (60, None, tmp_path)
        assert options.store == str(tmp_path / "blackbox.sqlite") and options.listen != "tcp/127.0.0.1:7447"
    # --vehicle-cpus reaches the run as it was given
    bench = build_parser().parse_args(["bench", "stack", "--vehicle-cpus", "0"])
    assert bench.vehicle_cpus == [0]
    options = run_options(bench.laps, bench.seconds, (), False, tmp_path, bench.speed, bench.vehicle_cpus)
    assert options.vehicle_cpus == (0,) and options.laps == 1 and options.speed == "max"
