"""The `ares` command line.

    ares run [--headless] [--manual] [--laps N] [--speed X|max] [--config FILE] [--route FILE]
             [--vehicle NAME] [--passengers N] [--vehicle-id ID] [--router ENDPOINT] [--run-dir DIR]
             [--store URI] [--seconds S] [--controller auto|mpc|rrc|pure_pursuit] [--scenario NAME|FILE]
             [--wire] [--vehicle-io FILE] [--record [FILE.mcap]] [--foxglove [[HOST:]PORT]]
    ares compare [--controllers mpc,pure_pursuit] [--route R] [--vehicle V] [--scenario S] [--laps N|--seconds S]
                                   the same headless run with each controller, figures side by side, and a picture
    ares node NAME                 run one process of the stack in the foreground
    ares describe [NODE] [--json|--markdown]
                                   each process's inputs, outputs, services, parameters; the topic graph
    ares config check FILE...      validate configuration files (exit 2 naming the file and the key)
    ares config show [FILE...]     the merged, validated configuration, every key commented
    ares replay check|update FILE...
                                   process replay of recorded node inputs against their outputs
    ares replay FILE.mcap [--node NAME] [--speed X|max] [--info] [--listen EP | --router EP]
                                   an MCAP recording of the bus: played into a bus, one process replayed
                                   against its recorded outputs, or its channels listed
    ares record [KEY ...] [--out FILE.mcap] [--seconds S]
                                   the running stack's bus to MCAP (opens in Foxglove; docs/recording.md)
    ares calibrate odometry        re-run the experiment that chose the odometry score's a, b, c
    ares calibrate lidars [--vehicle NAME] [--seed S] [--offset-m M] [--offset-deg D] [--write PATH] [--json]
                                   find the LiDARs' extrinsics against each other in a simulated warehouse
    ares topics [--seconds S]      keys seen under ares/<vehicle_id>/**, rates, schemas, live processes
    ares echo KEY [--count N] [--seconds S]
                                   print messages on a topic, one JSON object per line
    ares driver button|throttle|brake|steer|release [VALUE] [--duration S]
                                   act as the simulated shuttle's driver
    ares auto                      ask the drive-by-wire bridge for Automatic mode
    ares mission start [POI ...] [--drive] | pause | resume | cancel | status [--operator NAME]
                                   the mission manager's action: a goal of POIs (all of the route's if none
                                   named), a drive without stops, pause, resume, cancel, the feedback
    ares bench bus [--json] [--seconds S] [--mode peer|client]
    ares bench supervisor [--json] [--rounds N]
    ares route import FILE -o ROUTE [--format auto|csv|nmea] [--spacing M] [--strict]
                                   build a route file from a CSV of x,y[,z] or an NMEA log
    ares route record FILE [--seconds S]
                                   write the NMEA sentences of the running stack's receiver to FILE
    ares route profile ROUTE [--vehicle NAME] [--out FILE.png|svg]
                                   draw a route's speed profile and its single-speed sections
    ares bench path [--json]       KD-tree build, path match and UKF step times (in-process)
    ares bench perception [--json] [--frames N] [--repeats N]
                                   LiDAR pipeline stage times, the simulated LiDARs' ray casting (in-process)
    ares bench blackbox [--json]   store ingest and hour query, latest-state API req/s over HTTPS
    ares bench drivers [--json] [--repeats N] [--seconds S]
                                   Velodyne decode per rotation (VLP-16, HDL-64E), CAN frames per second
    ares api [--host H] [--port P] [--store URI] [--insecure-http]
                                   serve the black box's REST API (HTTPS; self-signed certificate if none configured)
    ares users add NAME --role ROLE [--store URI]
                                   add an API user; the password is read from stdin (asked twice on a terminal)
    ares users list [--store URI] [--json]
    ares perception scan FILE [--sensor-height M] [--vehicle NAME] [--out PNG]
                                   one LiDAR scan (KITTI .bin, .pcd, .ply) through the perception pipeline:
                                   one JSON line and a top view (exit 2 when the file gives no usable scan)
    ares deploy certs --fleet-ca DIR --vehicle ID [--fleet-host NAME] [--fleet-endpoint ENDPOINT]
                                   the fleet CA (made if absent), a vehicle's certificate, credentials and router config
    ares deploy router-config fleet|vehicle [--vehicles ID,ID] [-o FILE]
                                   a router's config, as deploy/ holds it
    ares deploy router --config FILE [--secrets DIR] [--listen EP] [--connect EP]
                                   run a router from a deployment's JSON5 file (stands in for zenohd)
    ares fleet serve [--config FILE] [--router EP] [--store URI] [--api-port P] [--run-dir DIR]
                                   the fleet server: every vehicle's black box in the fleet's store, its API
    ares soak [--hours H] [--faults N] [--seed S] [--json] [--config FILE] [--out DIR] | --summarise DIR
                                   the tour at --speed max with faults injected from a seeded plan (docs/reliability.md)
    ares sim serve --wire-dir DIR [--config FILE] [--route R] [--listen EP] [--run-dir DIR]
                                   the simulated shuttle alone behind its wires, for a run with simulate: false

`topics` and `echo` connect in client mode to the running stack's router (the `bus.router`
endpoint of the run configuration, or --router) and look under the configured vehicle id (or
--vehicle-id). A client session fails at once when no router listens there.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys

from . import (
    bench,
    blackbox,
    bus_tools,
    compare,
    deploy,
    fleet,
    inspect,
    mission,
    perception,
    record,
    route,
    run,
    sim,
    soak,
)
from .args import CliError, Command

COMMAND_GROUPS = (
    run,
    compare,
    inspect,
    bus_tools,
    record,
    mission,
    bench,
    route,
    blackbox,
    perception,
    deploy,
    fleet,
    sim,
    soak,
)  # as `ares --help` lists them


def build_parser() -> argparse.ArgumentParser:
    return _parser_and_commands()[0]


def _parser_and_commands() -> tuple[argparse.ArgumentParser, dict[str, Command]]:
    parser = argparse.ArgumentParser(prog="ares", description="ARES supervisory stack for autonomous shuttles.")
    try:
        from importlib.metadata import version

        parser.add_argument("--version", action="version", version=f"ares {version('ares')}")
    except Exception:
        pass
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    commands: dict[str, Command] = {}
    for group in COMMAND_GROUPS:
        commands.update(group.add_parser(subparsers))
    return parser, commands


def main(argv: list[str] | None = None) -> int:
    parser, commands = _parser_and_commands()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, or a usage error already printed by argparse
        return int(exc.code or 0) if not isinstance(exc.code, str) else 2
    if args.command is None:
        parser.print_help(sys.stderr)
        return 2
    if args.command != "node":
        logging.basicConfig(
            level=os.environ.get("ARES_LOG_LEVEL", "WARNING").upper(),
            stream=sys.stderr,
            format="%(levelname)s %(name)s: %(message)s",
        )
    try:
        return commands[args.command](args)
    except CliError as exc:
        print(f"ares: error: {exc}", file=sys.stderr)
        return 1
    except BrokenPipeError:  # e.g. `ares echo ... | head`
        try:
            sys.stdout = open(os.devnull, "w")
        except OSError:
            pass
        return 0
    except KeyboardInterrupt:
        return 130
