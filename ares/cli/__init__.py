"""The `ares` command line.

    ares run [--headless] [--manual] [--laps N] [--speed X|max|paced] [--config FILE] [--route NAME|FILE]
             [--scenario NAME|FILE] [--mission tour|drive|none] [--controller auto|mpc|rrc|pure_pursuit|stanley]
             [--wire] [--vehicle-io FILE] [--vehicle NAME] [--passengers N] [--vehicle-id ID] [--router ENDPOINT]
             [--listen ENDPOINT] [--vehicle-cpus LIST] [--run-dir DIR] [--api-port PORT] [--store URI]
             [--fleet N] [--seconds S] [--record [[full|light][:FILE.mcap]]] [--foxglove [[HOST:]PORT]]
                                   the whole stack (simulated shuttle, embedded router), or a headless run
    ares node NAME                 run one process of the stack in the foreground
    ares compare [--controllers LIST] [--route NAME|FILE] [--vehicle NAME] [--scenario NAME|FILE] [--laps N]
                 [--mission tour|drive] [--seconds S] [--config FILE] [--out PNG] [--json]
                                   the same headless run with each controller, figures side by side, and a picture
    ares reproduce [--only ID ...] [--out DIR] [--quick] [--list] [--json]
                                   the papers' experiments on ARES beside the papers' numbers: a report with pictures
    ares describe [NODE | --package NAME [--write]] [--json|--markdown|--architecture] [--config FILE]
                                   each process's inputs, outputs, services, parameters; the topic graph;
                                   docs/nodes.md (--markdown), docs/architecture.md (--architecture); a node
                                   package's (managers, perception, control, drivers, blackbox, simulator)
                                   README part (--package NAME --markdown; --write puts it in place)
    ares config check FILE...      validate configuration files (exit 2 naming the file and the key)
    ares config show [FILE...] [--json]
                                   the merged, validated configuration, every key commented
    ares replay check|update FILE...
                                   process replay of recorded node inputs against their outputs
    ares replay FILE.mcap [--node NAME] [--speed X|max] [--info] [--json] [--listen ENDPOINT | --router ENDPOINT]
                                   an MCAP recording of the bus: played into a bus, one process replayed
                                   against its recorded outputs, or its channels listed
    ares calibrate odometry [--laps N] [--seed S]
                                   re-run the experiment that chose the odometry score's a, b, c
    ares calibrate lidars [--vehicle NAME] [--seed S] [--offset-m M] [--offset-deg DEG] [--write PATH] [--json]
                                   find the LiDARs' extrinsics against each other in a simulated warehouse
    ares calibrate road [--samples N] [--seed S] [--write PATH] [--json]
                                   re-run the search that chose road detection's β (docs/road_detection.md)
    ares calibrate rrc-view [--seed S] [--json]
                                   where road reactive control reads the road at the vehicle (docs/control.md)
    ares topics [--seconds S] [--json] [--router ENDPOINT] [--vehicle-id ID]
                                   keys seen under ares/<vehicle_id>/**, rates, schemas, live processes
    ares echo KEY [--count N] [--seconds S] [--router ENDPOINT] [--vehicle-id ID]
                                   print messages on a topic, one JSON object per line
    ares driver button|throttle|brake|steer|release [VALUE] [--duration S] [--router ENDPOINT] [--vehicle-id ID]
                                   act as the simulated shuttle's driver
    ares auto [--router ENDPOINT] [--vehicle-id ID]
                                   ask the drive-by-wire bridge for Automatic mode
    ares record [KEY ...] [--out FILE.mcap] [--seconds S] [--compression zstd|lz4|none] [--no-views]
                [--router ENDPOINT] [--vehicle-id ID]
                                   the running stack's bus to MCAP (opens in Foxglove; docs/recording.md)
    ares snapshot [--reason TEXT] [--by NAME] [--wait S] [--router ENDPOINT] [--vehicle-id ID]
                                   an incident snapshot now: the seconds before and after, saved in the black box
    ares mission start [POI ...] [--drive] [--repeat] | pause | resume | cancel | status [--operator NAME]
                 [--seconds S] [--router ENDPOINT] [--vehicle-id ID]
                                   the mission manager's action: a goal of POIs (all of the route's if none
                                   named), a drive without stops, pause, resume, cancel, the feedback
    ares bench bus [--json] [--check] [--seconds S] [--mode peer|client]
                                   publish -> subscribe latency and throughput between two processes
    ares bench supervisor [--json] [--check] [--rounds N]
                                   how fast a killed, frozen or hung process is noticed and restarted
    ares bench path [--json] [--check]
                                   KD-tree build, path match and UKF step times (in-process)
    ares bench perception [--json] [--check] [--frames N] [--repeats N] [--reference] [--scan FILE]
                                   LiDAR pipeline stage times, the simulated LiDARs' ray casting (in-process);
                                   --reference: the ground stage beside Patchwork++ on KITTI-like scans
    ares bench mpc [--json] [--check] [--solves N] [--vehicle NAME]
                                   the MPC's solve times in closed loop round the tour (in-process)
    ares bench obstacle-zone [--json] [--check] [--step M] [--speed MPS]
                                   the obstacle area's false stops in the narrow lane, trapezoid vs rectangle
    ares bench blackbox [--json] [--check] [--seconds S]
                                   store ingest and hour query, latest-state API req/s over HTTPS
    ares bench live [--json] [--check] [--browsers N] [--seconds S] [--config FILE]
                                   how far the operator page lags the bus, with N browsers (the whole stack)
    ares bench drivers [--json] [--check] [--repeats N] [--seconds S]
                                   Velodyne decode per rotation (every model), CAN frames per second
    ares bench record [--json] [--check] [--recording FILE.mcap]
                                   a recording's cost per profile, cloud encoding and topic class: MB/s, writer CPU
    ares bench stack [--json] [--check] [--laps N] [--seconds S] [--config FILE] [--wire] [--vehicle-cpus LIST]
                     [--speed max|paced|FACTOR] [--profile DIR]
                                   a lap of the whole stack: speed-up, CPU per process, perception and MPC
                                   times, bus load, LiDAR-to-command lag; py-spy flame graphs (--profile)
    ares bench report FILE... [--out FILE.md]
                                   the benches' --json results as one Markdown table (figure, value, goal, met)
    ares route import FILE -o ROUTE [--format auto|csv|nmea] [--spacing M] [--strict]
                                   build a route file from a CSV of x,y[,z] or an NMEA log
    ares route record FILE [--seconds S] [--router ENDPOINT] [--vehicle-id ID]
                                   write the NMEA sentences of the running stack's receiver to FILE
    ares route profile ROUTE [--vehicle NAME] [--out FILE.png|svg]
                                   draw a route's speed profile and its single-speed sections
    ares route coverage [--store URI] [--vehicle-id ID] [--config FILE] [--route ROUTE] [--out PNG]
                                   where along the route RTK corrections and an RTK fix are to be had (the
                                   simulated receiver, or a run's black box), and the share covered
    ares api [--host H] [--port P] [--store URI] [--insecure-http]
                                   serve the black box's REST API (HTTPS; self-signed certificate if none configured)
    ares users add NAME --role auditor|operator|fleet|admin|passenger [--store URI]
                                   add an API user; the password is read from stdin (asked twice on a terminal)
    ares users list [--store URI] [--json]
                                   list the API's users and their roles
    ares users role NAME auditor|operator|fleet|admin|passenger [--store URI]
                                   change a user's role (the tokens they hold are refused from then on)
    ares users passwd NAME [--store URI]
                                   change a user's password, read from stdin
    ares users disable|enable NAME [--store URI]
                                   refuse a user's logins and tokens, or allow them again
    ares users delete NAME [--store URI]
                                   remove a user (their tokens are refused at their next request)
    ares perception scan FILE [--sensor-height M] [--vehicle NAME] [--json] [--out PNG]
                         [--model VLP-16|HDL-32E|VLP-32C|HDL-64E|VLS-128] [--frame N] [--calibration YAML]
                         [--port PORT] [--fov START END]
                                   one LiDAR scan (KITTI .bin, .pcd, .ply) or one rotation of a Velodyne
                                   capture (.pcap, with --model) through the perception pipeline: one JSON
                                   line and a top view (exit 2 when the file gives no usable scan)
    ares deploy certs --fleet-ca DIR --vehicle ID [--fleet-host NAME] [--api-host NAME] [--fleet-endpoint ENDPOINT]
                                   the fleet CA (made if absent), a vehicle's certificate, credentials and router config
    ares deploy router-config fleet|vehicle [--vehicles ID,ID] [-o FILE]
                                   a router's config, as deploy/ holds it
    ares deploy router --config FILE [--secrets DIR] [--listen ENDPOINT] [--connect ENDPOINT]
                       [--report-refusals-as ID]
                                   run a router from a deployment's JSON5 file (stands in for zenohd)
    ares deploy rehearse [--json] [--light] [--partition-s S] [--work DIR] [--containers [--base B]]
                                   as root: the fleet and two vehicles across network namespaces, a
                                   partition, the refusals, a restart (docs/deploy.md); --containers:
                                   the compose stacks under a Docker engine
    ares deploy images [--base debootstrap|python] [--json]
                                   the base and the ares image built (an engine started if none runs);
                                   each step's time, each image's size
    ares deploy check DIR [--json] a deployment folder checked before `docker compose up` (compose file,
                                   secrets, certificates, ARES configs)
    ares deploy manifest --key KEY --out MANIFEST
                                   the installed stack's files hashed and signed with the fleet's Ed25519
                                   release key (made at KEY, public half KEY.pub, when absent); `ares run`
                                   refuses to start a stack that differs (the `release` section)
    ares fleet serve [--config FILE] [--router ENDPOINT] [--store URI] [--api-port PORT] [--run-dir DIR]
                                   the fleet server: every vehicle's black box in the fleet's store, its API
    ares sim serve --wire-dir DIR [--config FILE] [--route NAME|FILE] [--listen ENDPOINT] [--run-dir DIR]
                                   the simulated shuttle alone behind its wires, for a run with simulate: false
    ares soak [--hours H] [--faults N] [--seed S] [--json] [--config FILE] [--route NAME|FILE] [--out DIR]
              [--listen ENDPOINT] [--api-port PORT] [--lead S] [--kinds K,K] | --summarise DIR | --resume DIR
                                   the tour at --speed max with faults injected from a seeded plan; a stopped
                                   soak summarised or gone on with (docs/reliability.md)

A bench's --json prints its result as one JSON line (its goals and `goals_met` in it); --check
exits 1 when it missed a goal, naming each on stderr (without it a bench that ran exits 0).

`topics` and `echo` connect in client mode to the running stack's router (the `bus.router`
endpoint of the run configuration, or --router) and look under the configured vehicle id (or
--vehicle-id). A client session fails at once when no router listens there.
tests/test_cli_usage.py holds this text to the parsers: every command, its every option.
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
    reproduce,
    route,
    run,
    sim,
    soak,
)
from .args import CliError, Command

COMMAND_GROUPS = (
    run,
    compare,
    reproduce,
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
