"""`ares bench bus|path|blackbox|supervisor|perception|mpc|obstacle-zone|live|drivers|stack`: the benchmarks."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from .args import CliError, Command, cpu_list, positive_float, positive_int


def add_parser(subparsers: argparse._SubParsersAction) -> dict[str, Command]:
    bench = subparsers.add_parser("bench", help="benchmarks", description="Benchmarks.")
    bench_sub = bench.add_subparsers(dest="bench", metavar="BENCH")
    bus = bench_sub.add_parser(
        "bus",
        help="publish -> subscribe latency and throughput between two processes",
        description="Latency and sustained throughput of the bus between two OS processes "
        "through an embedded router on a free port.",
    )
    bus.add_argument("--json", action="store_true", help="print one JSON object (last line of stdout)")
    bus.add_argument(
        "--seconds",
        type=positive_float,
        default=6.0,
        metavar="S",
        help="measurement time, split between latency and throughput (default 6)",
    )
    bus.add_argument(
        "--mode", choices=["peer", "client"], help="bus mode of the two processes (default: the stack's, bus.mode)"
    )
    sup = bench_sub.add_parser(
        "supervisor",
        help="how fast a killed, frozen or hung process is noticed and restarted",
        description="Rounds of a supervisor over ticker nodes: SIGKILL, SIGSTOP and a loop "
        "holding the GIL, timed from the signal to noticed / running again.",
    )
    sup.add_argument("--json", action="store_true", help="print one JSON object (last line of stdout)")
    sup.add_argument("--rounds", type=positive_int, default=3, metavar="N", help="rounds (default 3)")
    path = bench_sub.add_parser(
        "path",
        help="path manager KD-tree build and match times, UKF step time",
        description="Builds a 100,000-pose route and times the KD-tree build, "
        "10,000 reachable-nearest matches with realistic hints, the raw KD "
        "queries, and one UKF step (perception.ukf), all in this process.",
    )
    path.add_argument("--json", action="store_true", help="print one JSON object (last line of stdout)")
    perception = bench_sub.add_parser(
        "perception",
        help="LiDAR pipeline stage times and the simulated LiDARs' ray casting (in-process)",
        description="At places along the built-in tour: the three simulated LiDARs' frame through "
        "LidarPipeline.process (stage medians), heightmap ground removal on a dense ~125,000-point "
        "64-layer scan, and the ray casting of the three sensors for one frame, single-threaded "
        "(its share of a core at 10 Hz) and on every core.",
    )
    perception.add_argument("--json", action="store_true", help="print one JSON object (last line of stdout)")
    perception.add_argument(
        "--frames", type=positive_int, default=8, metavar="N", help="places along the tour, evenly spaced (default 8)"
    )
    perception.add_argument(
        "--repeats",
        type=positive_int,
        default=3,
        metavar="N",
        help="timed runs of the pipeline and the ground removal per place (default 3)",
    )
    perception.add_argument(
        "--reference",
        action="store_true",
        help="instead: our ground stage beside Patchwork++ (pypatchworkpp) on simulated HDL-64E scans of the "
        "tour and the --scan files: ground share, IoU, occupied cells and time of each",
    )
    perception.add_argument(
        "--scan",
        action="append",
        metavar="FILE",
        help="with --reference: a real scan (KITTI .bin, .pcd, .ply) to compare on too; repeatable",
    )
    mpc = bench_sub.add_parser(
        "mpc",
        help="the MPC's solve times in closed loop round the tour (in-process)",
        description="The MPC drives a kinematic bicycle (the steering's dead time and rate) "
        "round the built-in tour at its speed profile; each solve is timed.",
    )
    mpc.add_argument("--json", action="store_true", help="print one JSON object (last line of stdout)")
    mpc.add_argument("--solves", type=positive_int, default=2000, metavar="N", help="solves (default 2000)")
    mpc.add_argument("--vehicle", default="ares_shuttle", metavar="NAME", help="vehicle profile (default ares_shuttle)")
    zone = bench_sub.add_parser(
        "obstacle-zone",
        help="false stops of the obstacle manager's trapezoid beside a rectangle's, in the narrow lane",
        description="The built-in tour's narrow lane between rock walls, nothing in the way: every STEP m the three "
        "simulated LiDARs' frame through the perception pipeline, and the obstacle manager's trapezoid "
        "and a rectangle of the same length, each laid along the path ahead and along the wheels' arc; "
        "the frames each would have slowed or stopped the shuttle.",
    )
    zone.add_argument("--json", action="store_true", help="print one JSON object (last line of stdout)")
    zone.add_argument("--step", type=positive_float, default=2.0, metavar="M", help="between frames (default 2 m)")
    zone.add_argument(
        "--speed",
        type=positive_float,
        default=4.0,
        metavar="MPS",
        help="the speed the areas are sized for (default 4 m/s: the longest, 10 m)",
    )
    blackbox = bench_sub.add_parser(
        "blackbox",
        help="black box: ingest rate, one-hour query with 7 days stored, latest-state API over HTTPS",
        description="Ingests records in batches into a fresh embedded store, times one-hour queries with "
        "7 days of 1 Hz records (604,800) present, and loads the latest-state endpoint over "
        "HTTPS from a separate process (wrk when installed).",
    )
    blackbox.add_argument("--json", action="store_true", help="print one JSON object (last line of stdout)")
    blackbox.add_argument(
        "--seconds", type=positive_float, default=10.0, metavar="S", help="duration of the API load (default 10)"
    )
    live = bench_sub.add_parser(
        "live",
        help="how far the operator page lags the bus, with N browsers connected (the whole stack)",
        description="The whole stack at real time and N headless Chromium pages on /operator: each frame's lag from "
        "the moment its vehicle state was published on the bus to the page having drawn it.",
    )
    live.add_argument("--json", action="store_true", help="print one JSON object (last line of stdout)")
    live.add_argument("--browsers", type=positive_int, default=3, metavar="N", help="pages connected (default 3)")
    live.add_argument("--seconds", type=positive_float, default=30.0, metavar="S", help="measured (default 30)")
    live.add_argument("--config", action="append", metavar="FILE", help="configuration overrides, as for ares run")
    drivers = bench_sub.add_parser(
        "drivers",
        help="the device drivers: Velodyne decode per rotation (every model), CAN frames per second",
        description="Decodes and assembles full-resolution Velodyne rotations (VLP-16, HDL-32E, VLP-32C, "
        "HDL-64E, VLS-128) as the LiDAR driver does, and pushes CAN frames through the DBC codec and "
        "through python-can's udp_multicast into the CAN driver; medians of repeated rounds, in this process.",
    )
    drivers.add_argument("--json", action="store_true", help="print one JSON object (last line of stdout)")
    drivers.add_argument("--repeats", type=positive_int, default=20, metavar="N", help="rotations per model (20)")
    drivers.add_argument(
        "--seconds", type=positive_float, default=3.0, metavar="S", help="CAN measurement time (default 3)"
    )
    stack = bench_sub.add_parser(
        "stack",
        help="the whole stack at --speed max: speed-up, CPU per process, perception and MPC times, bus load, "
        "LiDAR-to-command lag",
        description="ares run --headless --speed max (a lap of the tour, the configuration's LiDARs) with probes: "
        "CPU per process (mean, p95), perception's frame time, the MPC's solve time, the bus's load and the lag "
        "from a roof rotation to the movement command; the lap's figures beside them.",
    )
    stack.add_argument("--json", action="store_true", help="print one JSON object (last line of stdout)")
    stack.add_argument("--laps", type=positive_int, default=1, metavar="N", help="laps of the tour (default 1)")
    stack.add_argument("--seconds", type=positive_float, metavar="S", help="vehicle seconds instead of laps")
    stack.add_argument("--config", action="append", metavar="FILE", help="configuration overrides, as for ares run")
    stack.add_argument("--wire", action="store_true", help="through the devices' wire formats, as ares run --wire")
    stack.add_argument(
        "--vehicle-cpus",
        type=cpu_list,
        metavar="LIST",
        help="as ares run --vehicle-cpus: the vehicle's own processes on these CPUs only, the simulator and "
        "the bench on the others (a vehicle computer of that many cores beside the simulated shuttle)",
    )
    stack.add_argument(
        "--speed",
        default="max",
        metavar="max|paced|FACTOR",
        help="as ares run --speed: max (default: the lockstep, as fast as every process keeps up), paced (the "
        "same, never faster than real time) or 1 (the wall clock, no lockstep: as on the vehicle)",
    )
    stack.add_argument(
        "--profile",
        type=Path,
        metavar="DIR",
        help="also sample every process with py-spy: a flame graph per process in DIR (slows the run)",
    )
    return {"bench": cmd_bench}


def _key_per_line(result: dict, out) -> None:
    for key, value in result.items():
        out.write(f"{key:32} {value}\n")


def _nested_per_line(result: dict, out, prefix: str = "") -> None:
    for key, value in result.items():
        if isinstance(value, dict):
            _nested_per_line(value, out, f"{prefix}{key}.")
        else:
            out.write(f"{prefix + key:40} {value}\n")


def _run(args: argparse.Namespace, progress):
    """(result, how to print it for people) of the chosen bench."""
    from ares.tools.bench.common import BenchError

    if args.bench == "blackbox":
        from ares.tools.bench.blackbox_api import run_api_bench
        from ares.tools.bench.blackbox_store import run_store_bench

        store = run_store_bench(progress=progress)
        api = run_api_bench(progress=progress, seconds=args.seconds)
        return {**store, **{k: v for k, v in api.items() if k not in store}}, _key_per_line
    if args.bench == "supervisor":
        from ares.tools.bench.supervisor import run_supervisor_bench

        return run_supervisor_bench(args.rounds, progress=progress), _key_per_line
    if args.bench == "perception" and args.reference:
        from ares.tools.bench.perception_reference import format_reference_result, run_reference_bench

        try:
            return run_reference_bench(
                args.frames, args.repeats, scans=args.scan or (), progress=progress
            ), format_reference_result
        except BenchError as exc:
            raise CliError(f"perception reference bench failed: {exc}") from None
    if args.bench == "perception" and args.scan:
        raise CliError("--scan goes with --reference")
    if args.bench == "perception":
        from ares.tools.bench.perception import format_perception_result, run_perception_bench

        return run_perception_bench(args.frames, args.repeats, progress=progress), format_perception_result
    if args.bench == "mpc":
        from ares.tools.bench.mpc import run_mpc_bench

        return run_mpc_bench(args.solves, args.vehicle, progress=progress), _key_per_line
    if args.bench == "obstacle-zone":
        from ares.tools.bench.obstacle_zone import run_obstacle_zone_bench

        return run_obstacle_zone_bench(args.step, args.speed, progress=progress), _key_per_line
    if args.bench == "live":
        from ares.tools.bench.live import run_live_bench

        try:
            return run_live_bench(
                args.browsers, args.seconds, config_files=tuple(args.config or ()), progress=progress
            ), _key_per_line
        except BenchError as exc:
            raise CliError(f"live bench failed: {exc}") from None
    if args.bench == "drivers":
        from ares.tools.bench.drivers_can import can_bench
        from ares.tools.bench.drivers_lidar import lidar_decode_bench

        progress("Velodyne rotations: decode and assembly")
        lidar = lidar_decode_bench(args.repeats)
        progress("CAN frames: codec and udp_multicast into the driver")
        return {"lidar": lidar, "can": can_bench(args.seconds)}, _nested_per_line
    if args.bench == "stack":
        from ares.tools.bench.stack import format_stack_result, run_stack_bench

        try:
            from ares.app.headless import drive
            from ares.cli import build_parser

            return run_stack_bench(
                build_parser().parse_args,
                drive,
                args.laps,
                args.seconds,
                tuple(args.config or ()),
                args.wire,
                profile_dir=args.profile,
                progress=progress,
                speed=args.speed,
                vehicle_cpus=args.vehicle_cpus,
            ), format_stack_result
        except BenchError as exc:
            raise CliError(f"stack bench failed: {exc}") from None
    if args.bench == "path":
        from ares.tools.bench.path import format_path_result, run_path_bench

        return run_path_bench(progress=progress), format_path_result
    from ares.tools.bench.bus import format_result, run_bus_bench

    try:
        return run_bus_bench(seconds=args.seconds, mode=args.mode, progress=progress), format_result
    except BenchError as exc:
        raise CliError(f"bus bench failed: {exc}") from None


def cmd_bench(args: argparse.Namespace) -> int:
    known = ("bus", "path", "blackbox", "supervisor", "perception", "mpc", "obstacle-zone", "live", "drivers", "stack")
    if args.bench not in known:
        raise CliError(
            "which benchmark? try `ares bench bus`, `ares bench path`, `ares bench supervisor`, "
            "`ares bench perception`, `ares bench mpc`, `ares bench obstacle-zone`, `ares bench blackbox`, "
            "`ares bench live`, `ares bench drivers` or `ares bench stack`"
        )
    progress = lambda msg: print(f"[bench] {msg}", file=sys.stderr, flush=True)  # noqa: E731
    result, for_people = _run(args, progress)
    if args.json:
        print(json.dumps(result))
    else:
        for_people(result, sys.stdout)
    return 0
