"""An MCAP recording of the bus read back: what it holds (`info`), played into a bus (`play`), or fed
to one node whose outputs are compared with the recorded ones (`replay_node`), as process replay
(ares.core.replay) does with a node's own recording.

The file is read from start to end, record by record (mcap's StreamReader): a recording whose
writer was killed has no summary and may end in the middle of a record; it is read up to its last
complete chunk, and `Recording.complete` says whether it ended properly.

Replaying one node from a recording of the whole bus: the node is built from the recorded run's
configuration on an in-memory bus with a manual clock, and the recording's messages are taken in
the order the recorder received them. At `--speed max` (the node a lockstep participant) it steps
at each tick the simulator sent it (`sim/clock/<node>`) once it had reported itself due
(`clock/done`: a tick before its first report found no node to step); otherwise at the stamps of
its recorded outputs (a step that published nothing is then unseen). Each step's outputs (its
declared outputs and its events, matched to the step by their stamps) are compared with what it
published in the run.

A recording of the bus says what reached the recorder, not what the node latched (the peers talk
to each other directly, the recorder hears them through the router, and a loaded machine wakes a
node late): each step latches a prefix of the inputs since the previous step in their order of
arrival, tried from what had reached the recorder at the tick, its state copied and put back
between tries, and the recorded outputs decide (_LockstepSteps; `BusReplayResult` counts the
searches). A node's own recording (`replay.record`, `ares replay check`) says what it latched.
"""

from __future__ import annotations

import collections
import copy
import json
import logging
import struct
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import orjson
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Message, Metadata, Schema
from mcap.stream_reader import StreamReader

from ares.app import processes
from ares.app.bus_record.recorder import ENCODING_META, RUN_METADATA, TOPIC_META
from ares.core import schema, topics
from ares.core.bus import BaseBus, Subscription
from ares.core.clock import ManualClock
from ares.core.membus import MemoryNetwork
from ares.core.recording import as_record
from ares.core.replay import ReplayResult, _compare, capture_outputs

log = logging.getLogger("ares.app.bus_record.replay")


@dataclass(frozen=True)
class Recorded:
    """One raw bus message of a recording."""

    topic: str
    encoding: str
    payload: bytes
    log_time: int  # ns, wall clock, when the recorder received it
    stamp: float  # its own `t`, stack seconds


@dataclass
class ChannelInfo:
    topic: str
    schema: str
    schema_encoding: str
    message_encoding: str
    messages: int = 0
    bytes: int | None = 0  # None: not counted (read from the file's summary)


@dataclass
class Recording:
    path: Path
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    complete: bool = False  # ended with its footer (closed properly)
    cut_short: str | None = None  # why reading stopped early

    @property
    def run(self) -> dict[str, str]:
        if RUN_METADATA not in self.metadata:
            raise ValueError(f"{self.path}: no {RUN_METADATA!r} metadata: not a recording of `ares record`")
        return self.metadata[RUN_METADATA]

    @property
    def cfg(self) -> dict[str, Any]:
        return dict(json.loads(self.run["config"]))

    def records(self) -> Iterator[tuple[Schema | None, Channel, Message]]:
        """Every message of the file in file order, with its channel and schema; metadata on the way."""
        schemas: dict[int, Schema] = {}
        channels: dict[int, Channel] = {}
        self.complete, self.cut_short = False, None
        with open(self.path, "rb") as f:
            reader = StreamReader(f, skip_magic=False)
            try:
                for record in reader.records:
                    if isinstance(record, Message):
                        channel = channels.get(record.channel_id)
                        if channel is not None:
                            yield schemas.get(channel.schema_id), channel, record
                    elif isinstance(record, Channel):
                        channels[record.id] = record
                    elif isinstance(record, Schema):
                        schemas[record.id] = record
                    elif isinstance(record, Metadata):
                        self.metadata[record.name] = dict(record.metadata)
                self.complete = True
            except (McapError, EOFError, ValueError, OSError, struct.error) as exc:  # a file cut short by a crash
                self.cut_short = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
                log.warning("%s: cut short (%s): read up to its last complete record", self.path, self.cut_short)

    def messages(self) -> Iterator[Recorded]:
        """The raw bus messages (not the Foxglove views), in the order the recorder received them."""
        for _schema, channel, message in self.records():
            topic = channel.metadata.get(TOPIC_META)
            if topic is not None:
                yield Recorded(
                    topic, channel.metadata.get(ENCODING_META, ""), message.data, message.log_time,
                    message.publish_time / 1e9,
                )  # fmt: skip


def open_recording(path: str | Path) -> Recording:
    """A recording, its metadata read (the run's configuration is written first)."""
    recording = Recording(Path(path))
    if not recording.path.exists():
        raise ValueError(f"{path}: no such file")
    for _ in recording.records():
        if RUN_METADATA in recording.metadata:
            break
    return recording


def info(path: str | Path) -> dict[str, Any]:
    """Channels (topic, schema, encodings, messages, bytes), span and whether the file is complete:
    from the summary of a file that has one (bytes per channel then unknown: None), else by reading
    it through."""
    summarised = _info_from_summary(Path(path))
    if summarised is not None:
        return summarised
    recording = Recording(Path(path))
    found: dict[int, ChannelInfo] = {}
    first = last = None
    for sch, channel, message in recording.records():
        entry = found.get(channel.id)
        if entry is None:
            entry = found[channel.id] = ChannelInfo(
                channel.topic,
                sch.name if sch is not None else "",
                sch.encoding if sch is not None else "",
                channel.message_encoding,
            )
        entry.messages += 1
        entry.bytes += len(message.data)
        first = message.log_time if first is None else min(first, message.log_time)
        last = message.log_time if last is None else max(last, message.log_time)
    return {
        "file": str(path),
        "size_bytes": Path(path).stat().st_size,
        "complete": recording.complete,
        "cut_short": recording.cut_short,
        "vehicle_id": recording.metadata.get(RUN_METADATA, {}).get("vehicle_id"),
        "messages": sum(c.messages for c in found.values()),
        "duration_s": round((last - first) / 1e9, 3) if first is not None and last is not None else 0.0,
        "channels": [vars(c) for c in sorted(found.values(), key=lambda c: c.topic)],
    }


def _info_from_summary(path: Path) -> dict[str, Any] | None:
    try:
        with open(path, "rb") as f:
            reader = make_reader(f)
            summary = reader.get_summary()
            metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()} if summary is not None else {}
    except (McapError, EOFError, ValueError, OSError):
        return None  # cut short: no summary to read
    if summary is None or summary.statistics is None:
        return None
    stats = summary.statistics
    channels = []
    for channel in summary.channels.values():
        sch = summary.schemas.get(channel.schema_id)
        channels.append(
            vars(
                ChannelInfo(
                    channel.topic,
                    sch.name if sch is not None else "",
                    sch.encoding if sch is not None else "",
                    channel.message_encoding,
                    stats.channel_message_counts.get(channel.id, 0),
                    None,
                )
            )
        )
    return {
        "file": str(path),
        "size_bytes": path.stat().st_size,
        "complete": True,
        "cut_short": None,
        "vehicle_id": metadata.get(RUN_METADATA, {}).get("vehicle_id"),
        "messages": stats.message_count,
        "duration_s": round((stats.message_end_time - stats.message_start_time) / 1e9, 3),
        "channels": sorted(channels, key=lambda c: c["topic"]),
    }


# ---- playing a recording into a bus ---------------------------------------------------------------


def play(
    recording: Recording, bus: BaseBus, speed: float | None = 1.0, stop: threading.Event | None = None
) -> dict[str, int]:
    """Publish the recorded messages on `bus`, in their order, paced by their own stamps (stack
    seconds) divided by `speed`, or as fast as they go (`speed` None). Returns messages per topic."""
    stop = stop or threading.Event()
    sent: dict[str, int] = {}
    anchor: tuple[float, float] | None = None  # (wall, stamp) of the first message
    for rec in recording.messages():
        if stop.is_set():
            break
        entry = topics.find(rec.topic)
        if entry is None or entry.is_pattern and "*" in rec.topic:
            continue
        if speed is not None:
            if anchor is None:
                anchor = (time.monotonic(), rec.stamp)
            due = anchor[0] + (rec.stamp - anchor[1]) / speed
            wait = due - time.monotonic()
            if wait > 0 and stop.wait(wait):
                break
        try:
            msg = schema.decode(rec.payload, entry.schema)
        except ValueError:
            continue
        bus.publisher(rec.topic).put(msg)
        sent[rec.topic] = sent.get(rec.topic, 0) + 1
    return sent


# ---- one node against its recorded outputs ----------------------------------------------------------


def _is_output(topic: str, outputs: list[str]) -> bool:
    return any(topic == o or topics.covers(o, topic) for o in outputs)


@dataclass
class BusReplayResult(ReplayResult):
    searched_steps: int = 0  # steps with inputs since the previous one: which of them it latched was searched
    latched_otherwise: int = 0  # of them, steps that latched more or fewer than had reached the recorder at the tick
    undecided: int = 0  # searched steps whose node state could not be copied to try the alternatives


def replay_node(path: str | Path, node_name: str, max_mismatches: int = 20) -> BusReplayResult:
    """Feed one node the recorded bus and compare what it publishes with what it published."""
    recording = open_recording(path)
    cfg = recording.cfg
    cfg["replay"] = {**cfg.get("replay", {}), "record": []}
    try:
        spec = processes.by_name(node_name, wire=bool(cfg.get("wire")))
    except KeyError as exc:
        raise ValueError(exc.args[0]) from None
    cls = spec.node_class()
    if not cls.steps:
        raise ValueError(f"{node_name} has no periodic step to replay")
    in_lockstep = node_name in cfg.get("lockstep", {}).get("participants", [])
    inputs = [i.topic for i in cls.inputs()]
    outputs = [o.topic for o in cls.outputs()]
    tick_topic = f"sim/clock/{node_name}"

    clock = ManualClock(0.0)
    network = MemoryNetwork(cfg["vehicle_id"])
    node = cls(cfg, clock=clock, bus=network.bus(node_name, clock), name=node_name)
    published = capture_outputs(node)
    feeder = network.bus("replay", clock)
    result = BusReplayResult(node=node_name, steps=0, outputs=0)
    matcher = _StepMatcher(result, max_mismatches, _run_setup(node, published))
    lockstep = _LockstepSteps(node, clock, published, feeder, matcher) if in_lockstep else None
    for rec in recording.messages():
        topic = rec.topic
        if lockstep is not None and topic == tick_topic:
            lockstep.tick(rec.stamp)
        elif topic == "clock/done":
            done = orjson.loads(rec.payload)
            if done.get("process") == node_name and lockstep is not None:
                lockstep.done(float(done["t"]), float(done["next_due"]))
        elif any(topic == i or topics.covers(i, topic) for i in inputs):
            if lockstep is not None:
                lockstep.input(rec)
            else:
                feeder.inject(topic, rec.payload, rec.encoding or None)
        elif _is_output(topic, outputs) or (topic == "events" and orjson.loads(rec.payload).get("source") == node_name):
            message = [topic, as_record(rec.payload)]
            if lockstep is not None:
                lockstep.output(rec.stamp, message)
                continue
            last = matcher.last_step
            if topic != "events" and (last is None or rec.stamp > last + 1e-9):
                # no ticks to go by: a step at each new stamp of the node's outputs, and what it
                # published before that stamp is all there
                matcher.settle(rec.stamp, inclusive=False)
                matcher.stepped(rec.stamp, _step(node, clock, rec.stamp, published))
            matcher.expect(rec.stamp, message)
    if lockstep is not None:
        lockstep.resolve(float("inf"))
    matcher.settle(float("inf"), inclusive=True)
    node.teardown()
    if recording.cut_short:
        log.warning("%s: replayed up to where the recording was cut short", path)
    return result


class _LockstepSteps:
    """The steps of a lockstep participant, from its ticks (or, for a tick the recorder heard after
    the node's output, from that output). A step's candidates are the inputs since the previous
    step, in order of arrival, up to the step's first output or, later still, up to the first input
    stamped after the step: the step latched a prefix of them. It is tried latching what had
    reached the recorder at the tick, then all, then fewer, then more, its state copied and put
    back between tries; the first try that gives the recorded outputs is kept, or, if none does,
    the first (and the mismatch reported). What a step did not latch stays for the next. A step is
    settled once the node has reported it done (after publishing its outputs) and an input stamped
    after it has come."""

    def __init__(self, node: Any, clock: ManualClock, published: list[list[Any]], feeder: Any, matcher: _StepMatcher):
        self.node, self.clock, self.published, self.feeder, self.matcher = node, clock, published, feeder, matcher
        self.result = cast(BusReplayResult, matcher.result)
        self.next_due: float | None = None
        self.last_tick: float | None = None
        self.timeline: list[tuple[Any, ...]] = []  # ("tick", t) | ("in", Recorded) | ("out", stamp, message)
        self.settled: float | None = None  # the node has reported its steps up to here done

    def tick(self, t: float, unseen: bool = False) -> None:
        # a tick before the node's first report found no node to step (not started yet)
        if self.next_due is None or t < self.next_due - 1e-9:
            return
        if self.last_tick is not None and t <= self.last_tick + 1e-9:
            return  # the same time again (a repeated tick): no new step
        self.last_tick = t
        if not unseen:
            self.timeline.append(("tick", t))
            return
        # its tick has not reached the recorder: the step began after the previous one, somewhere
        # among the inputs since, which are all its window
        ticks = [i for i, e in enumerate(self.timeline) if e[0] == "tick"]
        self.timeline.insert(ticks[-1] + 1 if ticks else 0, ("tick", t))

    def input(self, rec: Recorded) -> None:
        self.timeline.append(("in", rec))
        if self.settled is not None and rec.stamp > self.settled:
            self.resolve(self.settled)

    def output(self, stamp: float, message: list[Any]) -> None:
        self._stepped_unseen(stamp)
        if self.last_tick is None:
            self.matcher.expect(stamp, message)  # published while setting up
        else:
            self.timeline.append(("out", round(stamp, 9), message))

    def done(self, t: float, next_due: float) -> None:
        self._stepped_unseen(t)
        self.next_due = next_due
        self.settled = t if self.settled is None else max(self.settled, t)
        self.resolve(self.settled)

    def _stepped_unseen(self, t: float) -> None:
        """The node published (or reported done) for a step whose tick has not reached the
        recorder yet (it came straight from the simulator to the node): the step was there."""
        self.tick(t, unseen=True)

    def resolve(self, upto: float) -> None:
        """Settle the steps up to `upto` whose window is closed: an input stamped after the step has
        come (the node may still have latched one stamped before it that reached the recorder late)."""
        while True:
            ticks = [i for i, e in enumerate(self.timeline) if e[0] == "tick" and e[1] <= upto + 1e-9]
            if not ticks:
                break
            t = self.timeline[ticks[0]][1]
            later = any(e[0] == "in" and e[1].stamp > t + 1e-9 for e in self.timeline[ticks[0] + 1 :])
            if not later and upto != float("inf"):
                break
            self._resolve_first(ticks[0])
        if upto == float("inf"):  # the end: what is left is delivered
            for e in self.timeline:
                if e[0] == "in":
                    self._inject(e[1])
                else:
                    self.matcher.expect(e[1], e[2])
            self.timeline = []

    def _resolve_first(self, at: int) -> None:
        t = round(self.timeline[at][1], 9)
        # what came since the previous step latched and reached the recorder before this tick: the
        # node had it at its tick, most likely (not certainly: it may have come by another path)
        before = [e[1] for e in self.timeline[:at] if e[0] == "in"]
        for e in self.timeline[:at]:
            if e[0] == "out":  # recorded at no step of the replay (the matcher reports it)
                self.matcher.expect(e[1], e[2])
        rest = self.timeline[at + 1 :]
        first_out = next((i for i, e in enumerate(rest) if e[0] == "out" and e[1] == t), None)
        next_tick = next((i for i, e in enumerate(rest) if e[0] == "tick"), len(rest))
        # after the tick: what came before the step's first output, and what came later but stamped
        # no later than the step, up to the first input stamped after it
        later = next((i for i, e in enumerate(rest) if e[0] == "in" and e[1].stamp > t + 1e-9), len(rest))
        end = max(first_out if first_out is not None else next_tick, later)
        window = before + [e[1] for e in rest[:end] if e[0] == "in"]
        expected = [e[2] for e in rest if e[0] == "out" and e[1] == t]
        self.timeline = [
            e for i, e in enumerate(rest) if not (i < end and e[0] == "in") and not (e[0] == "out" and e[1] == t)
        ]
        got, latched = self._step_with_window(t, window, len(before), expected)
        # reached the node after this step latched: the next step's, most likely
        self.timeline = [("in", rec) for rec in window[latched:]] + self.timeline
        self.matcher.stepped(t, got)
        for message in expected:
            self.matcher.expect(t, message)
        self.matcher.settle(t, inclusive=True)

    def _step_with_window(
        self, t: float, window: list[Recorded], at_tick: int, expected: list[list[Any]]
    ) -> tuple[list[Any], int]:
        """Step latching a prefix of `window` (the inputs since the last step, in order of arrival):
        first the `at_tick` that reached the recorder before the tick, then all, then fewer, then more."""
        if not window:
            return _step(self.node, self.clock, t, self.published), 0
        self.result.searched_steps += 1
        try:
            snapshot = _NodeSnapshot(self.node)
        except Exception:  # a state that cannot be copied (a solver's handle): latch at the tick
            self.result.undecided += 1
            for rec in window[:at_tick]:
                self._inject(rec)
            return _step(self.node, self.clock, t, self.published), at_tick
        tries = list(
            dict.fromkeys([at_tick, len(window), *range(at_tick - 1, -1, -1), *range(at_tick + 1, len(window))])
        )
        for k in tries:
            for rec in window[:k]:
                self._inject(rec)
            got = _step(self.node, self.clock, t, self.published)
            if not _compare(0, t, expected, got):
                if k != at_tick:
                    self.result.latched_otherwise += 1
                return got, k
            snapshot.restore()
        for rec in window[:at_tick]:
            self._inject(rec)
        return _step(self.node, self.clock, t, self.published), at_tick

    def _inject(self, rec: Recorded) -> None:
        self.feeder.inject(rec.topic, rec.payload, rec.encoding or None)


class _NodeSnapshot:
    """A node's own state, copied, to be put back: everything but its runtime (bus, clock, ports,
    configuration), which stays shared; and what its subscriptions hold."""

    RUNTIME = ("bus", "clock", "log", "_stop", "cfg", "core", "params", "shared", "vehicle", "_ports", "_events",
               "_heartbeats", "_rated", "_done", "_recorder")  # fmt: skip

    def __init__(self, node: Any):
        self.node = node
        self.keep = {id(v): v for k, v in vars(node).items() if k in self.RUNTIME}
        self.keep.update({id(p): p for p in node._ports.values()})
        self.state = copy.deepcopy(vars(node), dict(self.keep))
        self.subscriptions = {
            name: (p, _subscription_state(p)) for name, p in node._ports.items() if isinstance(p, Subscription)
        }

    def restore(self) -> None:
        fresh = copy.deepcopy(self.state, dict(self.keep))
        vars(self.node).clear()
        vars(self.node).update(fresh)
        for sub, state in self.subscriptions.values():
            _set_subscription_state(sub, state)


_SUBSCRIPTION_STATE = ("latest", "latest_topic", "count", "overflowed", "_first_stamp")
_SUBSCRIPTION_QUEUES = ("_stamps", "_queue", "_staged")


def _subscription_state(sub: Subscription[Any]) -> dict[str, Any]:
    state = {name: getattr(sub, name) for name in _SUBSCRIPTION_STATE}
    for name in _SUBSCRIPTION_QUEUES:
        queue = getattr(sub, name)
        state[name] = None if queue is None else collections.deque(queue, maxlen=queue.maxlen)
    state["_staged_stamps"] = list(sub._staged_stamps)
    return state


def _set_subscription_state(sub: Subscription[Any], state: dict[str, Any]) -> None:
    for name, value in state.items():
        if isinstance(value, collections.deque):
            value = collections.deque(value, maxlen=value.maxlen)
        elif isinstance(value, list):
            value = list(value)
        setattr(sub, name, value)


def _run_setup(node: Any, published: list[list[Any]]) -> list[list[Any]]:
    """What the node publishes while setting up."""
    node.setup()
    out = list(published)
    published.clear()
    return out


def _step(node: Any, clock: ManualClock, t: float, published: list[list[Any]]) -> list[list[Any]]:
    clock.set(max(t, clock.now()))
    node.step_once(t)
    out = list(published)
    published.clear()
    return out


class _StepMatcher:
    """Pairs each replayed step with the outputs the recording holds for it, by their stamps (a
    node stamps what a step publishes with the step's time), and compares them once the recording
    has passed that step: the node ran late in the run, its outputs come after later ticks."""

    def __init__(self, result: ReplayResult, max_mismatches: int, setup_outputs: list[list[Any]]):
        self.result = result
        self.max_mismatches = max_mismatches
        self.replayed: dict[float, list[list[Any]]] = {}  # step time -> what the node published then
        self.expected: dict[float, list[list[Any]]] = {}  # stamp -> what the recording holds
        self.setup_outputs: list[list[Any]] | None = setup_outputs  # against what came before the first step
        self.setup_expected: list[list[Any]] = []
        self.last_step: float | None = None
        self.frames = 0

    def stepped(self, t: float, outputs: list[list[Any]]) -> None:
        self.replayed[round(t, 9)] = outputs
        self.last_step = t
        self.result.steps += 1

    def expect(self, stamp: float, message: list[Any]) -> None:
        if self.last_step is None:
            self.setup_expected.append(message)
        else:
            self.expected.setdefault(round(stamp, 9), []).append(message)

    def settle(self, upto: float, inclusive: bool) -> None:
        if self.setup_outputs is not None and self.last_step is not None:
            self._compare(None, self.setup_expected, self.setup_outputs)
            self.setup_outputs = None
        for t in [t for t in self.replayed if t < upto or inclusive and t <= upto + 1e-9]:
            self._compare(t, self.expected.pop(t, []), self.replayed.pop(t))
        for stamp in [s for s in self.expected if s < upto and s not in self.replayed]:
            # recorded at a time the node did not step in the replay
            self._compare(stamp, self.expected.pop(stamp), [])

    def _compare(self, t: float | None, expected: list[list[Any]], got: list[list[Any]]) -> None:
        self.result.outputs += len(got)
        if len(self.result.mismatches) < self.max_mismatches:
            self.result.mismatches += _compare(self.frames, t, expected, got)
        self.result.replayed.append(got)
        self.frames += 1
