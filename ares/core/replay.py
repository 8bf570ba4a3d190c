"""Process replay (after openpilot's): a node's recorded inputs, fed back through the node, must
give the outputs it gave.

`NodeReplay` is the one engine, whatever the recording: it builds the node from the recorded run's
configuration on an in-memory bus with a manual clock, delivers each step's inputs, steps it at
the recorded time and compares what it publishes with what it published in the run (numbers
within `REL_TOL`). Two kinds of recording feed it:

- a node's own (`replay()`, `ares replay check`): a run records a node when its name is in
  `replay.record` (ares.core.recording writes the file): the node class, its configuration and
  the time of its set-up; then, per step, its time, the inputs it latched (in order) and the
  outputs it published. A change of behaviour shows as a mismatch; when the change is intended,
  `update()` rewrites the expected outputs from the current code (the inputs stay those of the
  run);
- a recording of the whole bus (ares.core.bus_replay, from the MCAP files of ares.app.bus_record):
  it says what reached the recorder, not what the node latched, so the steps are rebuilt from it
  and a step's latched inputs searched for (`NodeReplay.step_latching_a_prefix`).

    ares run --headless --speed max --config tests/replay/record.yaml    # records
    ares replay check tests/replay/*.jsonl.gz                             # replays
"""

from __future__ import annotations

import gzip
import itertools
import logging
import math
import zlib
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import orjson

from ares.core.clock import ManualClock
from ares.core.launch import load
from ares.core.membus import MemoryNetwork
from ares.core.node import Node
from ares.core.recording import as_payload, as_record
from ares.core.schema import Payload

log = logging.getLogger("ares.core.replay")

REL_TOL = 1e-9
ABS_TOL = 1e-12

Published = list[list[Any]]  # [topic, record] in order: what a node published, or a recording holds


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
    replayed: list[Published] = field(default_factory=list)  # per step: what the node published now

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


class RecordedInput(Protocol):
    """An input as a recording holds it: its topic, its payload as it travelled, its encoding
    ("": the topic's own)."""

    @property
    def topic(self) -> str: ...
    @property
    def payload(self) -> bytes: ...
    @property
    def encoding(self) -> str: ...


@dataclass(frozen=True)
class LatchedInput:
    """An input of a node's own recording: what a step latched."""

    topic: str
    payload: bytes
    encoding: str = ""


@dataclass(frozen=True)
class SearchedStep:
    """A step replayed not knowing which of its candidate inputs it latched (NodeReplay.step_latching_a_prefix)."""

    outputs: Published
    latched: int  # how many of the candidates the kept try latched
    undecided: bool  # the node's state could not be copied: only the likely prefix was tried
    left: list[Any] = field(default_factory=list)  # the candidates it did not latch, in their order
    per_topic: bool = False  # what it latched was not a prefix of the arrival order, but of each topic's


# a step no prefix explains tries at most this many latchings of a prefix of each topic's candidates,
# chosen among at most PER_TOPIC_SPACE of them (beyond: a node of many inputs, no such search)
PER_TOPIC_TRIES = 64
PER_TOPIC_SPACE = 4096


class NodeReplay:
    """The replay engine: one node driven through recorded steps, whatever they were read from (a
    node's own recording here, a recording of the bus in ares.core.bus_replay). The node is built
    from the recorded run's configuration (recording nothing itself) on an in-memory bus with a
    manual clock; each step's inputs are delivered, the node stepped at the step's recorded time,
    and what it published is compared with what it published in the run (`compare`, into `result`)."""

    def __init__(
        self,
        node_class: type[Node],
        cfg: dict[str, Any],
        name: str,
        result: ReplayResult,
        *,
        start: float = 0.0,
        max_mismatches: int = 20,
    ):
        cfg = {**cfg, "replay": {**cfg.get("replay", {}), "record": []}}
        self.clock = ManualClock(start)
        network = MemoryNetwork(cfg["vehicle_id"])
        self.node = node_class(cfg, clock=self.clock, bus=network.bus(name, self.clock), name=name)
        self._published: Published = []
        self.node.tap_outputs(self._capture)
        self._feeder = network.bus("replay", self.clock)
        self.result = result
        self.max_mismatches = max_mismatches
        self._compared = 0  # steps compared so far: a mismatch names its step by this count
        self.ignores = node_class.replay_ignores

    def _capture(self, topic: str, payload: Payload) -> None:
        self._published.append([topic, as_record(payload)])

    def set_up(self) -> None:
        self.node.setup()

    def tear_down(self) -> None:
        self.node.teardown()

    def published(self) -> Published:
        """What the node published since this was last asked (or a step returned it), as
        [topic, record] in order, its events included."""
        found, self._published = self._published, []
        return found

    def deliver(self, inputs: Iterable[RecordedInput]) -> None:
        """Recorded inputs on the bus, in order: the node latches them at its next step."""
        for message in inputs:
            self._feeder.inject(message.topic, message.payload, message.encoding or None)

    def step(self, t: float, inputs: Iterable[RecordedInput] = ()) -> Published:
        """One step at `t` (the clock never goes back) latching `inputs` and what was delivered
        before them; returns what the node published since last asked."""
        outputs = self._step(t, inputs)
        self.result.steps += 1
        return outputs

    def step_latching_a_prefix(
        self, t: float, candidates: Sequence[RecordedInput], likely: int, expected: Published
    ) -> SearchedStep:
        """One step at `t` of a recording that does not say what it latched (one of the bus): a
        prefix of `candidates` (the inputs since the previous step, in order of arrival), most
        likely the first `likely`. Tried latching those, then all, then fewer, then more, the
        node's state put back between tries; the first try that publishes `expected` is kept.
        If none does, the inputs of several topics may have reached the node in another order
        than the recorder (each topic's own order holds: one publisher, one key): a prefix of each
        topic's candidates, nearest the likely ones first, at most PER_TOPIC_TRIES of them. If
        none does either, the likely prefix is kept (its mismatches `compare` then reports). What
        the kept try did not latch is the caller's: the next step's, most likely."""
        if not candidates:
            return SearchedStep(self.step(t), 0, undecided=False)
        try:
            state = self.node.copy_state()
        except Exception:  # a state that cannot be copied (a solver's handle): the likely ones
            self.deliver(candidates[:likely])
            return SearchedStep(self.step(t), likely, undecided=True, left=list(candidates[likely:]))
        tries = dict.fromkeys(
            [likely, len(candidates), *range(likely - 1, -1, -1), *range(likely + 1, len(candidates))]
        )
        for latched in tries:
            self.deliver(candidates[:latched])
            outputs = self._step(t)
            if not mismatches(0, t, expected, outputs, self.ignores):
                self.result.steps += 1
                return SearchedStep(outputs, latched, undecided=False, left=list(candidates[latched:]))
            self.node.restore_state(state)
        for chosen in _per_topic_latchings(candidates, likely):
            self.deliver([c for i, c in enumerate(candidates) if i in chosen])
            outputs = self._step(t)
            if not mismatches(0, t, expected, outputs, self.ignores):
                self.result.steps += 1
                left = [c for i, c in enumerate(candidates) if i not in chosen]
                return SearchedStep(outputs, len(chosen), undecided=False, left=left, per_topic=True)
            self.node.restore_state(state)
        self.deliver(candidates[:likely])
        return SearchedStep(self.step(t), likely, undecided=False, left=list(candidates[likely:]))

    def compare(self, t: float | None, expected: Published, got: Published) -> None:
        """A recorded step's outputs against the replayed ones (t None: the set-up's), into the
        result; the steps are numbered in the order they are compared."""
        self.result.outputs += len(got)
        if len(self.result.mismatches) < self.max_mismatches:
            self.result.mismatches += mismatches(self._compared, t, expected, got, self.ignores)
        self.result.replayed.append(got)
        self._compared += 1

    def _step(self, t: float, inputs: Iterable[RecordedInput] = ()) -> Published:
        self.clock.set(max(t, self.clock.now()))
        self.deliver(inputs)
        self.node.step_once(t)
        return self.published()


def _per_topic_latchings(candidates: Sequence[RecordedInput], likely: int) -> list[set[int]]:
    """The latchings that take a prefix of each topic's candidates and are no prefix of them all,
    as sets of indices: those that differ least from the likely prefix first, at most
    PER_TOPIC_TRIES (none where there are more than PER_TOPIC_SPACE)."""
    by_topic: dict[str, list[int]] = {}
    for i, candidate in enumerate(candidates):
        by_topic.setdefault(candidate.topic, []).append(i)
    if len(by_topic) < 2:
        return []
    topics = list(by_topic)
    if math.prod(len(by_topic[topic]) + 1 for topic in topics) > PER_TOPIC_SPACE:
        return []
    likely_counts = [sum(1 for i in by_topic[topic] if i < likely) for topic in topics]
    counts = itertools.product(*(range(len(by_topic[topic]) + 1) for topic in topics))
    ranked = sorted(counts, key=lambda ks: sum(abs(k - k0) for k, k0 in zip(ks, likely_counts, strict=True)))
    out = []
    for ks in ranked:
        chosen = {i for topic, k in zip(topics, ks, strict=True) for i in by_topic[topic][:k]}
        if chosen == set(range(len(chosen))):  # a prefix of the arrival order: tried already
            continue
        out.append(chosen)
        if len(out) == PER_TOPIC_TRIES:
            break
    return out


def replay(
    path: str | Path, config_overrides: dict[str, dict[str, Any]] | None = None, max_mismatches: int = 20
) -> ReplayResult:
    """Replay a node's own recording: each step latching what the recording says it latched."""
    header, frames = read(path)
    cfg = dict(header["config"])
    for section, values in (config_overrides or {}).items():
        cfg[section] = {**cfg.get(section, {}), **values}
    result = ReplayResult(node=header["node"], steps=0, outputs=0)
    engine = NodeReplay(
        load(header["class"]), cfg, header["node"], result, start=header["start"], max_mismatches=max_mismatches
    )
    engine.set_up()
    for frame in frames:
        t = frame["t"]
        if t is None:  # what it published while setting up
            outputs = engine.published()
        else:
            outputs = engine.step(t, [LatchedInput(topic, as_payload(message)) for topic, message in frame["in"]])
        engine.compare(t, frame["out"], outputs)
    engine.tear_down()
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


def mismatches(
    step: int, t: float | None, expected: Published, got: Published, ignores: tuple[str, ...] = ()
) -> list[Mismatch]:
    """How one step's outputs differ from the recorded ones (floats within REL_TOL, ABS_TOL)."""
    if len(expected) != len(got):
        return [Mismatch(step, t, "number of messages", [e[0] for e in expected], [g[0] for g in got])]
    found = []
    for (e_topic, e_msg), (g_topic, g_msg) in zip(expected, got):
        if e_topic != g_topic:
            found.append(Mismatch(step, t, "topic", e_topic, g_topic))
        else:
            found += [
                Mismatch(step, t, f"{e_topic}.{where}", a, b)
                for where, a, b in _differences(e_msg, g_msg)
                if not _ignored(f"{e_topic}.{where}", ignores)
            ]
    return found


def _ignored(path: str, ignores: tuple[str, ...]) -> bool:
    return any(path == i or path.startswith((i + ".", i + "[")) for i in ignores)


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
