"""The table of `ares bench`'s benchmarks: each one's name, its options, how it runs and how its
result reads for people. `ares bench` (ares/cli/bench.py) is built from this table alone."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TextIO

from .args import CliError, cpu_list, positive_float, positive_int
from .run import speed as run_speed

Progress = Callable[[str], None]


@dataclass(frozen=True)
class Bench:
    name: str
    help: str
    description: str
    add_arguments: Callable[[argparse.ArgumentParser], None]
    run: Callable[[argparse.Namespace, Progress], dict]
    show: Callable[[dict, TextIO], None]  # the result for people (without --json)


def key_per_line(result: dict, out: TextIO) -> None:
    for key, value in result.items():
        out.write(f"{key:32} {value}\n")


def nested_per_line(result: dict, out: TextIO, prefix: str = "") -> None:
    for key, value in result.items():
        if isinstance(value, dict):
            nested_per_line(value, out, f"{prefix}{key}.")
        else:
            out.write(f"{prefix + key:40} {value}\n")


def _config_files(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", action="append", metavar="FILE", help="configuration overrides, as for ares run")


# ---- bus -------------------------------------------------------------------------------------


def _bus_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--seconds",
        type=positive_float,
        default=6.0,
        metavar="S",
        help="measurement time, split between latency and throughput (default 6)",
    )
    p.add_argument(
        "--mode", choices=["peer", "client"], help="bus mode of the two processes (default: the stack's, bus.mode)"
    )


def _bus_run(args: argparse.Namespace, progress: Progress) -> dict:
    from ares.tools.bench.bus import run_bus_bench

    return run_bus_bench(seconds=args.seconds, mode=args.mode, progress=progress)


def _bus_show(result: dict, out: TextIO) -> None:
    from ares.tools.bench.bus import format_result

    format_result(result, out)


# ---- supervisor ------------------------------------------------------------------------------


def _supervisor_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--rounds", type=positive_int, default=3, metavar="N", help="rounds (default 3)")


def _supervisor_run(args: argparse.Namespace, progress: Progress) -> dict:
    from ares.tools.bench.supervisor import run_supervisor_bench

    return run_supervisor_bench(args.rounds, progress=progress)


# ---- path ------------------------------------------------------------------------------------


def _no_arguments(_p: argparse.ArgumentParser) -> None:
    """The bench has no options besides the common ones."""


def _path_run(_args: argparse.Namespace, progress: Progress) -> dict:
    from ares.tools.bench.path import run_path_bench

    return run_path_bench(progress=progress)


def _path_show(result: dict, out: TextIO) -> None:
    from ares.tools.bench.path import format_path_result

    format_path_result(result, out)


# ---- perception ------------------------------------------------------------------------------


def _perception_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--frames", type=positive_int, default=8, metavar="N", help="places along the tour, evenly spaced (default 8)"
    )
    p.add_argument(
        "--repeats",
        type=positive_int,
        default=3,
        metavar="N",
        help="timed runs of the pipeline and the ground removal per place (default 3)",
    )
    p.add_argument(
        "--reference",
        action="store_true",
        help="instead: our ground stage beside Patchwork++ (pypatchworkpp) on simulated HDL-64E scans of the "
        "tour and the --scan files: ground share, IoU, occupied cells and time of each",
    )
    p.add_argument(
        "--scan",
        action="append",
        metavar="FILE",
        help="with --reference: a real scan (KITTI .bin, .pcd, .ply) to compare on too; repeatable",
    )


def _perception_run(args: argparse.Namespace, progress: Progress) -> dict:
    if args.reference:
        from ares.tools.bench.perception_reference import run_reference_bench

        return run_reference_bench(args.frames, args.repeats, scans=args.scan or (), progress=progress)
    if args.scan:
        raise CliError("--scan goes with --reference")
    from ares.tools.bench.perception import run_perception_bench

    return run_perception_bench(args.frames, args.repeats, progress=progress)


def _perception_show(result: dict, out: TextIO) -> None:
    if result.get("bench") == "perception_reference":
        from ares.tools.bench.perception_reference import format_reference_result

        format_reference_result(result, out)
    else:
        from ares.tools.bench.perception import format_perception_result

        format_perception_result(result, out)


# ---- record ------------------------------------------------------------------------------------


def _record_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--recording",
        type=Path,
        metavar="FILE.mcap",
        help="a run's recording to measure on (default: a 20 s headless run at --speed max, made first)",
    )


def _record_run(args: argparse.Namespace, progress: Progress) -> dict:
    from ares.tools.bench.record import run_record_bench

    return run_record_bench(args.recording, progress)


def _record_show(result: dict, out: TextIO) -> None:
    from ares.tools.bench.record import format_record_result

    format_record_result(result, out)


# ---- mpc, obstacle-zone ----------------------------------------------------------------------


def _mpc_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--solves", type=positive_int, default=2000, metavar="N", help="solves (default 2000)")
    p.add_argument("--vehicle", default="ares_shuttle", metavar="NAME", help="vehicle profile (default ares_shuttle)")


def _mpc_run(args: argparse.Namespace, progress: Progress) -> dict:
    from ares.tools.bench.mpc import run_mpc_bench

    return run_mpc_bench(args.solves, args.vehicle, progress=progress)


def _obstacle_zone_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--step", type=positive_float, default=2.0, metavar="M", help="between frames (default 2 m)")
    p.add_argument(
        "--speed",
        type=positive_float,
        default=4.0,
        metavar="MPS",
        help="the speed the areas are sized for (default 4 m/s: the longest, 10 m)",
    )


def _obstacle_zone_run(args: argparse.Namespace, progress: Progress) -> dict:
    from ares.tools.bench.obstacle_zone import run_obstacle_zone_bench

    return run_obstacle_zone_bench(args.step, args.speed, progress=progress)


# ---- blackbox, live, drivers -----------------------------------------------------------------


def _blackbox_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--seconds", type=positive_float, default=10.0, metavar="S", help="duration of the API load (default 10)"
    )


def _blackbox_run(args: argparse.Namespace, progress: Progress) -> dict:
    from ares.tools.bench.blackbox_api import run_api_bench
    from ares.tools.bench.blackbox_store import run_store_bench

    store = run_store_bench(progress=progress)
    api = run_api_bench(progress=progress, seconds=args.seconds)
    return {**store, **{k: v for k, v in api.items() if k not in store}}


def _live_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--browsers", type=positive_int, default=3, metavar="N", help="pages connected (default 3)")
    p.add_argument("--seconds", type=positive_float, default=30.0, metavar="S", help="measured (default 30)")
    _config_files(p)


def _live_run(args: argparse.Namespace, progress: Progress) -> dict:
    from ares.tools.bench.live import run_live_bench

    return run_live_bench(args.browsers, args.seconds, config_files=tuple(args.config or ()), progress=progress)


def _drivers_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--repeats", type=positive_int, default=20, metavar="N", help="rotations per model (20)")
    p.add_argument("--seconds", type=positive_float, default=3.0, metavar="S", help="CAN measurement time (default 3)")


def _drivers_run(args: argparse.Namespace, progress: Progress) -> dict:
    from ares.tools.bench.drivers_can import can_bench
    from ares.tools.bench.drivers_lidar import lidar_decode_bench

    progress("Velodyne rotations: decode and assembly")
    lidar = lidar_decode_bench(args.repeats)
    progress("CAN frames: codec and udp_multicast into the driver")
    return {"bench": "drivers", "lidar": lidar, "can": can_bench(args.seconds)}


# ---- stack -----------------------------------------------------------------------------------


def _stack_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--laps", type=positive_int, default=1, metavar="N", help="laps of the tour (default 1)")
    p.add_argument("--seconds", type=positive_float, metavar="S", help="vehicle seconds instead of laps")
    _config_files(p)
    p.add_argument("--wire", action="store_true", help="through the devices' wire formats, as ares run --wire")
    p.add_argument(
        "--vehicle-cpus",
        type=cpu_list,
        metavar="LIST",
        help="as ares run --vehicle-cpus: the vehicle's own processes on these CPUs only, the simulator and "
        "the bench on the others (a vehicle computer of that many cores beside the simulated shuttle)",
    )
    p.add_argument(
        "--speed",
        type=run_speed,
        default="max",
        metavar="max|paced|FACTOR",
        help="as ares run --speed: max (default: the lockstep, as fast as every process keeps up), paced (the "
        "same, never faster than real time) or 1 (the wall clock, no lockstep: as on the vehicle)",
    )
    p.add_argument(
        "--profile",
        type=Path,
        metavar="DIR",
        help="also sample every process with py-spy: a flame graph per process in DIR (slows the run)",
    )


def _stack_run(args: argparse.Namespace, progress: Progress) -> dict:
    from ares.tools.bench.stack import run_stack_bench

    return run_stack_bench(
        args.laps,
        args.seconds,
        tuple(args.config or ()),
        args.wire,
        profile_dir=args.profile,
        progress=progress,
        speed=args.speed,
        vehicle_cpus=args.vehicle_cpus,
    )


def _stack_show(result: dict, out: TextIO) -> None:
    from ares.tools.bench.stack import format_stack_result

    format_stack_result(result, out)


BENCHES = (
    Bench(
        "bus",
        "publish -> subscribe latency and throughput between two processes",
        "Latency and sustained throughput of the bus between two OS processes "
        "through an embedded router on a free port.",
        _bus_arguments,
        _bus_run,
        _bus_show,
    ),
    Bench(
        "supervisor",
        "how fast a killed, frozen or hung process is noticed and restarted",
        "Rounds of a supervisor over ticker nodes: SIGKILL, SIGSTOP and a loop "
        "holding the GIL, timed from the signal to noticed / running again.",
        _supervisor_arguments,
        _supervisor_run,
        key_per_line,
    ),
    Bench(
        "path",
        "path manager KD-tree build and match times, UKF step time",
        "Builds a 100,000-pose route and times the KD-tree build, "
        "10,000 reachable-nearest matches with realistic hints, the raw KD "
        "queries, and one UKF step (perception.ukf), all in this process.",
        _no_arguments,
        _path_run,
        _path_show,
    ),
    Bench(
        "perception",
        "LiDAR pipeline stage times and the simulated LiDARs' ray casting (in-process)",
        "At places along the built-in tour: the three simulated LiDARs' frame through "
        "LidarPipeline.process (stage medians), heightmap ground removal on a dense ~125,000-point "
        "64-layer scan, and the ray casting of the three sensors for one frame, single-threaded "
        "(its share of a core at 10 Hz) and on every core.",
        _perception_arguments,
        _perception_run,
        _perception_show,
    ),
    Bench(
        "record",
        "what a recording costs: bytes per second, the writer's CPU, per profile, cloud encoding and topic class",
        "A run's recording read back and offered again to the recorder with each profile, cloud encoding and "
        "chunk compression (and each topic class alone): the file's MB per second of stack time, the writer's "
        "share of a core at real time, the file against the bytes received.",
        _record_arguments,
        _record_run,
        _record_show,
    ),
    Bench(
        "mpc",
        "the MPC's solve times in closed loop round the tour (in-process)",
        "The MPC drives a kinematic bicycle (the steering's dead time and rate) "
        "round the built-in tour at its speed profile; each solve is timed.",
        _mpc_arguments,
        _mpc_run,
        key_per_line,
    ),
    Bench(
        "obstacle-zone",
        "false stops of the obstacle manager's trapezoid beside a rectangle's, in the narrow lane",
        "The built-in tour's narrow lane between rock walls, nothing in the way: every STEP m the three "
        "simulated LiDARs' frame through the perception pipeline, and the obstacle manager's trapezoid "
        "and a rectangle of the same length, each laid along the path ahead and along the wheels' arc; "
        "the frames each would have slowed or stopped the shuttle.",
        _obstacle_zone_arguments,
        _obstacle_zone_run,
        key_per_line,
    ),
    Bench(
        "blackbox",
        "black box: ingest rate, one-hour query with 7 days stored, latest-state API over HTTPS",
        "Ingests records in batches into a fresh embedded store, times one-hour queries with "
        "7 days of 1 Hz records (604,800) present, and loads the latest-state endpoint over "
        "HTTPS from a separate process (wrk when installed).",
        _blackbox_arguments,
        _blackbox_run,
        key_per_line,
    ),
    Bench(
        "live",
        "how far the operator page lags the bus, with N browsers connected (the whole stack)",
        "The whole stack at real time and N headless Chromium pages on /operator: each frame's lag from "
        "the moment its vehicle state was published on the bus to the page having drawn it.",
        _live_arguments,
        _live_run,
        key_per_line,
    ),
    Bench(
        "drivers",
        "the device drivers: Velodyne decode per rotation (every model), CAN frames per second",
        "Decodes and assembles full-resolution Velodyne rotations (VLP-16, HDL-32E, VLP-32C, "
        "HDL-64E, VLS-128) as the LiDAR driver does, and pushes CAN frames through the DBC codec and "
        "through python-can's udp_multicast into the CAN driver; medians of repeated rounds, in this process.",
        _drivers_arguments,
        _drivers_run,
        nested_per_line,
    ),
    Bench(
        "stack",
        "the whole stack at --speed max: speed-up, CPU per process, perception and MPC times, bus load, "
        "LiDAR-to-command lag",
        "ares run --headless --speed max (a lap of the tour, the configuration's LiDARs) with probes: "
        "CPU per process (mean, p95), perception's frame time, the MPC's solve time, the bus's load and the lag "
        "from a roof rotation to the movement command; the lap's figures beside them.",
        _stack_arguments,
        _stack_run,
        _stack_show,
    ),
)
BY_NAME = {bench.name: bench for bench in BENCHES}
