"""`ares record`: the running stack's bus to an MCAP file; and the MCAP half of `ares replay`
(`ares replay FILE.mcap [--node NAME] [--info]`), whose parser is `ares replay`'s (inspect.py)."""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
import time
from pathlib import Path

from .args import CliError, Command, add_connection_args, connect, endpoint, positive_float

UTC_EPOCH_WAIT_S = 2.0  # for a heartbeat, whose stamp and wall time give the stack's epoch


def add_parser(subparsers: argparse._SubParsersAction) -> dict[str, Command]:
    record = subparsers.add_parser(
        "record",
        help="record the running stack's bus to an MCAP file (opens in Foxglove)",
        description="Record every key of the vehicle (or the KEYS given: topics or patterns such as "
        "`lidar/*/points`) to an MCAP file, binary point clouds included, with a schema per topic and "
        "Foxglove's views of the pose, the clouds, the grid and the plan. Until Ctrl-C or --seconds. "
        "`ares run --record` records a whole run from its start.",
    )
    record.add_argument("keys", nargs="*", metavar="KEY", help="topics or patterns (default: all, `**`)")
    record.add_argument("--out", metavar="FILE.mcap", help="the file (default: ares-<date>-<time>.mcap)")
    record.add_argument("--seconds", type=positive_float, metavar="S", help="stop after S wall seconds")
    record.add_argument(
        "--compression", choices=["zstd", "lz4", "none"], default="zstd", help="chunk compression (default zstd)"
    )
    record.add_argument("--no-views", action="store_true", help="only the bus's own channels, no Foxglove views")
    add_connection_args(record)
    snapshot = subparsers.add_parser(
        "snapshot",
        help="save an incident snapshot now: the seconds before and after, as MCAP in the black box",
        description="Ask the running stack's recorder (recording.snapshots.enabled) for an incident snapshot: "
        "the ring of the last seconds of the bus and the seconds after, saved as an MCAP file beside the "
        "black box and listed with its event (GET /api/v1/vehicles/ID/snapshots). Waits for the file.",
    )
    snapshot.add_argument("--reason", default="", metavar="TEXT", help="why, kept in the snapshot's event")
    snapshot.add_argument("--by", default="", metavar="NAME", help="who asks (default: the user running it)")
    snapshot.add_argument(
        "--wait", type=positive_float, default=90.0, metavar="S", help="wall seconds to wait for the file (default 90)"
    )
    add_connection_args(snapshot)
    return {"record": cmd_record, "snapshot": cmd_snapshot}


def cmd_snapshot(args: argparse.Namespace) -> int:
    import getpass

    from ares.app.bus_record.snapshots import EVENT_KIND, FAILED_KIND, REQUEST_TOPIC, request_id
    from ares.core.messages import Event, SnapshotRequest

    bus = connect(args, "cli_snapshot")
    wanted = request_id()
    answers: list[Event] = []
    done = threading.Event()

    def on_event(_topic: str, msg) -> None:
        if isinstance(msg, Event) and msg.kind in (EVENT_KIND, FAILED_KIND) and msg.data.get("request_id") == wanted:
            answers.append(msg)
            done.set()

    try:
        bus.subscribe("events", on_message=on_event)
        by = args.by or getpass.getuser()
        bus.publish(
            REQUEST_TOPIC, SnapshotRequest(t=bus.clock.now(), requested_by=by, reason=args.reason, request_id=wanted)
        )
        print(f"snapshot asked for ({wanted}): waiting for the seconds after and the file", file=sys.stderr)
        done.wait(args.wait)
    finally:
        bus.close()
    if not answers:
        raise CliError(
            f"no snapshot within {args.wait:g} s: is recording.snapshots.enabled true in the running stack's "
            "configuration?"
        )
    answer = answers[0]
    print(json.dumps({"kind": answer.kind, "message": answer.message, **answer.data}))
    return 0 if answer.kind == EVENT_KIND else 1


def cmd_record(args: argparse.Namespace) -> int:
    from ares.app.bus_record.foxglove_views import FoxgloveViews
    from ares.app.bus_record.recorder import McapRecorder
    from ares.core import config
    from ares.core.route import RouteError, load_route

    bus = connect(args, "recorder")
    cfg = dict(bus.cfg)
    out = Path(args.out or time.strftime("ares-%Y%m%d-%H%M%S.mcap"))
    stop = threading.Event()
    previous = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        utc_epoch = _stack_utc_epoch(bus)
        try:
            route = load_route(config.core(cfg))
        except (RouteError, config.ConfigError, OSError):
            route = None
        views = None if args.no_views else FoxgloveViews(cfg, utc_epoch)
        recorder = McapRecorder(
            out, cfg, utc_epoch=utc_epoch, keys=tuple(args.keys) or ("**",), views=views, route=route,
            compression=args.compression,
        )  # fmt: skip
        recorder.attach(bus)
        recorder.start()
        print(f"recording {', '.join(recorder.keys)} of {cfg['vehicle_id']} to {out} (Ctrl-C stops)", file=sys.stderr)
        stop.wait(args.seconds)
        recorder.detach(bus)
        stats = recorder.close()
    finally:
        bus.close()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    print(json.dumps({"file": str(out), "size_bytes": out.stat().st_size, **stats.as_dict()}))
    return 0


def _stack_utc_epoch(bus) -> float:
    """The stack's UTC epoch (UTC of stack time 0), from a heartbeat's stamp and wall time; the wall
    clock if none comes (the views' timestamps then follow the recorder's clock)."""
    beats = bus.subscribe("heartbeat/*")
    deadline = time.monotonic() + UTC_EPOCH_WAIT_S
    try:
        while beats.latest is None and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        bus.unsubscribe(beats)
    if beats.latest is None:
        return time.time()
    return beats.latest.wall - beats.latest.t


# ---- `ares replay FILE.mcap` ------------------------------------------------------------------------


def add_replay_arguments(replay: argparse.ArgumentParser) -> None:
    """What `ares replay FILE.mcap` takes beside `ares replay check|update`'s arguments."""
    replay.add_argument("--node", metavar="NAME", help="FILE.mcap: replay this process against its recorded outputs")
    replay.add_argument(
        "--speed",
        default="1",
        metavar="X|max",
        help="FILE.mcap played into a bus: X times the recording's own pace (its stamps), or max",
    )
    replay.add_argument("--info", action="store_true", help="FILE.mcap: its channels, schemas and message counts")
    replay.add_argument("--json", action="store_true", help="with --info or --node: one JSON object")
    replay.add_argument(
        "--listen",
        type=endpoint,
        metavar="ENDPOINT",
        help="FILE.mcap played into a bus: host a router here (default: the recorded run's bus.router)",
    )
    replay.add_argument(
        "--router",
        type=endpoint,
        metavar="ENDPOINT",
        help="FILE.mcap played into a bus: join this router instead (a stack of yours, not the recorded one)",
    )


def is_mcap(path: str) -> bool:
    try:
        with open(path, "rb") as f:
            return f.read(8) == b"\x89MCAP0\r\n"
    except OSError:
        return False


def cmd_replay_mcap(args: argparse.Namespace, path: str) -> int:
    from ares.app.bus_record import mcap_replay

    try:
        if args.info:
            return _info(mcap_replay.info(path), args.json)
        if args.node:
            started = time.perf_counter()
            result = mcap_replay.replay_node(path, args.node)
            return _report_node(path, result, time.perf_counter() - started, args.json)
        return _play(args, path)
    except (OSError, ValueError) as exc:
        raise CliError(f"{path}: {exc}") from None


def _info(found: dict, as_json: bool) -> int:
    if as_json:
        print(json.dumps(found))
        return 0
    state = "complete" if found["complete"] else f"cut short ({found['cut_short']}): read to its last complete chunk"
    print(
        f"{found['file']}: {found['size_bytes'] / 1e6:.1f} MB, {found['messages']} messages over "
        f"{found['duration_s']:.1f} s, vehicle {found['vehicle_id']}, {state}"
    )
    print(f"{'channel':<48} {'schema':<26} {'encoding':<10} {'messages':>9} {'MB':>9}")
    for c in found["channels"]:
        print(
            f"{c['topic']:<48} {c['schema'] or '-':<26} {c['message_encoding']:<10} {c['messages']:>9} "
            + (f"{c['bytes'] / 1e6:>9.2f}" if c["bytes"] is not None else f"{'-':>9}")
        )
    return 0


def _report_node(path: str, result, seconds: float, as_json: bool) -> int:
    if as_json:
        print(
            json.dumps(
                {
                    "file": path,
                    "node": result.node,
                    "steps": result.steps,
                    "outputs": result.outputs,
                    "mismatches": len(result.mismatches),
                    "searched_steps": result.searched_steps,
                    "latched_otherwise": result.latched_otherwise,
                    "latched_per_topic": getattr(result, "latched_per_topic", 0),
                    "undecided": result.undecided,
                    "unrecorded_steps": getattr(result, "unrecorded_steps", 0),
                    "first_mismatches": [str(m) for m in result.mismatches[:5]],
                    "seconds": round(seconds, 2),
                }
            )
        )
    elif result.ok:
        print(
            f"{path}: {result.node}, {result.steps} steps, {result.outputs} outputs: identical "
            f"({result.latched_otherwise} of {result.searched_steps} steps latched otherwise than the recorder heard"
            + (
                f", {result.latched_per_topic} of them in another order of topics"
                if getattr(result, "latched_per_topic", 0)
                else ""
            )
            + (
                f"; {result.unrecorded_steps} at the end not compared: "
                "the recording stopped before the node reported them"
                if getattr(result, "unrecorded_steps", 0)
                else ""
            )
            + ")"
        )
    else:
        print(f"{path}: {result.node}: {len(result.mismatches)} mismatches, first:", file=sys.stderr)
        for m in result.mismatches[:5]:
            print(f"  {m}", file=sys.stderr)
    return 0 if result.ok else 1


def _play(args: argparse.Namespace, path: str) -> int:
    from ares.app.bus_record import mcap_replay
    from ares.core.bus import Bus

    try:
        speed = None if str(args.speed).strip().lower() == "max" else positive_float(str(args.speed))
    except argparse.ArgumentTypeError as exc:
        raise CliError(f"--speed: {exc}") from None
    recording = mcap_replay.open_recording(path)
    cfg = recording.cfg
    if args.router:
        cfg["bus"] = {**cfg["bus"], "router": args.router}
        mode = "client"
    else:
        cfg["bus"] = {**cfg["bus"], "router": args.listen or cfg["bus"]["router"]}
        mode = "router"
    try:
        bus = Bus(cfg, "replay", mode=mode)
    except Exception as exc:
        where = cfg["bus"]["router"]
        raise CliError(
            f"cannot {'join the router at' if args.router else 'host a router on'} {where} ({exc}): "
            + ("is it running?" if args.router else "is a stack running there? Pass --listen ENDPOINT")
        ) from None
    stop = threading.Event()
    previous = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGINT, signal.SIGTERM)}
    print(f"playing {path} into the bus at {cfg['bus']['router']} (Ctrl-C stops)", file=sys.stderr)
    try:
        sent = mcap_replay.play(recording, bus, speed, stop)
    finally:
        bus.close()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    print(json.dumps({"file": path, "messages": sum(sent.values()), "topics": len(sent)}))
    return 0
