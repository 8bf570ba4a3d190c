"""`ares bench stack`: the whole stack at `--speed max`, every process measured while it drives.

It is `ares run --headless --speed max` (a lap of the tour by default, the three full-resolution
LiDARs of the configuration) with four probes beside the headless drive:

- CPU per process, from the kernel's counters (psutil) once a second: mean (CPU seconds over the
  wall seconds it lived) and p95 of the one-second samples, in cores. The vehicle's own processes
  are the process table's less the simulator's (`sim_only`); the run's host process (the
  supervisor, the embedded router and the headless measurements) is reported apart;
- perception's frame time and the MPC's solve time, as they publish them
  (perception/lidar_status's stage times, control/candidate/mpc's solve_ms);
- the bus's load: messages and bytes per wall second on every key of the vehicle;
- the lag from a LiDAR rotation to the movement command that follows from it: the roof's sweep,
  the next occupancy grid, the obstacle manager's next state, the movement manager's next command,
  each as it arrives here, in wall and stack milliseconds.

The speed-up is the run's own `speed_factor` (stack seconds per wall second). The lap's figures
(the README's bounds) are in `lap`, as `ares run --headless` prints them.

`speed` 1 runs it on the wall clock, as on the vehicle: no lockstep (the processes step on their
own timers, the simulator waits for nobody), where `max` adds the lockstep's tick and report per
step. On this 2-core machine the simulated LiDARs (niced: they stand for hardware) then miss
some of their 10 Hz slots and the awareness manager rightly latches an emergency stop
(docs/performance.md); `paced` is the lockstep capped at real time.
"""

from __future__ import annotations

import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path

import psutil

from ares.app import headless, processes, stack
from ares.app.run_options import HeadlessDrive, RunningStack, RunOptions, Speed
from ares.core.localhost import free_port
from ares.tools.bench.common import BenchError, percentile, versions

CHAIN = ("lidar/roof/points", "perception/grid", "obstacle/state", "movement/command")
SAMPLE_S = 1.0
HOST = "host (supervisor, router, measurements)"
PROFILE_AFTER_S = 30.0  # a process is profiled from this long after its start
PY_SPY = shutil.which("py-spy") or str(Path(sys.executable).with_name("py-spy"))


class CpuSampler:
    """CPU per process of the run, once a second, by the node each child runs (its command line's
    `module:Class`; a restarted process adds to the same name)."""

    def __init__(self, names_by_node: dict[str, str], profile_dir: Path | None = None):
        self.names_by_node = names_by_node
        self.profile_dir = profile_dir  # py-spy records each process's stacks there (a flame graph each)
        self.profilers: list[subprocess.Popen] = []
        self._profiled: set[int] = set()
        self.samples: dict[str, list[float]] = defaultdict(list)  # name -> cores, per second
        self.cpu_s: dict[str, float] = defaultdict(float)
        self.alive_s: dict[str, float] = defaultdict(float)
        self._last: dict[int, tuple[str, float]] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="cpu-sampler", daemon=True)
        self.me = psutil.Process()

    def _name(self, proc: psutil.Process) -> str | None:
        cmd = proc.cmdline()
        return self.names_by_node.get(cmd[-1]) if len(cmd) >= 3 and cmd[-2] == "ares.core.launch" else None

    def sample(self, elapsed: float) -> None:
        """One sample: the CPU each process used since the last, over `elapsed` seconds (the first: a baseline)."""
        seen: dict[int, tuple[str, float]] = {}
        for proc in [self.me, *self.me.children(recursive=True)]:
            try:
                name = HOST if proc.pid == self.me.pid else self._name(proc)
                if name is None:
                    continue
                times = proc.cpu_times()
                seen[proc.pid] = (name, times.user + times.system)
            except (psutil.NoSuchProcess, psutil.AccessDenied, psutil.ZombieProcess):
                continue
        per_name: dict[str, float] = defaultdict(float)
        for pid, (name, total) in seen.items():
            before = self._last.get(pid)
            if before is not None:
                per_name[name] += total - before[1]
        if self.profile_dir is not None:
            for pid, (name, _total) in seen.items():
                if name != HOST and pid not in self._profiled and self._settled(pid):
                    self._profile(pid, name)
        for name, used in per_name.items():
            self.samples[name].append(used / elapsed)
            self.cpu_s[name] += used
            self.alive_s[name] += elapsed
        self._last = seen

    def _settled(self, pid: int) -> bool:
        """Whether the process has had its time to start: a profiler attached while it imports and
        joins the bus slows its start past the supervisor's patience on a small machine."""
        try:
            return time.time() - psutil.Process(pid).create_time() > PROFILE_AFTER_S
        except psutil.Error:
            return False

    def _profile(self, pid: int, name: str) -> None:
        """py-spy samples the process until the run ends (a restarted process gets a graph of its own)."""
        assert self.profile_dir is not None
        out = self.profile_dir / f"{name}-{pid}.svg"
        self._profiled.add(pid)
        self.profilers.append(
            subprocess.Popen(
                [PY_SPY, "record", "--nonblocking", "--rate", "20", "--pid", str(pid), "--output", str(out)],
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )
        )

    def _loop(self) -> None:
        self.sample(SAMPLE_S)  # the baseline
        last = time.monotonic()
        while not self._stop.wait(SAMPLE_S):
            now = time.monotonic()
            self.sample(now - last)
            last = now

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        for profiler in self.profilers:  # SIGINT: py-spy writes its graph and exits
            profiler.send_signal(signal.SIGINT)
        for profiler in self.profilers:
            try:
                profiler.wait(timeout=30)
            except subprocess.TimeoutExpired:
                profiler.kill()

    def figures(self) -> dict[str, dict[str, float | None]]:
        return {
            name: {
                "mean_cores": round(self.cpu_s[name] / max(self.alive_s[name], 1e-9), 3),
                "p95_cores": percentile(self.samples[name], 95, 3),
            }
            for name in sorted(self.samples, key=lambda n: -self.cpu_s[n])
        }


class BusLoad:
    """Messages and bytes on every key of the vehicle, as this process receives them."""

    def __init__(self, bus):
        self.messages: dict[str, int] = defaultdict(int)
        self.bytes: dict[str, int] = defaultdict(int)
        self.started = time.monotonic()
        self.handle = bus.subscribe_raw("**", self._count)

    def _count(self, topic: str, encoding: str, payload: bytes) -> None:
        self.messages[topic] += 1
        self.bytes[topic] += len(payload)

    def figures(self) -> dict:
        wall = max(time.monotonic() - self.started, 1e-9)
        busiest = sorted(self.bytes, key=lambda t: -self.bytes[t])[:8]
        return {
            "messages_per_s": round(sum(self.messages.values()) / wall, 1),
            "megabytes_per_s": round(sum(self.bytes.values()) / wall / 1e6, 3),
            "keys": len(self.messages),
            "busiest_kb_per_s": {t: round(self.bytes[t] / wall / 1e3, 1) for t in busiest},
        }


class RotationToCommand:
    """The lag from each roof rotation to the movement command that follows it: a rotation waits for
    the next grid, that for the next obstacle state, that for the next command (CHAIN), each taken
    as it arrives here; wall and stack milliseconds."""

    def __init__(self, bus, clock):
        self.clock = clock
        self.lock = threading.Lock()
        self.pending: list[list] = []  # [stage index reached, wall at rotation, stack at rotation]
        self.wall_ms: list[float] = []
        self.stack_ms: list[float] = []
        for k, topic in enumerate(CHAIN):
            bus.subscribe(topic, on_message=lambda _topic, _msg, k=k: self._arrived(k))

    def _arrived(self, stage: int) -> None:
        wall, now = time.monotonic(), self.clock.now()
        with self.lock:
            if stage == 0:
                self.pending.append([0, wall, now])
                return
            for chain in self.pending:
                if chain[0] == stage - 1:
                    chain[0] = stage
            if stage == len(CHAIN) - 1:
                for chain in self.pending:
                    if chain[0] == stage:
                        self.wall_ms.append((wall - chain[1]) * 1e3)
                        self.stack_ms.append((now - chain[2]) * 1e3)
                self.pending = [c for c in self.pending if c[0] != stage][-50:]

    def figures(self) -> dict:
        return {
            "rotations": len(self.wall_ms),
            "wall_p50_ms": percentile(self.wall_ms, 50, 1),
            "wall_p99_ms": percentile(self.wall_ms, 99, 1),
            "stack_p50_ms": percentile(self.stack_ms, 50, 1),
            "stack_p99_ms": percentile(self.stack_ms, 99, 1),
        }


class Published:
    """A number each message of a topic carries, kept for its percentiles."""

    def __init__(self, bus, topic: str, value: Callable[[object], float | None]):
        self.values: list[float] = []

        def keep(_topic: str, msg: object) -> None:
            v = value(msg)
            if v is not None:
                self.values.append(float(v))

        bus.subscribe(topic, on_message=keep)

    def figures(self) -> dict:
        return {
            "count": len(self.values),
            "p50_ms": percentile(self.values, 50, 2),
            "p99_ms": percentile(self.values, 99, 2),
            "max_ms": round(max(self.values), 2) if self.values else None,
        }


def run_options(
    laps: int,
    seconds: float | None,
    config_files: tuple[str, ...],
    wire: bool,
    run_dir: Path,
    speed: Speed = "max",
    vehicle_cpus: list[int] | None = None,
) -> RunOptions:
    """The headless run the bench drives, on ports and a store of its own."""
    return RunOptions(
        headless=True,
        speed=speed,
        run_dir=run_dir,
        listen=f"tcp/127.0.0.1:{free_port()}",
        api_port=free_port(),
        store=str(run_dir / "blackbox.sqlite"),
        seconds=seconds,
        laps=None if seconds else laps,
        config_files=config_files,
        wire=wire,
        vehicle_cpus=tuple(vehicle_cpus) if vehicle_cpus else None,
    )


class Probes:
    """The bench's probes, set up beside the headless drive once the stack runs."""

    def __init__(self, running: RunningStack, profile_dir: Path | None):
        table = processes.for_config(running.cfg)
        bus, clock = running.bus, running.clock
        self.clock = clock
        self.cpus = running.cfg["cpus"]
        self.sim = [p.name for p in table if p.sim_only]
        self.sampler = CpuSampler({p.node: p.name for p in table}, profile_dir)
        self.load = BusLoad(bus)
        self.lag = RotationToCommand(bus, clock)
        self.perception = Published(bus, "perception/lidar_status", lambda m: m.stage_ms.get("total"))
        self.perception_cpu = Published(bus, "perception/lidar_status", lambda m: m.stage_ms.get("cpu"))
        self.mpc = Published(bus, "control/candidate/mpc", lambda m: m.solve_ms)
        self.began = self.ended = (clock.now(), time.monotonic())

    def around(self, drive: HeadlessDrive, running: RunningStack) -> dict:
        """`drive`, with the CPU sampled while it lasts."""
        self.sampler.start()
        self.began = (self.clock.now(), time.monotonic())
        try:
            return drive(running)
        finally:
            self.ended = (self.clock.now(), time.monotonic())
            self.sampler.stop()


def run_stack_bench(
    laps: int = 1,
    seconds: float | None = None,
    config_files: tuple[str, ...] = (),
    wire: bool = False,
    profile_dir: Path | None = None,
    run_dir: Path | None = None,
    progress: Callable[[str], None] = lambda _msg: None,
    speed: Speed = "max",
    vehicle_cpus: list[int] | None = None,
    drive: HeadlessDrive = headless.drive,
) -> dict:
    """A headless run (ares.app.stack.run) whose `drive` (default: ares run --headless's) the
    probes watch; their figures and the run's own (`lap`)."""
    run_dir = run_dir or Path(tempfile.mkdtemp(prefix="ares-bench-stack-"))
    if profile_dir is not None:
        profile_dir.mkdir(parents=True, exist_ok=True)
    options = run_options(laps, seconds, config_files, wire, run_dir, speed, vehicle_cpus)
    probed: list[Probes] = []

    def probed_drive(running: RunningStack) -> dict:
        probed.append(Probes(running, profile_dir))
        return probed[0].around(drive, running)

    progress(f"ares run --headless --speed {speed} ({f'{seconds:g} s' if seconds else f'{laps} lap(s)'}), in {run_dir}")
    result = stack.run(options, drive=probed_drive)
    lap = result.summary()
    if not probed:
        raise BenchError(f"the stack did not start: {result.error}")
    probes = probed[0]
    cpu = probes.sampler.figures()
    (t0, wall0), (t1, wall1) = probes.began, probes.ended
    # the run's own figure when it finished; over what it drove when it did not (a failed run's too)
    speedup = lap.get("speed_factor") or round((t1 - t0) / max(wall1 - wall0, 1e-9), 2)
    vehicle = {n: f for n, f in cpu.items() if n != HOST and n not in probes.sim}
    vehicle_cores = sum(f["mean_cores"] or 0.0 for f in vehicle.values())
    return {
        "ok": result.ok,
        "speed": options.speed,
        "speedup": speedup,
        "vehicle_cpu_cores": round(vehicle_cores, 3),
        # what the same work needs at real time: the vehicle's own clock
        "vehicle_cpu_s_per_vehicle_s": round(vehicle_cores / speedup, 3) if speedup else None,
        "cpus": probes.cpus,
        "simulator_cpu_cores": round(sum(cpu[n]["mean_cores"] or 0.0 for n in probes.sim if n in cpu), 3),
        "host_cpu_cores": cpu.get(HOST, {}).get("mean_cores"),
        "cpu_per_process": cpu,
        "perception_frame_ms": probes.perception.figures(),
        "perception_frame_cpu_ms": probes.perception_cpu.figures(),
        "mpc_solve_ms": probes.mpc.figures(),
        "bus": probes.load.figures(),
        "rotation_to_command": probes.lag.figures(),
        "lap": lap,
        "profiles": sorted(str(p) for p in profile_dir.glob("*.svg")) if profile_dir is not None else None,
        "cores": psutil.cpu_count(),
        "versions": versions("eclipse-zenoh", "numpy", "open3d", "casadi"),
    }


def format_stack_result(result: dict, out) -> None:
    lap = result["lap"]
    out.write(f"{'speedup (stack s per wall s)':40} {result['speedup']}\n")
    out.write(f"{'vehicle processes, CPU cores (mean)':40} {result['vehicle_cpu_cores']}\n")
    out.write(f"{'  CPU-s per vehicle second':40} {result['vehicle_cpu_s_per_vehicle_s']}\n")
    out.write(f"{'CPUs (vehicle, simulator, host)':40} {result['cpus']}\n")
    out.write(f"{'simulator, CPU cores (mean)':40} {result['simulator_cpu_cores']}\n")
    out.write(f"{'host process, CPU cores (mean)':40} {result['host_cpu_cores']}\n")
    for name, fig in result["cpu_per_process"].items():
        out.write(f"  {name:38} mean {fig['mean_cores']:.3f}  p95 {fig['p95_cores']}\n")
    for key in ("perception_frame_ms", "perception_frame_cpu_ms", "mpc_solve_ms", "rotation_to_command", "bus"):
        out.write(f"{key:40} {result[key]}\n")
    for key in ("ok", "distance_m", "xte_rmse_m", "xte_max_m", "collisions", "invariant_violations", "error"):
        if key in lap:
            out.write(f"{'lap.' + key:40} {lap[key]}\n")
