"""`ares mission start|pause|resume|cancel|status`: the mission manager's action from a terminal.

The mission manager obeys signed commands only (ares/core/signed_command.py): the CLI signs each with
the vehicle's command key, `commands.key_file` of the run configuration, else the user's state
directory's `command_key`, the file the stack's processes read too. So on a developer's machine a
stack started by the same user takes `ares mission ...` with nothing to set up, and a user who
cannot read the key cannot command the shuttle, whatever name they give.
"""

from __future__ import annotations

import argparse
import getpass
import json

from .args import CliError, Command, add_connection_args, connect, positive_float


def add_parser(subparsers: argparse._SubParsersAction) -> dict[str, Command]:
    mission = subparsers.add_parser(
        "mission",
        help="start, pause, resume, cancel the mission or see its status",
        description="The mission manager's services on the running stack. `start` sends a goal: the POIs named "
        "(in order), every POI of the route ahead (none named), or a drive round the route without "
        "stopping (--drive); a new goal pre-empts the one that runs. `status` prints the feedback.",
    )
    mission.add_argument("action", choices=["start", "pause", "resume", "cancel", "status"])
    mission.add_argument("pois", nargs="*", metavar="POI", help="start: the POIs to serve, in order")
    mission.add_argument("--drive", action="store_true", help="start: round the route without stopping")
    mission.add_argument(
        "--repeat", action="store_true", help="start: round again after the last POI (a closed route), until canceled"
    )
    mission.add_argument(
        "--operator",
        default=None,
        metavar="NAME",
        help="the name the black box keeps with the command, signed with the command key (default: your login name)",
    )
    mission.add_argument(
        "--seconds",
        type=positive_float,
        default=3.0,
        metavar="S",
        help="status: how long to wait for the mission's feedback (default 3)",
    )
    add_connection_args(mission)
    return {"mission": cmd_mission}


def cmd_mission(args: argparse.Namespace) -> int:
    from ares.core import config
    from ares.core.bus import ServiceError
    from ares.core.messages import MissionGoal, MissionRequest
    from ares.core.signed_command import load_command_key, sign

    if args.action != "start" and (args.pois or args.drive or args.repeat):
        raise CliError(f"`ares mission {args.action}` takes no POIs, --drive or --repeat")
    operator = args.operator or getpass.getuser()
    key = b""
    if args.action != "status":
        try:
            key = load_command_key(config.core(config.current()).commands)
        except (config.ConfigError, OSError, ValueError) as exc:
            raise CliError(f"cannot read the command key: {exc}") from None
    bus = connect(args, "cli")
    try:
        if args.action == "status":
            return _status(bus, args.seconds)
        try:
            if args.action == "start":
                goal = MissionGoal(operator=operator, pois=args.pois or None, drive=args.drive, repeat=args.repeat)
                reply = bus.call("mission/goal", sign(key, "mission/goal", goal, operator))
            else:
                service = f"mission/{args.action}"
                reply = bus.call(service, sign(key, service, MissionRequest(operator=operator), operator))
        except ServiceError as exc:
            raise CliError(str(exc)) from None
        print(f"{'accepted' if reply.accepted else 'refused'}: {reply.reason} (goal {reply.goal_id}, {reply.state})")
        return 0 if reply.accepted else 1
    finally:
        bus.close()


def _status(bus, seconds: float) -> int:
    import time

    sub = bus.subscribe("mission/status")
    deadline = time.monotonic() + seconds
    while sub.latest is None and time.monotonic() < deadline:
        time.sleep(0.05)
    if sub.latest is None:
        raise CliError(f"no mission status within {seconds:g} s: is the mission manager running?")
    print(json.dumps(sub.latest.model_dump(mode="json")))
    return 0
