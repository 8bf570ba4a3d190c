"""Process replay (after openpilot's): a node's recorded inputs, fed back through the node, must
give the outputs it gave.

A run records a node when its name is in `replay.record` (ares.core.recording writes the file): the
node class, its configuration and the time of its set-up; then, per step, its time, the inputs it
latched (in order) and the outputs it published. `replay()` builds
the same node on an in-memory bus with a manual clock, delivers each step's inputs, steps it at
the recorded time and compares what it publishes with what it published in the run (numbers
within `rel_tol`). A change of behaviour shows as a mismatch; when the change is intended,
`update()` rewrites the expected outputs from the current code (the inputs stay those of the
run).

    ares run --headless --speed max --config tests/replay/record.yaml    # records
    ares replay check tests/replay/*.jsonl.gz                             # replays
"""

from __future__ import annotations

import gzip
import logging
import math
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import orjson

from ares.core.bus import Publisher, PublisherFamily
from ares.core.clock import ManualClock
from ares.core.launch import load
from ares.core.membus import MemoryNetwork
from ares.core.node import Node
from ares.core.recording import as_payload, as_record
from ares.core.schema import Payload

log = logging.getLogger("ares.core.replay")

REL_TOL = 1e-9
ABS_TOL = 1e-12


@dataclass
class Mismatch:
    step: int
    t: float | None
    where: str
    expected: Any
    got: Any

    def __str__(self) -> str:
        return f"step {self.step} (t={self.t}): {self.where}: expected {self.expected!r:.200}, got {self.got!r:.200}"


@dataclass
class ReplayResult:
    node: str
    steps: int
    outputs: int
    mismatches: list[Mismatch] = field(default_factory=list)
    replayed: list[list[list[Any]]] = field(default_factory=list)  # per step: what the node published now

    @property
    def ok(self) -> bool:
        return not self.mismatches


def read(path: str | Path) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """The header and the steps of a recording. One cut short (its process killed) is read up to
    its last complete line."""
    lines: list[dict[str, Any]] = []
    try:
        with gzip.open(path, "rb") as f:
            for line in f:
                if line.endswith(b"\n"):
                    lines.append(orjson.loads(line))
    except (EOFError, gzip.BadGzipFile, zlib.error) as exc:
        if not lines:
            raise ValueError(f"{path}: not a process replay recording ({exc})") from None
        log.warning("%s: cut short after %d steps (%s): replaying those", path, len(lines) - 1, exc)
    if not lines or "node" not in lines[0]:
        raise ValueError(f"{path}: not a process replay recording")
    return lines[0], lines[1:]


def capture_outputs(node: Node) -> list[list[Any]]:
    """What `node` publishes from now on, as [topic, record] in order (its events included): the
    outputs a replay compares with the recorded ones."""
    published: list[list[Any]] = []

    def capture(topic: str, payload: Payload) -> None:
        published.append([topic, as_record(payload)])

    for port in node._ports.values():
        if isinstance(port, Publisher):
            port.tap = capture
        elif isinstance(port, PublisherFamily):  # made as used: each gets the tap when made
            port._tap = capture
    node._events.tap = capture
    return published


def replay(
    path: str | Path, config_overrides: dict[str, dict[str, Any]] | None = None, max_mismatches: int = 20
) -> ReplayResult:
    header, frames = read(path)
    cfg = dict(header["config"])
    cfg["replay"] = {**cfg.get("replay", {}), "record": []}
    for section, values in (config_overrides or {}).items():
        cfg[section] = {**cfg.get(section, {}), **values}
    clock = ManualClock(header["start"])
    network = MemoryNetwork(cfg["vehicle_id"])
    node = load(header["class"])(cfg, clock=clock, bus=network.bus(header["node"], clock), name=header["node"])
    published = capture_outputs(node)
    feeder = network.bus("replay", clock)
    result = ReplayResult(node=header["node"], steps=0, outputs=0)
    node.setup()
    for index, frame in enumerate(frames):
        if frame["t"] is not None:
            clock.set(max(frame["t"], clock.now()))
            for topic, message in frame["in"]:
                feeder.inject(topic, as_payload(message))
            node.step_once(frame["t"])
            result.steps += 1
        result.outputs += len(published)
        if len(result.mismatches) < max_mismatches:
            result.mismatches += _compare(index, frame["t"], frame["out"], published)
        result.replayed.append(list(published))
        published.clear()
    node.teardown()
    return result


def update(path: str | Path) -> ReplayResult:
    """Rewrite the recording's expected outputs with what the current code publishes."""
    header, frames = read(path)
    result = replay(path, max_mismatches=10**9)
    with gzip.open(path, "wb", compresslevel=9) as f:
        f.write(orjson.dumps(header) + b"\n")
        for frame, outputs in zip(frames, result.replayed):
            f.write(orjson.dumps({**frame, "out": outputs}) + b"\n")
    return result


def _compare(step: int, t: float | None, expected: list[list[Any]], got: list[list[Any]]) -> list[Mismatch]:
    if len(expected) != len(got):
        return [Mismatch(step, t, "number of messages", [e[0] for e in expected], [g[0] for g in got])]
    found = []
    for (e_topic, e_msg), (g_topic, g_msg) in zip(expected, got):
        if e_topic != g_topic:
            found.append(Mismatch(step, t, "topic", e_topic, g_topic))
        else:
            found += [Mismatch(step, t, f"{e_topic}.{where}", a, b) for where, a, b in _differences(e_msg, g_msg)]
    return found


def _differences(a: Any, b: Any, where: str = "") -> list[tuple[str, Any, Any]]:
    if isinstance(a, dict) and isinstance(b, dict):
        if a.keys() != b.keys():
            return [(where or "<fields>", sorted(a), sorted(b))]
        return [d for k in a for d in _differences(a[k], b[k], f"{where}.{k}" if where else k)]
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return [(where + "[len]", len(a), len(b))]
        return [d for i, (x, y) in enumerate(zip(a, b)) for d in _differences(x, y, f"{where}[{i}]")]
    if isinstance(a, float) or isinstance(b, float):
        if (
            isinstance(a, (int, float))
            and isinstance(b, (int, float))
            and math.isclose(a, b, rel_tol=REL_TOL, abs_tol=ABS_TOL)
        ):
            return []
        return [(where, a, b)]
    return [] if a == b else [(where, a, b)]
