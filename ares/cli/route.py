"""`ares route import` (a route file from a recorded drive) and `ares route record` (an NMEA
log from the running stack's receiver)."""
from __future__ import annotations

import argparse
import sys
import time

from .args import CliError, Command, add_connection_args, connect, positive_float


def add_parser(subparsers: argparse._SubParsersAction) -> dict[str, Command]:
    route = subparsers.add_parser("route", help="route files: import a recorded drive, record an NMEA log",
                                  description="Route files for `ares run --route FILE`.")
    route_sub = route.add_subparsers(dest="route", metavar="ACTION")
    imp = route_sub.add_parser("import", help="build a route file from a CSV of x,y[,z] metres or an NMEA log",
                               description="Build a route from a recorded drive: project the fixes (GGA; RMC or "
                                           "GLL when a log has none) to a local frame, drop standstill "
                                           "duplicates, resample evenly, smooth, add yaw. Writes a CSV x,y,z,yaw "
                                           "with its origin that `ares run --route` reads. A receiver's log is "
                                           "read as it comes: comments, headers, CRLF, other sentences and "
                                           "talkers are counted and skipped, and so is a bad line, by reason.")
    imp.add_argument("file", metavar="FILE", help="the recording: CSV of x,y[,z] metres, or an NMEA log")
    imp.add_argument("-o", "--output", required=True, metavar="ROUTE", help="route file to write (CSV)")
    imp.add_argument("--format", choices=["auto", "csv", "nmea"], default="auto",
                     help="input format (default: auto, NMEA when most lines hold NMEA sentences)")
    imp.add_argument("--spacing", type=positive_float, metavar="M",
                     help="distance between route points, metres (default gnss.route_import.spacing_m, 0.5)")
    imp.add_argument("--strict", action="store_true",
                     help="fail on the first bad NMEA line (bad checksum, broken field, beyond the frame's "
                          "reach) instead of skipping and counting it")
    rec = route_sub.add_parser("record", help="write the NMEA sentences arriving on sensors/gnss to a file",
                               description="Record an NMEA log from the running stack's GNSS receiver "
                                           "(sensors/gnss), one sentence per line, until --seconds or Ctrl-C. "
                                           "Drive the route meanwhile, then `ares route import FILE -o ROUTE`.")
    rec.add_argument("file", metavar="FILE", help="NMEA log to write")
    rec.add_argument("--seconds", type=positive_float, metavar="S", help="stop after S seconds (default: Ctrl-C)")
    add_connection_args(rec)
    return {"route": cmd_route}


def cmd_route(args: argparse.Namespace) -> int:
    if args.route == "import":
        return _route_import(args)
    if args.route == "record":
        return _route_record(args)
    raise CliError("which action? try `ares route import FILE -o ROUTE` or `ares route record FILE`")



def _route_import(args: argparse.Namespace) -> int:
    from ares import config, route_import
    from ares.route import Route, RouteError
    try:
        cfg = config.current()
    except (config.ConfigError, OSError, ValueError) as exc:
        raise CliError(f"cannot read the run configuration: {exc}") from None
    try:
        result = route_import.import_route(args.file, args.output, fmt=args.format, spacing_m=args.spacing,
                                           strict=args.strict, cfg=cfg)
        Route.from_csv(args.output)     # what `ares run --route` will do: it must read it back
    except RouteError as exc:
        raise CliError(str(exc)) from None
    print(f"imported {result.summary()}")
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
            print(f"recording {bus.key('sensors/gnss')} to {args.file}"
                  f"{f' for {args.seconds:g} s' if args.seconds else ' (Ctrl-C to stop)'}", file=sys.stderr)
            try:
                while args.seconds is None or time.monotonic() - started < args.seconds:
                    write(sub, out)
                    time.sleep(0.1)
            except KeyboardInterrupt:
                pass
            write(sub, out)             # what arrived during the last sleep
    finally:
        bus.close()
    print(f"recorded {counts['lines']} sentences ({counts['messages']} messages) in "
          f"{time.monotonic() - started:.1f} s to {args.file}")
    if counts["lines"] == 0:
        print("ares: no GNSS sentences arrived on sensors/gnss; is the simulated shuttle running?", file=sys.stderr)
        return 1
    return 0

