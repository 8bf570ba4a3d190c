"""`ares route import` (a route file from a recorded drive), `ares route record` (an NMEA
log from the running stack's receiver) and `ares route profile` (the speed manager's profile
and sections of a route, drawn as the ARES paper's Figure 17)."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from .args import CliError, Command, add_connection_args, connect, positive_float


def add_parser(subparsers: argparse._SubParsersAction) -> dict[str, Command]:
    route = subparsers.add_parser(
        "route",
        help="route files: import a recorded drive, record an NMEA log",
        description="Route files for `ares run --route FILE`.",
    )
    route_sub = route.add_subparsers(dest="route", metavar="ACTION")
    imp = route_sub.add_parser(
        "import",
        help="build a route file from a CSV of x,y[,z] metres or an NMEA log",
        description="Build a route from a recorded drive: project the fixes (GGA; RMC or "
        "GLL when a log has none) to a local frame, drop standstill "
        "duplicates, resample evenly, smooth, add yaw. Writes a CSV x,y,z,yaw "
        "with its origin that `ares run --route` reads. A receiver's log is "
        "read as it comes: comments, headers, CRLF, other sentences and "
        "talkers are counted and skipped, and so is a bad line, by reason.",
    )
    imp.add_argument("file", metavar="FILE", help="the recording: CSV of x,y[,z] metres, or an NMEA log")
    imp.add_argument("-o", "--output", required=True, metavar="ROUTE", help="route file to write (CSV)")
    imp.add_argument(
        "--format",
        choices=["auto", "csv", "nmea"],
        default="auto",
        help="input format (default: auto, NMEA when most lines hold NMEA sentences)",
    )
    imp.add_argument(
        "--spacing",
        type=positive_float,
        metavar="M",
        help="distance between route points, metres (default gnss.route_import.spacing_m, 0.5)",
    )
    imp.add_argument(
        "--strict",
        action="store_true",
        help="fail on the first bad NMEA line (bad checksum, broken field, beyond the frame's "
        "reach) instead of skipping and counting it",
    )
    rec = route_sub.add_parser(
        "record",
        help="write the NMEA sentences arriving on sensors/gnss to a file",
        description="Record an NMEA log from the running stack's GNSS receiver "
        "(sensors/gnss), one sentence per line, until --seconds or Ctrl-C. "
        "Drive the route meanwhile, then `ares route import FILE -o ROUTE`.",
    )
    rec.add_argument("file", metavar="FILE", help="NMEA log to write")
    rec.add_argument("--seconds", type=positive_float, metavar="S", help="stop after S seconds (default: Ctrl-C)")
    add_connection_args(rec)
    prof = route_sub.add_parser(
        "profile",
        help="draw a route's speed profile and its single-speed sections",
        description="The speed manager's profile of a route (ARES §3.6.3, Figure 17): "
        "the top speed on straights, sqrt(a_lat R) in turns, slowing before "
        "them, grade considered, reduced to numbered single-speed sections. "
        "Draws the profile over s and the path coloured by speed (the "
        "speed_profile section of the run configuration); prints one JSON "
        "line.",
    )
    prof.add_argument("route_name", metavar="ROUTE", help="a built-in tour's name, a tour YAML or a route CSV")
    prof.add_argument(
        "--vehicle",
        metavar="NAME",
        help="vehicle profile: a name in ares/core/config/vehicles/ or a YAML file (default: the run configuration's)",
    )
    prof.add_argument(
        "--out", metavar="FILE", help="picture to write, .png or .svg (default: ROUTE's name + .profile.png, here)"
    )
    cov = route_sub.add_parser(
        "coverage",
        help="where along the route the RTK corrections and an RTK fix are to be had, and the share covered",
        description="Drives the run configuration's route (simulated: at its speed profile, the simulated "
        "receiver and its 4G link, the tour's no_4g and rtk_loss zones) or reads a run's black box "
        "(--store), and draws the route coloured by the receiver's fix, with where the corrections "
        "arrived, after the ARES paper's Figure 3 (there: 95 %% of the route with RTK). Prints one "
        "JSON line: the shares of the route with RTK fixed and with corrections.",
    )
    cov.add_argument("--store", metavar="URI", help="a run's black box (its SQLite file or a MongoDB URI): recorded")
    cov.add_argument("--vehicle-id", metavar="ID", help="with --store: that vehicle's records (default: all)")
    cov.add_argument("--config", action="append", metavar="FILE", help="configuration overrides, as for ares run")
    cov.add_argument(
        "--route", dest="route_name", metavar="ROUTE", help="a built-in tour's name or a route CSV (default: the run's)"
    )
    cov.add_argument("--out", metavar="PNG", help="picture to write (default: ROUTE's name + .coverage.png, here)")
    return {"route": cmd_route}


def cmd_route(args: argparse.Namespace) -> int:
    if args.route == "import":
        return _route_import(args)
    if args.route == "record":
        return _route_record(args)
    if args.route == "profile":
        return _route_profile(args)
    if args.route == "coverage":
        return _route_coverage(args)
    raise CliError(
        "which action? try `ares route import FILE -o ROUTE`, `ares route record FILE`, `ares route profile ROUTE` "
        "or `ares route coverage`"
    )


def _route_import(args: argparse.Namespace) -> int:
    from ares.app import route_import
    from ares.core import config
    from ares.core.route import Route, RouteError

    try:
        cfg = config.current()
    except (config.ConfigError, OSError, ValueError) as exc:
        raise CliError(f"cannot read the run configuration: {exc}") from None
    try:
        result = route_import.import_route(
            args.file, args.output, fmt=args.format, spacing_m=args.spacing, strict=args.strict, cfg=cfg
        )
        Route.from_csv(args.output)  # what `ares run --route` will do: it must read it back
    except RouteError as exc:
        raise CliError(str(exc)) from None
    print(f"imported {result.summary()}")
    return 0


def _route_coverage(args: argparse.Namespace) -> int:
    import json

    from ares.app import run_config
    from ares.core import config
    from ares.core.route import RouteError, load_route
    from ares.tools.coverage import coverage_recorded, coverage_simulated, write_coverage_png

    overrides = {}
    if args.route_name:
        key = "route_file" if args.route_name.lower().endswith(".csv") else "tour"
        overrides = {key: args.route_name}
    try:
        cfg = run_config.build(tuple(args.config or ()), overrides)
        route = load_route(config.core(cfg))
        result = coverage_recorded(cfg, args.store, args.vehicle_id) if args.store else coverage_simulated(cfg)
    except (config.ConfigError, RouteError, OSError, ValueError) as exc:
        raise CliError(str(exc)) from None
    out = Path(args.out) if args.out else Path(f"{route.name}.coverage.png")
    title = f"{route.name}, {result.source}: RTK fixed on {result.rtk_fixed_share:.1%} of the route driven" + (
        f", corrections on {result.corrections_share:.1%}" if result.corrections_share is not None else ""
    )
    picture = write_coverage_png(out, route, result, title)
    print(json.dumps({**result.summary(), "picture": str(picture)}))
    return 0


def _route_profile(args: argparse.Namespace) -> int:
    from ares.core import config
    from ares.core.route import Route, RouteError
    from ares.tools.figures.speed_profile import write_profile_figure
    from managers.speed import SpeedProfileParams, SpeedTable

    out = Path(args.out) if args.out else Path(f"{Path(args.route_name).stem}.profile.png")
    if out.suffix.lower() not in (".png", ".svg"):
        raise CliError(f"{out}: the picture is a .png or an .svg")
    try:
        cfg = config.current()
        params = config.section(cfg, "speed_profile", SpeedProfileParams)
        vehicle = config.load_vehicle(args.vehicle) if args.vehicle else config.core(cfg).vehicle_profile
        route = (
            Route.from_csv(args.route_name)
            if args.route_name.lower().endswith(".csv")
            else Route.from_tour(args.route_name)
        )
    except (config.ConfigError, RouteError, OSError, ValueError) as exc:
        raise CliError(str(exc)) from None
    table = SpeedTable(route, params, vehicle)
    sections = table.sections
    picture = write_profile_figure(
        out, route, table.profile, sections, f"speed profile of {route.name} ({vehicle.name}): {len(sections)} sections"
    )
    print(
        json.dumps(
            {
                "route": route.name,
                "length_m": round(route.length, 2),
                "sections": len(sections),
                "max_speed_mps": round(max(sec.speed for sec in sections), 3),
                "min_speed_mps": round(min(sec.speed for sec in sections), 3),
                "picture": str(picture),
            }
        )
    )
    return 0


def _route_record(args: argparse.Namespace) -> int:
    bus = connect(args, "cli_route_record")
    counts = {"lines": 0, "messages": 0}

    def write(sub, out) -> None:
        for _topic, msg in sub.drain():
            counts["messages"] += 1
            for sentence in msg.sentences:
                # one sentence per line, whatever line ending (or stray break) it came with
                out.write(" ".join(sentence.split("\n")).replace("\r", "").strip() + "\n")
                counts["lines"] += 1
        out.flush()

    started = time.monotonic()
    try:
        try:
            out = open(args.file, "w")
        except OSError as exc:
            raise CliError(f"{args.file}: cannot write: {exc.strerror}") from None
        with out:
            sub = bus.subscribe("sensors/gnss", queue=1000)
            print(
                f"recording {bus.key('sensors/gnss')} to {args.file}"
                f"{f' for {args.seconds:g} s' if args.seconds else ' (Ctrl-C to stop)'}",
                file=sys.stderr,
            )
            try:
                while args.seconds is None or time.monotonic() - started < args.seconds:
                    write(sub, out)
                    time.sleep(0.1)
            except KeyboardInterrupt:
                pass
            write(sub, out)  # what arrived during the last sleep
    finally:
        bus.close()
    print(
        f"recorded {counts['lines']} sentences ({counts['messages']} messages) in "
        f"{time.monotonic() - started:.1f} s to {args.file}"
    )
    if counts["lines"] == 0:
        print("ares: no GNSS sentences arrived on sensors/gnss; is the simulated shuttle running?", file=sys.stderr)
        return 1
    return 0
