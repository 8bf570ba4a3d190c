"""`ares run` (the whole stack, supervised: ares.app.stack.run, given the options the arguments
ask for) and `ares node` (one of its processes)."""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from .args import CliError, Command, cpu_list, endpoint, non_negative_int, positive_float, positive_int, vehicle_id

if TYPE_CHECKING:
    from ares.app.run_options import RunOptions


def speed(text: str) -> float | str:
    """--speed: a positive factor, `max` (the simulator drives the clock) or `paced` (it drives
    the clock, at most at real time)."""
    word = text.strip().lower()
    return word if word in ("max", "paced") else positive_float(text)


def add_parser(subparsers: argparse._SubParsersAction) -> dict[str, Command]:
    run = subparsers.add_parser(
        "run",
        help="run the whole stack (simulated shuttle, embedded router)",
        description="Run the whole stack: router, simulator and every process, supervised.",
    )
    run.add_argument(
        "--headless",
        action="store_true",
        help="unattended: engage Automatic, drive --laps laps, print one JSON result line",
    )
    run.add_argument(
        "--manual",
        action="store_true",
        help="do not engage Automatic mode (interactive runs): drive with the sim/driver service",
    )
    run.add_argument("--laps", type=positive_int, metavar="N", help="laps of the tour to drive headless (default 1)")
    run.add_argument(
        "--speed",
        type=speed,
        metavar="X",
        help="the clock. In simulation by default `paced`: the simulator drives the clock, never faster "
        "than real time (a machine too small for the stack runs it slower instead of starving the simulated "
        "sensors into faults); `max`: the same, as fast as every process keeps up; a factor X: simulated "
        "seconds per wall second, each process on its own timers (1: real time). On the vehicle "
        "(simulate: false) the wall clock",
    )
    run.add_argument(
        "--config",
        action="append",
        default=[],
        metavar="FILE",
        help="a YAML file of configuration overrides (repeatable; later files win); "
        "`ares config show` prints every key",
    )
    run.add_argument(
        "--route",
        metavar="NAME|FILE",
        help="a built-in tour (ares/core/config/tours/: default, campus), a tour's "
        "YAML, or an open route (CSV of x,y[,z] metres)",
    )
    run.add_argument(
        "--scenario",
        metavar="NAME|FILE",
        help="simulated obstacles and faults: a built-in scenario (simulator/scenarios/) or a YAML file",
    )
    run.add_argument(
        "--mission",
        choices=["tour", "drive", "none"],
        help="the goal the mission manager sets itself: tour (stop at every POI: doors, ramp, "
        "passengers), drive (round the route without stopping) or none (`ares mission start`); "
        "default: the scenario's, else mission_manager.autostart (tour)",
    )
    run.add_argument(
        "--controller",
        choices=["auto", "mpc", "rrc", "pure_pursuit", "stanley"],
        help="pin one controller for comparisons (default auto: the control manager chooses)",
    )
    run.add_argument(
        "--wire",
        action="store_true",
        help="put the simulator behind the devices' wire formats: it writes NMEA to a pseudo-terminal, "
        "Velodyne packets over UDP and CAN frames (python-can udp_multicast), and the stack reads "
        "them through its drivers, which print their figures at the end of a headless run",
    )
    run.add_argument(
        "--vehicle-io",
        metavar="FILE",
        help="the vehicle's devices (a YAML file of the vehicle_io section: gnss, lidars, can); "
        "a run with simulate: false needs one (docs/vehicle_io.md)",
    )
    run.add_argument("--vehicle", metavar="NAME", help="vehicle profile (config/vehicles/NAME.yaml)")
    run.add_argument("--passengers", type=non_negative_int, metavar="N", help="passengers on board")
    run.add_argument("--vehicle-id", type=vehicle_id, metavar="ID", help="vehicle id in the bus keys")
    run.add_argument(
        "--router",
        type=endpoint,
        metavar="ENDPOINT",
        help="use this external router instead of hosting the embedded one",
    )
    run.add_argument(
        "--listen",
        type=endpoint,
        metavar="ENDPOINT",
        help="where the embedded router listens (default: bus.router, tcp/127.0.0.1:7447)",
    )
    run.add_argument(
        "--vehicle-cpus",
        type=cpu_list,
        metavar="LIST",
        help="run the vehicle's own processes on these CPUs only (like 0 or 0-1), the simulator and this "
        "process (supervisor, router, measurements) on the others: the vehicle computer's share of this "
        "machine (the cpus: section sets each part)",
    )
    run.add_argument("--run-dir", metavar="DIR", help="where the run's config and logs go")
    run.add_argument("--api-port", type=int, metavar="PORT", help="port of the REST API (default: api.port, 8443)")
    run.add_argument(
        "--store",
        metavar="URI",
        help="black box store for the recorder and the API: a mongodb:// URI or the embedded "
        "store's file (default: blackbox_store.uri, else data/blackbox.sqlite)",
    )
    run.add_argument(
        "--fleet",
        type=positive_int,
        metavar="N",
        help="N simulated shuttles on one router (ids shuttle01, shuttle02, ...; APIs on consecutive "
        "ports), for the fleet page; interactive only",
    )
    run.add_argument(
        "--seconds",
        type=positive_float,
        metavar="S",
        help="headless: drive for S seconds of vehicle time (the tour repeats as needed) instead of --laps",
    )

    run.add_argument(
        "--record",
        nargs="?",
        const="",
        metavar="[full|light][:FILE.mcap]",
        help="record the run's bus to an MCAP file: `full` (every message, the default: "
        "`recording.profile`) or `light` (a few per second of each topic, no clouds), to FILE "
        "(default: bus.mcap or bus-light.mcap in the run folder); it opens in Foxglove, and "
        "`ares replay FILE.mcap` plays it back (docs/recording.md)",
    )
    run.add_argument(
        "--foxglove",
        nargs="?",
        const="",
        metavar="[HOST:]PORT",
        help="serve the live bus to Foxglove over its WebSocket protocol (default 127.0.0.1:8765)",
    )

    node = subparsers.add_parser(
        "node",
        help="run one process of the stack in the foreground",
        description="Run one process of the process table in the foreground.",
    )
    node.add_argument("name", metavar="NAME", help="process name (see the process table)")
    return {"run": cmd_run, "node": cmd_node}


def cmd_run(args: argparse.Namespace) -> int:
    from ares.app import stack

    result = stack.run(run_options(args))
    if not result.ok:
        print(f"ares run: {result.error}" + (f" (logs in {result.logs})" if result.logs else ""), file=sys.stderr)
    if args.headless and not result.refused:
        print(json.dumps(result.summary()))
    return result.exit_code


def run_options(args: argparse.Namespace) -> RunOptions:
    """The run `ares run`'s arguments ask for."""
    from ares.app.run_options import RunOptions

    return RunOptions(
        config_files=tuple(args.config),
        headless=args.headless,
        manual=args.manual,
        laps=args.laps,
        seconds=args.seconds,
        speed=args.speed,
        route=args.route,
        scenario=args.scenario,
        mission=args.mission,
        controller=args.controller,
        wire=args.wire,
        vehicle_io=args.vehicle_io,
        vehicle=args.vehicle,
        passengers=args.passengers,
        vehicle_id=args.vehicle_id,
        router=args.router,
        listen=args.listen,
        vehicle_cpus=None if args.vehicle_cpus is None else tuple(args.vehicle_cpus),
        run_dir=None if args.run_dir is None else Path(args.run_dir),
        api_port=args.api_port,
        store=args.store,
        fleet=args.fleet or 1,
        record=args.record,
        foxglove=args.foxglove,
    )


def cmd_node(args: argparse.Namespace) -> int:
    from ares.app import processes
    from ares.core.node import PROCESS_ENV, run_node

    try:
        spec = processes.by_name(args.name)
    except KeyError as exc:
        raise CliError(exc.args[0]) from None
    try:
        cls = spec.node_class()
    except (ImportError, ValueError) as exc:
        raise CliError(f"process {spec.name!r}: its node {spec.node} cannot be loaded: {exc}") from None
    os.environ.setdefault(PROCESS_ENV, spec.name)
    run_node(cls)
    return 0
