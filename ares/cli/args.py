"""What the command groups share: argument types, the connection options, the user-facing
error, and the client-mode session on the running stack's router."""

from __future__ import annotations

import argparse
import re
from collections.abc import Callable

ENDPOINT_RE = re.compile(r"^[a-z][a-z0-9+-]*/\S+$")

Command = Callable[[argparse.Namespace], int]  # a command's implementation: arguments in, exit code out


class CliError(Exception):
    """A user-facing error: printed as `ares: error: ...`, exit code 1."""


# ---- argument types --------------------------------------------------------------------------


def positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not value > 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text}")
    return value


def positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text}")
    return value


def non_negative_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be zero or more, got {text}")
    return value


def cpu_list(text: str) -> list[int]:
    """CPU numbers as taskset takes them: `0`, `0,2`, `0-3`."""
    refusal = argparse.ArgumentTypeError(f"not a CPU list (like 0 or 0,2 or 0-3): {text!r}")
    cpus: set[int] = set()
    for part in text.split(","):
        first, _, last = part.strip().partition("-")
        try:
            low, high = int(first), int(last or first)
        except ValueError:
            raise refusal from None
        if low < 0 or high < low:
            raise refusal
        cpus.update(range(low, high + 1))
    return sorted(cpus)


def port(text: str) -> int:
    value = non_negative_int(text)
    if value > 65535:
        raise argparse.ArgumentTypeError(f"not a TCP port: {text}")
    return value


def endpoint(text: str) -> str:
    if not ENDPOINT_RE.match(text):
        raise argparse.ArgumentTypeError(f"expected a Zenoh endpoint such as tcp/127.0.0.1:7447, got {text!r}")
    return text


def vehicle_id(text: str) -> str:
    if not text or any(c in text for c in "/*$?#") or text.strip() != text:
        raise argparse.ArgumentTypeError(f"a vehicle id is one key segment (no '/', '*', spaces), got {text!r}")
    return text


# ---- connecting to the running stack ---------------------------------------------------------


def add_connection_args(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--router",
        type=endpoint,
        metavar="ENDPOINT",
        help="router to connect to (default: bus.router of the run configuration)",
    )
    p.add_argument(
        "--vehicle-id",
        type=vehicle_id,
        metavar="ID",
        help="vehicle id whose keys to look at (default: vehicle_id of the configuration)",
    )


def connect(args: argparse.Namespace, process: str, login: str | None = None):
    """A client-mode Bus on the running stack's router (on a deployed vehicle, logged in as
    `login` of bus.credentials_file, else as `process`)."""
    import zenoh

    from ares.core import config
    from ares.core.bus import Bus

    try:
        cfg = config.current()
    except (config.ConfigError, OSError, ValueError) as exc:
        raise CliError(f"cannot read the run configuration: {exc}") from None
    if args.vehicle_id:
        cfg["vehicle_id"] = args.vehicle_id
    if args.router:
        cfg["bus"]["router"] = args.router
    router = cfg["bus"]["router"]
    try:
        return Bus(cfg, process, mode="client", login=login)
    except zenoh.ZError as exc:
        raise CliError(
            f"no Zenoh router reachable at {router} ({str(exc).split(' at ')[0].strip()}). "
            "Is the stack running? Start it with `ares run`, or pass --router ENDPOINT."
        ) from None
