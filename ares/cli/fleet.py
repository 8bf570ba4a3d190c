"""`ares fleet serve`: the fleet server (ares/app/fleet_server.py, deploy/fleet)."""

from __future__ import annotations

import argparse

from .args import CliError, Command, endpoint, port


def add_parser(subparsers: argparse._SubParsersAction) -> dict[str, Command]:
    fleet = subparsers.add_parser(
        "fleet",
        help="the fleet server: every vehicle's black box and the fleet's API",
        description="The fleet server's processes under one supervisor: fleet_sync (every vehicle's "
        "black box from the fleet router into the fleet's store, gaps filled after a lost link) and "
        "fleet_api (the REST API and the pages over that store, with every vehicle's live view).",
    )
    sub = fleet.add_subparsers(dest="fleet", metavar="ACTION")
    serve = sub.add_parser("serve", help="run the fleet server until Ctrl-C")
    serve.add_argument("--config", action="append", default=[], metavar="FILE", help="a config file (repeatable)")
    serve.add_argument("--router", type=endpoint, metavar="ENDPOINT", help="the fleet router's local endpoint")
    serve.add_argument("--store", metavar="URI", help="the fleet's store: a mongodb:// URI or a file")
    serve.add_argument("--api-port", type=port, metavar="PORT", help="port of the REST API (default api.port)")
    serve.add_argument("--run-dir", metavar="DIR", help="where the config and logs go")
    return {"fleet": cmd_fleet}


def cmd_fleet(args: argparse.Namespace) -> int:
    from pathlib import Path

    from ares.app import fleet_server
    from ares.app.stack import default_run_dir
    from ares.core import config

    if args.fleet != "serve":
        raise CliError("ares fleet: say what to do (serve)")
    overrides: dict = {}
    if args.router:
        overrides["bus"] = {"router": args.router, "embedded_router": False}
    if args.store:
        overrides["blackbox_store"] = {"uri": args.store}
    if args.api_port:
        overrides["api"] = {"port": args.api_port}
    try:
        cfg = fleet_server.fleet_config(tuple(args.config), overrides)
    except config.ConfigError as exc:
        raise CliError(str(exc)) from None
    run_dir = Path(args.run_dir) if args.run_dir else default_run_dir()
    return fleet_server.serve(cfg, run_dir)
