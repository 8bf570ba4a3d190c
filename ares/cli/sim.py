"""`ares sim serve`: the simulated shuttle alone, behind its wires (ares/app/wire_sim.py)."""

from __future__ import annotations

import argparse

from .args import CliError, Command, endpoint


def add_parser(subparsers: argparse._SubParsersAction) -> dict[str, Command]:
    sim = subparsers.add_parser(
        "sim",
        help="the simulated shuttle alone, behind its wires, for a stack run as on a vehicle",
        description="The simulator and its LiDARs on the wall clock, writing NMEA to a pseudo-terminal, "
        "Velodyne packets to UDP and CAN frames to a udp_multicast group; a stack with simulate: false "
        "reads them through its drivers (ares run --vehicle-io DIR/vehicle_io.yaml, beside it on its router).",
    )
    sub = sim.add_subparsers(dest="sim", metavar="ACTION")
    serve = sub.add_parser("serve", help="run the simulated shuttle behind its wires until Ctrl-C")
    serve.add_argument("--wire-dir", required=True, metavar="DIR", help="where vehicle_io.yaml and clock.env go")
    serve.add_argument("--config", action="append", default=[], metavar="FILE", help="a config file (repeatable)")
    serve.add_argument("--route", metavar="NAME|FILE", help="a built-in tour or a route file, as for ares run")
    serve.add_argument("--listen", type=endpoint, metavar="ENDPOINT", help="host the router here (default bus.router)")
    serve.add_argument("--run-dir", metavar="DIR", help="where its config and logs go")
    return {"sim": cmd_sim}


def cmd_sim(args: argparse.Namespace) -> int:
    from pathlib import Path

    from ares.app import wire_sim
    from ares.app.run_options import RunOptions
    from ares.app.stack import default_run_dir
    from ares.core import config

    if args.sim != "serve":
        raise CliError("ares sim: say what to do (serve)")
    try:
        overrides = RunOptions(route=args.route, listen=args.listen).overrides()
        cfg = wire_sim.sim_config(tuple(args.config), overrides, Path(args.wire_dir).resolve())
    except config.ConfigError as exc:
        raise CliError(str(exc)) from None
    run_dir = Path(args.run_dir) if args.run_dir else default_run_dir()
    return wire_sim.serve(cfg, Path(args.wire_dir).resolve(), run_dir)
