"""The commands that talk to a running stack over its router: `ares topics`, `ares echo`,
`ares driver`, `ares auto`."""

from __future__ import annotations

import argparse
import base64
import json
import queue
import sys
import threading
import time

from .args import CliError, Command, add_connection_args, connect, positive_float, positive_int


def add_parser(subparsers: argparse._SubParsersAction) -> dict[str, Command]:
    topics = subparsers.add_parser(
        "topics",
        help="list the keys seen on the bus, their rates and schemas",
        description="List every key under ares/<vehicle_id>/** seen during a few "
        "seconds, with message count, rate and schema, and the live processes.",
    )
    topics.add_argument(
        "--seconds", type=positive_float, default=2.0, metavar="S", help="how long to listen (default 2)"
    )
    topics.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    add_connection_args(topics)

    echo = subparsers.add_parser(
        "echo",
        help="print the messages on a topic as JSON lines",
        description="Print the messages on a topic (e.g. dbw/car_state), a full key "
        "or a wildcard (heartbeat/*, ares/*/events), one JSON object per line.",
    )
    echo.add_argument(
        "key", metavar="KEY", help="topic relative to ares/<vehicle_id>/, or a full key starting with ares/"
    )
    echo.add_argument("--count", type=positive_int, metavar="N", help="stop after N messages")
    echo.add_argument("--seconds", type=positive_float, metavar="S", help="stop after S seconds")
    add_connection_args(echo)

    driver = subparsers.add_parser(
        "driver",
        help="act as the simulated shuttle's driver (button, pedals, steering wheel)",
        description="Inject a driver action into the simulated shuttle. Any pedal or "
        "steering-wheel action switches the drive-by-wire bridge to Manual; "
        "the button goes Manual -> Ready (and back).",
    )
    driver.add_argument("action", choices=["button", "throttle", "brake", "steer", "release"])
    driver.add_argument(
        "value", type=float, nargs="?", default=0.0, help="pedal position 0..1, or steering-wheel angle in degrees"
    )
    driver.add_argument(
        "--duration",
        type=positive_float,
        default=2.0,
        metavar="S",
        help="how long the driver keeps it up, stack seconds (default 2)",
    )
    add_connection_args(driver)

    auto = subparsers.add_parser(
        "auto",
        help="ask the drive-by-wire bridge for Automatic mode (set_automatic_mode)",
        description="Request Automatic mode. The bridge accepts only in Ready, i.e. after "
        "the Auto/Manual button (`ares driver button`).",
    )
    add_connection_args(auto)
    return {"topics": cmd_topics, "echo": cmd_echo, "driver": cmd_driver, "auto": cmd_auto}


def cmd_topics(args: argparse.Namespace) -> int:
    from ares.core import topics
    from ares.core.config.run import OBSERVER_USER  # the observer reads; --help stays light

    bus = connect(args, "cli_topics", login=OBSERVER_USER)
    seen: dict[str, list] = {}  # key -> [count, encoding, bytes]
    lock = threading.Lock()

    def on_sample(sample) -> None:  # Zenoh thread: count and return
        key = str(sample.key_expr)
        with lock:
            entry = seen.get(key)
            if entry is None:
                seen[key] = [1, str(sample.encoding), len(sample.payload)]
            else:
                entry[0] += 1
                entry[2] = len(sample.payload)

    try:
        subscriber = bus.session.declare_subscriber(f"{bus.prefix}/**", on_sample)
        started = time.monotonic()
        time.sleep(args.seconds)
        elapsed = time.monotonic() - started
        subscriber.undeclare()
        alive = sorted(bus.alive_processes(timeout_s=min(1.0, args.seconds)))
    finally:
        bus.close()

    rows = []
    with lock:
        items = sorted(seen.items())
    for key, (count, encoding, size) in items:
        topic = bus.topic_of(key)
        _, _, schema = encoding.partition(";")
        entry = topics.find(topic)
        expected = entry.schema if entry is not None else None
        note = ""
        if expected is None:
            note = "not in the topic table (ares/core/topics.py)"
        elif schema and schema != expected.schema_name():
            note = f"expected {expected.schema_name()}"
        rows.append(
            {
                "topic": topic,
                "key": key,
                "count": count,
                "rate_hz": round(count / elapsed, 2),
                "schema": schema or (expected.schema_name() if expected else "?"),
                "encoding": encoding,
                "bytes": size,
                "note": note,
            }
        )
    if args.json:
        print(
            json.dumps(
                {
                    "prefix": bus.prefix,
                    "router": bus.cfg["bus"]["router"],
                    "seconds": round(elapsed, 3),
                    "topics": rows,
                    "alive": alive,
                }
            )
        )
    else:
        print(f"{bus.prefix}/** via {bus.cfg['bus']['router']}, {elapsed:.1f} s")
        if rows:
            width = max(len("TOPIC"), *(len(r["topic"]) for r in rows))
            print(f"{'TOPIC':<{width}}  {'MSGS':>7}  {'RATE_HZ':>8}  {'BYTES':>6}  SCHEMA")
            for r in rows:
                note = f"  ({r['note']})" if r["note"] else ""
                columns = f"{r['count']:>7}  {r['rate_hz']:>8.1f}  {r['bytes']:>6}"
                print(f"{r['topic']:<{width}}  {columns}  {r['schema']}{note}")
        else:
            print("(no messages)")
        print(f"live processes ({len(alive)}): {', '.join(alive) if alive else '-'}")
    if not rows and not alive:
        print(
            f"ares: nothing seen under {bus.prefix}/** in {elapsed:.1f} s; is the stack running "
            f"with vehicle id {bus.vehicle_id!r}?",
            file=sys.stderr,
        )
        return 1
    return 0


def _raw(payload: bytes):
    try:
        text = payload.decode()
    except UnicodeDecodeError:
        return {"raw_base64": base64.b64encode(payload).decode()}
    try:
        return {"raw": json.loads(text)}
    except ValueError:
        return {"raw": text}


def render_sample(key: str, encoding: str, payload: bytes) -> dict:
    """One received sample as a JSON-ready dict: decoded and validated when the topic's
    schema is known, raw otherwise."""
    import pydantic

    from ares.core import schema as wire
    from ares.core import topics

    parts = key.split("/", 2)  # ares/<vehicle_id>/<topic>, this vehicle's or another's
    out: dict = {"key": key}
    _, _, named = encoding.partition(";")
    entry = topics.find(parts[2]) if len(parts) == 3 and parts[0] == "ares" else None
    schema = entry.schema if entry is not None else None
    if schema is None and named:
        schema = topics.SCHEMAS.get(named)
    if schema is None:
        out["encoding"] = encoding
        out.update(_raw(payload))
        return out
    out["schema"] = schema.schema_name()
    if named and named != schema.schema_name():
        out["error"] = f"schema mismatch: sent as {named}, topic carries {schema.schema_name()}"
        out.update(_raw(payload))
        return out
    try:
        msg = wire.decode(payload, schema)
    except pydantic.ValidationError as exc:
        out["error"] = "invalid: " + "; ".join(
            f"{'.'.join(str(p) for p in e['loc']) or '<root>'}: {e['msg']}" for e in exc.errors(include_url=False)[:3]
        )
        out.update(_raw(payload))
        return out
    except wire.BulkDecodeError as exc:
        out["error"] = f"invalid: {exc}"
        out["bytes"] = len(payload)
        return out
    if wire.is_bulk(schema):  # the header, and each array's shape instead of its values
        out["msg"] = {
            **msg.header_fields(),
            "arrays": {
                name: {"dtype": getattr(msg, name).dtype.str, "shape": list(getattr(msg, name).shape)}
                for name in msg.ARRAYS
            },
        }
    else:
        out["msg"] = msg.model_dump(mode="json")
    return out


def cmd_echo(args: argparse.Namespace) -> int:
    import zenoh

    key_arg = args.key.strip().strip("/")
    if not key_arg:
        raise CliError("empty key")
    from ares.core.config.run import OBSERVER_USER  # the observer reads; --help stays light

    bus = connect(args, "cli_echo", login=OBSERVER_USER)
    key = key_arg if key_arg == "ares" or key_arg.startswith("ares/") else bus.key(key_arg)
    inbox: queue.Queue = queue.Queue(maxsize=10000)
    dropped = [0]

    def on_sample(sample) -> None:  # Zenoh thread: hand over and return
        try:
            inbox.put_nowait((str(sample.key_expr), str(sample.encoding), sample.payload.to_bytes()))
        except queue.Full:
            dropped[0] += 1

    printed = 0
    try:
        try:
            bus.session.declare_subscriber(key, on_sample)
        except zenoh.ZError as exc:
            raise CliError(f"invalid key expression {key!r}: {str(exc).split(' at ')[0]}") from None
        deadline = time.monotonic() + args.seconds if args.seconds else None
        while args.count is None or printed < args.count:
            timeout = 0.2 if deadline is None else min(0.2, deadline - time.monotonic())
            if timeout <= 0:
                break
            try:
                k, encoding, payload = inbox.get(timeout=timeout)
            except queue.Empty:
                continue
            sys.stdout.write(json.dumps(render_sample(k, encoding, payload)) + "\n")
            sys.stdout.flush()
            printed += 1
    except KeyboardInterrupt:
        pass
    finally:
        bus.close()
    if dropped[0]:
        print(f"ares: {dropped[0]} messages dropped (output too slow)", file=sys.stderr)
    if args.count is not None and printed < args.count:
        print(f"ares: {printed} of {args.count} messages on {key} within {args.seconds:g} s", file=sys.stderr)
        return 1
    if printed == 0 and args.seconds:
        print(f"ares: no messages on {key} within {args.seconds:g} s", file=sys.stderr)
        return 1
    return 0


def _call(args: argparse.Namespace, service: str, request=None):
    from ares.core.bus import ServiceError

    bus = connect(args, "cli")
    try:
        return bus.call(service, request)
    except ServiceError as exc:
        raise CliError(str(exc)) from None
    finally:
        bus.close()


def cmd_driver(args: argparse.Namespace) -> int:
    from ares.core.messages import DriverCommand

    reply = _call(
        args, "sim/driver", DriverCommand(action=args.action.upper(), value=args.value, duration_s=args.duration)
    )
    print(reply.detail)
    return 0 if reply.ok else 1


def cmd_auto(args: argparse.Namespace) -> int:
    reply = _call(args, "set_automatic_mode")
    reason = f": {reply.reason}" if reply.reason else ""
    print(f"{'accepted' if reply.accepted else 'refused'}: mode {reply.mode.value}{reason}")
    return 0 if reply.accepted else 1
