"""Process replay from a recording of the whole bus (the MCAP files of ares.app.bus_record): one
node's steps rebuilt from what the bus carried, and driven through the replay engine
(ares.core.replay.NodeReplay) against the outputs it published in the run.

The node is built from the recorded run's configuration, and the recording's messages are taken
in the order the recorder received them. At `--speed max` (the node a lockstep participant) it
steps at each tick the simulator sent it (`sim/clock/<node>`) once it had reported itself due
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

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any, Protocol

import orjson

from ares.core import topics
from ares.core.node import Node
from ares.core.recording import as_record
from ares.core.replay import NodeReplay, Published, ReplayResult


class BusMessage(Protocol):
    """One raw bus message of a recording: its topic, payload and encoding as they travelled
    ("": the topic's own), and its own stamp `t` (stack seconds)."""

    @property
    def topic(self) -> str: ...
    @property
    def payload(self) -> bytes: ...
    @property
    def encoding(self) -> str: ...
    @property
    def stamp(self) -> float: ...


@dataclass
class BusReplayResult(ReplayResult):
    searched_steps: int = 0  # steps with inputs since the previous one: which of them it latched was searched
    latched_otherwise: int = 0  # of them, steps that latched more or fewer than had reached the recorder at the tick
    latched_per_topic: int = 0  # ... of those, steps that latched no prefix of the arrival order, but of each topic's
    undecided: int = 0  # searched steps whose node state could not be copied to try the alternatives
    unrecorded_steps: int = 0  # steps the recording ended before the node reported done: replayed, not compared


def replay_from_bus(
    messages: Iterable[BusMessage], node_class: type[Node], cfg: dict[str, Any], name: str, max_mismatches: int = 20
) -> BusReplayResult:
    """Feed the node `name` (of `node_class`, configured by the recorded run's `cfg`) the recorded
    bus and compare what it publishes with what it published."""
    if not node_class.steps:
        raise ValueError(f"{name} has no periodic step to replay")
    in_lockstep = name in cfg.get("lockstep", {}).get("participants", [])
    inputs = [i.topic for i in node_class.inputs()]
    outputs = [o.topic for o in node_class.outputs()]
    tick_topic = f"sim/clock/{name}"

    result = BusReplayResult(node=name, steps=0, outputs=0)
    engine = NodeReplay(node_class, cfg, name, result, max_mismatches=max_mismatches)
    engine.set_up()
    matcher = _StepMatcher(engine, engine.published())
    lockstep = (
        _LockstepSteps(engine, matcher, result, by_done=node_class.stamps_outputs_with == "data")
        if in_lockstep
        else None
    )
    for rec in messages:
        topic = rec.topic
        if lockstep is not None and topic == tick_topic:
            lockstep.tick(rec.stamp)
        elif topic == "clock/done":
            done = orjson.loads(rec.payload)
            if done.get("process") == name and lockstep is not None:
                lockstep.done(float(done["t"]), float(done["next_due"]))
        elif any(topic == i or topics.covers(i, topic) for i in inputs):
            if lockstep is not None:
                lockstep.input(rec)
            else:
                engine.deliver([rec])
        elif _is_output(topic, outputs) or (topic == "events" and orjson.loads(rec.payload).get("source") == name):
            message = [topic, as_record(rec.payload)]
            if lockstep is not None:
                lockstep.output(rec.stamp, message)
                continue
            last = matcher.last_step
            if topic != "events" and (last is None or rec.stamp > last + 1e-9):
                # no ticks to go by: a step at each new stamp of the node's outputs, and what it
                # published before that stamp is all there
                matcher.settle(rec.stamp, inclusive=False)
                matcher.stepped(rec.stamp, engine.step(rec.stamp))
            matcher.expect(rec.stamp, message)
    if lockstep is not None:
        lockstep.resolve(float("inf"))
    matcher.settle(float("inf"), inclusive=True)
    engine.tear_down()
    return result


def _is_output(topic: str, outputs: list[str]) -> bool:
    return any(topic == o or topics.covers(o, topic) for o in outputs)


class _LockstepSteps:
    """The steps of a lockstep participant, from its ticks (or, for a tick the recorder heard after
    the node's output, from that output). A step's candidates are the inputs since the previous
    step, in order of arrival, up to the step's first output or, later still, up to the first input
    stamped after the step: the step latched a prefix of them, which the engine searches for
    (NodeReplay.step_latching_a_prefix) from what had reached the recorder at the tick. What a step
    did not latch stays for the next. A step is settled once the node has reported it done (after
    publishing its outputs) and an input stamped after it has come. A node whose outputs carry the
    stamp of their data, not of the step (`by_done`), published them at the step it reports done
    next: that step's time is theirs."""

    def __init__(self, engine: NodeReplay, matcher: _StepMatcher, result: BusReplayResult, by_done: bool = False):
        self.engine, self.matcher, self.result = engine, matcher, result
        self.by_done = by_done
        self.awaiting_done: list[list[Any]] = []  # by_done: outputs of the step not yet reported done
        self.next_due: float | None = None
        self.last_tick: float | None = None
        self.timeline: list[tuple[Any, ...]] = []  # ("tick", t) | ("in", BusMessage) | ("out", stamp, message)
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

    def input(self, rec: BusMessage) -> None:
        self.timeline.append(("in", rec))
        if self.settled is not None and rec.stamp > self.settled:
            self.resolve(self.settled)

    def output(self, stamp: float, message: list[Any]) -> None:
        if self.by_done and self.last_tick is not None:
            self.awaiting_done.append(message)
            return
        self._stepped_unseen(stamp)
        if self.last_tick is None:
            self.matcher.expect(stamp, message)  # published while setting up
        else:
            self.timeline.append(("out", round(stamp, 9), message))

    def done(self, t: float, next_due: float) -> None:
        self._stepped_unseen(t)
        for message in self.awaiting_done:
            self.timeline.append(("out", round(t, 9), message))
        self.awaiting_done = []
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
        tail = self._unrecorded_tail() if upto == float("inf") else []
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
                    self.engine.deliver([e[1]])
                else:
                    self.matcher.expect(e[1], e[2])
            self.timeline = []
            self.matcher.settle(float("inf"), inclusive=True)
            self._step_unrecorded(tail)

    def _unrecorded_tail(self) -> list[tuple[Any, ...]]:
        """At the end: cut off the steps the node never reported done before the recording ended
        (a run stopped, a file cut). What they published may not have reached the recorder, so
        they are not compared; they are returned to be stepped after the rest."""
        first = next(
            (
                i
                for i, e in enumerate(self.timeline)
                if e[0] == "tick" and (self.settled is None or e[1] > self.settled + 1e-9)
            ),
            None,
        )
        if first is None:
            return []
        tail, self.timeline = self.timeline[first:], self.timeline[:first]
        cut_from = round(tail[0][1], 9)
        self.timeline += [e for e in tail if e[0] == "out" and e[1] < cut_from]  # an earlier step's, late
        return [e for e in tail if e[0] != "out"]

    def _step_unrecorded(self, tail: list[tuple[Any, ...]]) -> None:
        for e in tail:
            if e[0] == "in":
                self.engine.deliver([e[1]])
            else:
                self.engine.step(round(e[1], 9))
                self.result.unrecorded_steps += 1

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
        step = self.engine.step_latching_a_prefix(t, window, len(before), expected)
        if window:
            self.result.searched_steps += 1
            if step.undecided:
                self.result.undecided += 1
            elif step.latched != len(before) or step.per_topic:
                self.result.latched_otherwise += 1
            if step.per_topic:
                self.result.latched_per_topic += 1
        # reached the node after this step latched: the next step's, most likely
        self.timeline = [("in", rec) for rec in step.left] + self.timeline
        self.matcher.stepped(t, step.outputs)
        for message in expected:
            self.matcher.expect(t, message)
        self.matcher.settle(t, inclusive=True)


class _StepMatcher:
    """Pairs each replayed step with the outputs the recording holds for it, by their stamps (a
    node stamps what a step publishes with the step's time), and compares them once the recording
    has passed that step: the node ran late in the run, its outputs come after later ticks."""

    def __init__(self, engine: NodeReplay, setup_outputs: Published):
        self.engine = engine
        self.replayed: dict[float, Published] = {}  # step time -> what the node published then
        self.expected: dict[float, Published] = {}  # stamp -> what the recording holds
        self.setup_outputs: Published | None = setup_outputs  # against what came before the first step
        self.setup_expected: Published = []
        self.last_step: float | None = None

    def stepped(self, t: float, outputs: Published) -> None:
        self.replayed[round(t, 9)] = outputs
        self.last_step = t

    def expect(self, stamp: float, message: list[Any]) -> None:
        if self.last_step is None:
            self.setup_expected.append(message)
        else:
            self.expected.setdefault(round(stamp, 9), []).append(message)

    def settle(self, upto: float, inclusive: bool) -> None:
        if self.setup_outputs is not None and self.last_step is not None:
            self.engine.compare(None, self.setup_expected, self.setup_outputs)
            self.setup_outputs = None
        for t in [t for t in self.replayed if t < upto or inclusive and t <= upto + 1e-9]:
            self.engine.compare(t, self.expected.pop(t, []), self.replayed.pop(t))
        for stamp in [s for s in self.expected if s < upto and s not in self.replayed]:
            # recorded at a time the node did not step in the replay
            self.engine.compare(stamp, self.expected.pop(stamp), [])
