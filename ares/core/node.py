"""The base of every ARES process: its contract as data, and the runtime around its step.

A node declares what it reads, writes, serves and takes as parameters, as class attributes:

    class OdometryManager(Node):
        '''Odometry manager: how far the pose estimate can be trusted (ARES eq. 6).'''
        name = "odometry_manager"
        Params = OdometryParams                      # its config section, typed (ares.core.config)
        pose = Input("localization/pose", max_age="stale_after_s", doc="the fused pose")
        score = Output("odometry/score", rate="rate_hz")

        def step(self, now):
            pose = self.pose.fresh(now)
            ...
            self.score.put(OdometryScore(...))

The base makes the subscriptions and publishers from the declaration (`self.pose` is then the
Subscription, `self.score` the Publisher), refuses a topic that is not in the topic table when
the class is defined, and refuses at once any publish or subscribe on `self.bus` that the
contract does not declare. `ares describe` prints the contracts; docs/nodes.md is generated from
them; the supervisor uses the declared output rates to notice a process alive but silent.

Every node also publishes `events`, its heartbeat `heartbeat/<name>` (from the loop itself: a
loop stuck holding the GIL keeps its liveliness token alive but stops its heartbeat), and with
the simulator-driven clock (`--speed max`) `clock/done` after each step (ares.core.lockstep).

The runtime: `run()` sets up, declares the liveliness token and loops at the node's rate on the
stack clock: each step latches the inputs that arrived since the last one (a step sees one
consistent set), answers queued service calls, calls `step(now)`, heartbeats. A node whose
parent (the supervisor) has gone stops too. `step_once(now)` is the same step without the loop,
for tests on ares.core.membus with a ManualClock; process replay (ares.core.replay) records and replays
exactly those steps.

`AsyncNode` is the same runtime for a process whose work is an asyncio event loop (the REST
API): heartbeat and parent watch are tasks on that loop, so a stuck loop stops the heartbeat.
"""

from __future__ import annotations

import asyncio
import copy
import logging
import math
import os
import signal
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Generic, Literal, Self, TypeVar, cast, overload

from ares.core import config, topics
from ares.core.bus import BaseBus, Bus, Publisher, PublisherFamily, RejectCounter, Subscription, SubscriptionState
from ares.core.clock import Clock, DrivenClock
from ares.core.config import Params
from ares.core.messages import ClockDone, Event, EventLevel, Heartbeat
from ares.core.recording import INCARNATION_ENV, StepRecorder, recording_path
from ares.core.schema import Msg, Payload

PROCESS_ENV = "ARES_PROCESS_NAME"
NICE_ENV = "ARES_NICE"
IMPLICIT_OUTPUTS = ("events", "heartbeat/*", "clock/done")  # what every node publishes undeclared

Port = TypeVar("Port")  # what a declaration is on a node: its Subscription, Publisher, ...
Handler = TypeVar("Handler", bound=Callable[..., Any])


class ContractError(RuntimeError):
    """A node used the bus beyond its declared contract, or declared something unknown."""


class NoParams(Params):
    pass


# ---- declarations -----------------------------------------------------------------------------


class _Port(Generic[Port]):
    def __init__(self, topic: str, doc: str):
        try:
            self.entry = topics.topic(topic)
        except KeyError as exc:
            raise ContractError(exc.args[0]) from None
        self.topic = topic
        self.doc = doc
        self.attr = ""

    def __set_name__(self, owner: type, name: str) -> None:
        self.attr = name

    @overload
    def __get__(self, node: None, owner: type | None = None) -> Self: ...
    @overload
    def __get__(self, node: Node, owner: type | None = None) -> Port: ...
    def __get__(self, node: Node | None, owner: type | None = None) -> Self | Port:
        if node is None:
            return self
        return cast(Port, node._ports[self.attr])  # made from this declaration by Node.__init__

    @staticmethod
    def _resolve(value: float | str | None, params: Params, what: str) -> float | None:
        if value is None or isinstance(value, (int, float)):
            return value
        found: Any = params  # then what each name leads to: the models type it, not this walk
        for part in value.split("."):  # "body.rate_hz": a parameter of a sub-section
            if not hasattr(found, part):
                raise ContractError(f"{what} names parameter {value!r}, which {type(params).__name__} does not have")
            found = getattr(found, part)
        return float(found)


class Input(_Port[Subscription[Msg]]):
    """A topic the node reads: `max_age` (seconds, or the name of a parameter) is how old its
    latest message may be and still count (Subscription.fresh); `queue` keeps every message."""

    def __init__(self, topic: str, *, max_age: float | str | None = None, queue: int | str = 0, doc: str = ""):
        super().__init__(topic, doc)
        self.max_age = max_age
        self.queue = queue

    def max_age_s(self, params: Params) -> float | None:
        return self._resolve(self.max_age, params, f"input {self.topic}")

    def queue_size(self, params: Params) -> int:
        return int(self._resolve(self.queue, params, f"input {self.topic}") or 0)


class InputGroup:
    """Several inputs read alike, by name (`{"odometry": "odometry/score", ...}`): the node
    sees a dict of name -> Subscription."""

    def __init__(self, topics_by_name: dict[str, str], *, max_age: float | str | None = None, doc: str = ""):
        self.members = {name: Input(topic, max_age=max_age, doc=doc) for name, topic in topics_by_name.items()}
        self.doc = doc
        self.attr = ""

    def __set_name__(self, owner: type, name: str) -> None:
        self.attr = name
        for key, member in self.members.items():
            member.attr = f"{name}.{key}"

    @overload
    def __get__(self, node: None, owner: type | None = None) -> Self: ...
    @overload
    def __get__(self, node: Node, owner: type | None = None) -> dict[str, Subscription[Msg]]: ...
    def __get__(self, node: Node | None, owner: type | None = None) -> Self | dict[str, Subscription[Msg]]:
        if node is None:
            return self
        return {key: member.__get__(node) for key, member in self.members.items()}


class Output(_Port[Publisher[Msg] | PublisherFamily]):
    """A topic the node publishes: `rate` (Hz, or the name of a parameter) when it is periodic."""

    def __init__(self, topic: str, *, rate: float | str | None = None, doc: str = ""):
        super().__init__(topic, doc)
        if self.entry.is_pattern and rate is not None:
            raise ContractError(f"output {topic!r} is a family of keys: it has no single rate")
        self.rate = rate

    def rate_hz(self, params: Params) -> float | None:
        return self._resolve(self.rate, params, f"output {self.topic}")


def service(name: str) -> Callable[[Handler], Handler]:
    """Marks a method as the handler of a service of the table (a request in, its reply out)."""
    topics.service(name)

    def mark(method: Handler) -> Handler:
        vars(method)["ares_service"] = name  # method.ares_service, which no Callable type declares
        return method

    return mark


# ---- the node -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class NodeState:
    """A node's own state and what its subscriptions hold, copied (Node.copy_state)."""

    attributes: dict[str, Any]
    shared: dict[int, Any]  # id -> object: its runtime, which a copy shares instead of copying
    subscriptions: list[tuple[Subscription[Msg], SubscriptionState[Msg]]]


class Node:
    name: str = "node"  # the class's; an instance has its process's name
    Params: ClassVar[type[config.Params]] = NoParams
    sections: ClassVar[dict[str, type[config.Params]]] = {}  # other (shared) config sections it reads
    rate: ClassVar[float | str] = "rate_hz"  # loop rate: Hz, or the name of a parameter
    steps: ClassVar[bool] = True  # works in periodic steps (latched inputs; a --speed max participant)
    calls: ClassVar[tuple[str, ...]] = ()  # the services it calls (any other call is refused)
    # fields of its outputs that are measured, not computed (a stage's wall time): a replay does
    # not compare them, as openpilot's process replay ignores its timings ("topic.field.path")
    replay_ignores: ClassVar[tuple[str, ...]] = ()
    # what its outputs' stamps are: the step's time, or the time of the data they describe (a
    # perception stamps its grid with the sweep's); a replay of a recording of the bus then pairs
    # outputs with the step the node reported done after them
    stamps_outputs_with: ClassVar[Literal["step", "data"]] = "step"
    fleet_inputs: ClassVar[tuple[str, ...]] = ()  # topics it reads from every vehicle (bus.subscribe_fleet)
    # device wires (wire/gnss, wire/can, wire/lidar) it reads or writes instead of the bus: a driver
    # reads what the simulator writes with --wire, so the lockstep waits for it as for a subscriber
    wire_inputs: ClassVar[tuple[str, ...]] = ()
    wire_outputs: ClassVar[tuple[str, ...]] = ()
    # what a node is made of but does not change by stepping: its runtime, which a copy of its
    # state shares instead of copying (copy_state); anything else a subclass sets is its state
    RUNTIME: ClassVar[tuple[str, ...]] = (
        "bus", "clock", "log", "_stop", "cfg", "core", "params", "shared", "vehicle", "_ports", "_events",
        "_heartbeats", "_rated", "_done", "_recorder",
    )  # fmt: skip

    # ---- the contract, as data --------------------------------------------------------------
    @classmethod
    def inputs(cls) -> list[Input]:
        found: list[Input] = []
        for value in _class_attrs(cls).values():
            if isinstance(value, Input):
                found.append(value)
            elif isinstance(value, InputGroup):
                found.extend(value.members.values())
        return found

    @classmethod
    def outputs(cls) -> list[Output]:
        return [v for v in _class_attrs(cls).values() if isinstance(v, Output)]

    @classmethod
    def services(cls) -> dict[str, str]:
        """service name -> handler method name"""
        return {v.ares_service: k for k, v in _class_attrs(cls).items() if callable(v) and hasattr(v, "ares_service")}

    @classmethod
    def drives_clock(cls) -> bool:
        """Whether this node publishes the time at --speed max (the simulator)."""
        return any(o.topic == "sim/clock" for o in cls.outputs())

    @classmethod
    def loop_rate_hz(cls, params: config.Params) -> float:
        return float(cls.rate) if isinstance(cls.rate, (int, float)) else float(getattr(params, cls.rate))

    @classmethod
    def section(cls) -> str:
        return cls.name

    # ---- construction -------------------------------------------------------------------------
    def __init__(
        self,
        cfg: dict[str, Any] | None = None,
        *,
        clock: Clock | None = None,
        bus: BaseBus | None = None,
        name: str | None = None,
    ):
        self.cfg = cfg if cfg is not None else config.current()
        self.core = config.core(self.cfg)
        self.params = config.section(self.cfg, self.section(), self.Params)
        self.shared = {key: config.section(self.cfg, key, model) for key, model in self.sections.items()}
        self.vehicle = self.core.vehicle_profile
        self.clock = clock or Clock.from_env()
        self.name = name or os.environ.get(PROCESS_ENV) or type(self).name
        self.log = logging.getLogger(self.name)
        self.rate_hz = self.loop_rate_hz(self.params)
        raw_bus = bus or Bus(self.cfg, self.name, self.clock)
        self.bus = _DeclaredBus(raw_bus, self)
        self._stop = threading.Event()
        self._hb_period_s = self.core.heartbeat.period_s
        self._hb_seq = 0
        self._hb_last = -math.inf
        self.loop_overruns = 0
        self._last_step_ms = 0.0
        self._parent_pid = os.getppid()
        # the recorder exists before the first subscription, so that it misses no message
        self._recorder = self._start_recorder() if self.name in self.core.replay.record else None
        took = self._recorder.took if self._recorder else None
        gave = self._recorder.gave if self._recorder else None
        self._ports: dict[str, Subscription[Msg] | Publisher[Msg] | PublisherFamily] = {}
        self._rated: list[tuple[Publisher[Msg], float]] = []
        for inp in self.inputs():
            self._ports[inp.attr] = raw_bus.subscribe(
                inp.topic,
                queue=inp.queue_size(self.params),
                max_age=inp.max_age_s(self.params),
                latched=self.steps,
                tap=took,
            )
        for out in self.outputs():
            if out.entry.is_pattern:  # a family of keys (sim/clock/<process>): one publisher per key
                self._ports[out.attr] = PublisherFamily(raw_bus, out.topic, gave)
                continue
            pub = raw_bus.publisher(out.topic)
            pub.tap = gave
            self._ports[out.attr] = pub
            rate = out.rate_hz(self.params)
            if rate:
                self._rated.append((pub, rate))
        self._events = raw_bus.publisher("events")
        self._events.tap = gave
        self._heartbeats = raw_bus.publisher(f"heartbeat/{self.name}")
        clock = self.clock
        self._driven = isinstance(clock, DrivenClock)
        if isinstance(clock, DrivenClock) and not self.drives_clock():
            self._done = raw_bus.publisher("clock/done")
            # a participant hears the time when its step is due, and only then; others hear it now and then
            ticks = f"sim/clock/{self.name}" if self.name in self.core.lockstep.participants else "sim/clock"
            raw_bus.subscribe(ticks, on_message=lambda _topic, tick: clock.advance(tick.t))
        for name, method in self.services().items():
            raw_bus.serve(name, getattr(self, method))

    @property
    def restarted(self) -> bool:
        """Whether this process is a restart by the supervisor (not the run's first start)."""
        return int(os.environ.get(INCARNATION_ENV, "0")) > 0

    def kept_state_path(self) -> Path | None:
        """Where this process keeps what a restart must find (beside the run's configuration), or
        None outside a supervised run (tests on the in-memory bus)."""
        run_config = os.environ.get(config.RUN_CONFIG_ENV)
        return Path(run_config).with_name(f"{self.name}.json") if run_config else None

    def _start_recorder(self) -> StepRecorder:
        incarnation = int(os.environ.get(INCARNATION_ENV, "0"))
        path = recording_path(Path(self.core.replay.dir or "replay"), self.name, incarnation)
        self.log.info("recording inputs and outputs for process replay to %s", path)
        return StepRecorder(
            path,
            {
                "node": self.name,
                "class": f"{type(self).__module__}:{type(self).__qualname__}",
                "start": self.clock.now(),
                "config": self.cfg,
            },
        )

    # ---- to override ------------------------------------------------------------------------
    def setup(self) -> None:
        pass

    def step(self, now: float) -> None:
        raise NotImplementedError

    def teardown(self) -> None:
        pass

    # ---- helpers ----------------------------------------------------------------------------
    def event(
        self, kind: str, message: str, level: EventLevel = EventLevel.INFO, **data: str | float | int | bool | None
    ) -> None:
        self.log.log(logging.WARNING if level != EventLevel.INFO else logging.INFO, "%s: %s", kind, message)
        self._events.put(
            Event(t=self.clock.now(), source=self.name, kind=kind, level=level, message=message, data=data)
        )

    def stop(self) -> None:
        self._stop.set()

    @property
    def stopping(self) -> bool:
        return self._stop.is_set()

    def step_once(self, now: float | None = None) -> None:
        """One step: latch the inputs, answer queued service calls, step."""
        for port in self._ports.values():
            if isinstance(port, Subscription):
                port.latch()
        # read after latching: every input of this step was produced before `now`
        now = self.clock.now() if now is None else now
        if self._recorder is not None:
            self._recorder.begin(now)
        try:
            self.bus.poll_services()
            started = time.perf_counter()
            self.step(now)
            self._last_step_ms = (time.perf_counter() - started) * 1e3
        finally:
            if self._recorder is not None:
                self._recorder.end()

    # ---- for process replay (ares.core.replay) ---------------------------------------------
    def tap_outputs(self, tap: Callable[[str, Payload], None]) -> None:
        """Hand `tap` (topic, payload) everything the node publishes from now on, on its declared
        outputs and on `events`: a replay compares it with what the node published in the run. It
        takes the place of the step recorder's tap (a replayed node records nothing)."""
        for port in self._ports.values():
            if isinstance(port, (Publisher, PublisherFamily)):
                port.tap = tap
        self._events.tap = tap

    def copy_state(self) -> NodeState:
        """The node's own state (what its steps change: every attribute but its RUNTIME, a
        subclass's included) and what its subscriptions hold, copied: `restore_state` puts it
        back. A replay from a recording of the bus, which does not say which inputs a step
        latched, tries the step latching different ones and puts the node back between tries.
        Raises what copy.deepcopy raises for a state that cannot be copied (a solver's handle)."""
        shared = {id(value): value for name, value in vars(self).items() if name in self.RUNTIME}
        shared.update({id(port): port for port in self._ports.values()})
        return NodeState(
            copy.deepcopy(vars(self), dict(shared)),
            shared,
            [(port, port.copy_state()) for port in self._ports.values() if isinstance(port, Subscription)],
        )

    def restore_state(self, state: NodeState) -> None:
        """Be again what `state` was copied from (copied once more: a state can be put back many times)."""
        attributes = copy.deepcopy(state.attributes, dict(state.shared))
        vars(self).clear()
        vars(self).update(attributes)
        for subscription, held in state.subscriptions:
            subscription.restore_state(held)

    def heartbeat(self, force: bool = False) -> None:
        elapsed = time.monotonic()
        if not force and elapsed - self._hb_last < self._hb_period_s:
            return
        self._hb_last = elapsed
        self._heartbeats.put(
            Heartbeat(
                t=self.clock.now(),
                process=self.name,
                seq=self._hb_seq,
                pid=os.getpid(),
                wall=time.time(),
                loop_overruns=self.loop_overruns,
                step_ms=self._last_step_ms,
                outputs={pub.topic: (rate, pub.last_stamp) for pub, rate in self._rated},
            )
        )
        self._hb_seq += 1

    def parent_gone(self) -> bool:
        if os.getppid() != self._parent_pid:
            self.log.warning("parent process %d is gone: stopping", self._parent_pid)
            return True
        return False

    # ---- the loop -----------------------------------------------------------------------------
    def run(self) -> None:
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, lambda *_: self._stop.set())
        try:
            self.setup()
            self.bus.declare_alive()
            self.heartbeat(force=True)
            self.loop()
        finally:
            try:
                self.teardown()
            finally:
                if self._recorder is not None:
                    self._recorder.close()
                self.bus.close()

    def loop(self) -> None:
        period = 1.0 / self.rate_hz
        next_t = self._first_due(period)
        while not self._stop.is_set():
            reached = self.clock.wait_until(next_t, self._stop, self._hb_period_s)
            if self._stop.is_set() or self.parent_gone():
                break
            if not reached:
                self.bus.poll_services()
                self.heartbeat()
                if self._driven:  # again: the simulator may have started after our last report
                    self._report_done(self.clock.now(), next_t)
                continue
            self.step_once()
            self.heartbeat()
            next_t = self._next_due(next_t, period)

    def _first_due(self, period: float) -> float:
        now = self.clock.now()
        if not self._driven:
            return now
        due = grid_after(now, period)
        self._report_done(now, due)  # joins the lockstep: nothing due before `due`
        return due

    def _next_due(self, due: float, period: float) -> float:
        now = self.clock.now()
        if self._driven:
            # on the period grid, strictly after now: the clock may have jumped past several
            following = grid_after(now, period)
            self._report_done(now, following)
            return following
        following = due + period
        if now - following > period:
            self.loop_overruns += 1
            following = now  # don't try to catch up with a burst of steps
        return following

    def _report_done(self, now: float, next_due: float) -> None:
        self._done.put(ClockDone(t=now, process=self.name, next_due=next_due))


class AsyncNode(Node):
    """A node whose work is an asyncio loop (`serve()`); heartbeat and parent watch run as a task
    on that loop, so the supervisor sees the loop itself, not a thread beside it. It has no
    periodic step: its inputs update as messages arrive, and it never holds the clock back."""

    rate = 5.0  # its heartbeat task's rate
    steps = False

    async def serve(self) -> None:
        raise NotImplementedError

    def request_stop(self) -> None:
        """How `serve()` is told to finish (parent gone); the subclass decides."""
        self._stop.set()

    def step(self, now: float) -> None:
        pass

    async def _beat(self) -> None:
        lag_ms = 0.0
        while not self._stop.is_set():
            self._last_step_ms = lag_ms
            self.heartbeat(force=True)
            self.bus.poll_services()
            if self.parent_gone():
                self.request_stop()
                return
            started = time.monotonic()
            await asyncio.sleep(self._hb_period_s)
            # how late the loop woke us: a measure of how busy the event loop is
            lag_ms = max(time.monotonic() - started - self._hb_period_s, 0.0) * 1e3
            if lag_ms > self._hb_period_s * 1e3:
                self.loop_overruns += 1

    async def main(self) -> None:
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, self.request_stop)
        beat = asyncio.create_task(self._beat(), name=f"heartbeat/{self.name}")
        beat.add_done_callback(self._beat_ended)
        try:
            await self.serve()
        finally:
            beat.cancel()
            try:
                await beat
            except asyncio.CancelledError:
                pass

    def _beat_ended(self, task: asyncio.Task[None]) -> None:
        if not task.cancelled() and task.exception() is not None:
            self.log.error("the heartbeat task failed: stopping", exc_info=task.exception())
            self.request_stop()

    def run(self) -> None:
        try:
            self.setup()
            self.bus.declare_alive()
            self.loop_forever()
        finally:
            try:
                self.teardown()
            finally:
                self.bus.close()

    def loop_forever(self) -> None:
        asyncio.run(self.main())


# ---- the bus as the contract allows it ---------------------------------------------------------


class _DeclaredBus:
    """The node's view of the bus: what its contract declares, and nothing else."""

    def __init__(self, bus: BaseBus, node: Node):
        self._bus = bus
        self._node = node
        self._allowed = {o.topic for o in node.outputs()} | {t.replace("*", node.name) for t in IMPLICIT_OUTPUTS}

    def publisher(self, topic: str, reliable: bool | None = None) -> Publisher[Msg]:
        if topic not in self._allowed and not any(topics.covers(o.topic, topic) for o in self._node.outputs()):
            raise ContractError(
                f"{self._node.name} publishes {topic!r} but its contract does not declare it: "
                f"add `Output({topic!r}, ...)` to {type(self._node).__name__}"
            )
        return self._bus.publisher(topic, reliable)

    def publish(self, topic: str, msg: Msg) -> None:
        self.publisher(topic).put(msg)

    def subscribe(
        self,
        topic: str,
        queue: int = 0,
        on_message: Callable[[str, Msg], None] | None = None,
        *,
        max_age: float | None = None,
        latched: bool = False,
        tap: Callable[[str, bytes | None], None] | None = None,
    ) -> Subscription[Msg]:
        """Another subscription (with a callback, say) to a declared input."""
        if topic not in {i.topic for i in self._node.inputs()}:
            raise ContractError(
                f"{self._node.name} subscribes to {topic!r} outside its contract: declare "
                f"`Input({topic!r}, ...)` on {type(self._node).__name__} instead"
            )
        return self._bus.subscribe(topic, queue, on_message, max_age=max_age, latched=latched, tap=tap)

    def subscribe_fleet(self, topic: str, on_message: Callable[[str, str, Msg], None]) -> object:
        """A topic of every vehicle on the network, declared in `fleet_inputs`."""
        if topic not in self._node.fleet_inputs:
            raise ContractError(
                f"{self._node.name} reads {topic!r} of every vehicle outside its contract: add it "
                f"to `fleet_inputs` on {type(self._node).__name__}"
            )
        return self._bus.subscribe_fleet(topic, on_message)

    def call(
        self, name: str, request: Msg | None = None, timeout_s: float | None = None, vehicle_id: str | None = None
    ) -> Msg:
        """A service the contract declares in `calls` (of another vehicle: `vehicle_id`)."""
        if name not in self._node.calls:
            raise ContractError(
                f"{self._node.name} calls service {name!r} outside its contract: add it to "
                f"`calls` on {type(self._node).__name__}"
            )
        return self._bus.call(name, request, timeout_s, vehicle_id)

    def serve(self, name: str, handler: Callable[[Msg], Msg]) -> None:
        raise ContractError(
            f"{self._node.name} offers service {name!r} outside its contract: mark the "
            "handler with @service(...) instead"
        )

    def poll_services(self) -> int:
        return self._bus.poll_services()

    def declare_alive(self) -> None:
        self._bus.declare_alive()

    def close(self) -> None:
        self._bus.close()

    def key(self, topic: str) -> str:
        return self._bus.key(topic)

    @property
    def rejects(self) -> RejectCounter:
        return self._bus.rejects


def grid_after(t: float, period: float) -> float:
    """The first multiple of `period` after t, rounded to the nanosecond so that the simulator's
    ticks and every process's due times, computed apart, compare equal."""
    return round((math.floor(t / period + 1e-9) + 1) * period, 9)


def _class_attrs(cls: type) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for klass in reversed(cls.__mro__):
        out.update(vars(klass))
    return out


# ---- running one ---------------------------------------------------------------------------------


def setup_logging(name: str) -> None:
    level = os.environ.get("ARES_LOG_LEVEL", "INFO").upper()
    logging.basicConfig(
        level=level, stream=sys.stderr, format=f"%(asctime)s {name} %(levelname)s %(name)s: %(message)s"
    )


def lower_priority() -> None:
    """ARES_NICE (from the process table): a process that must yield the CPU to the driving ones."""
    niceness = int(os.environ.get(NICE_ENV, "0") or 0)
    if niceness > 0:
        try:
            os.nice(niceness)
        except OSError as exc:
            logging.getLogger("ares.core.node").warning("could not lower the priority by %d: %s", niceness, exc)


def run_node(node_cls: type[Node]) -> None:
    """Run one node in this process until SIGINT/SIGTERM or its parent goes."""
    setup_logging(os.environ.get(PROCESS_ENV, node_cls.name))
    lower_priority()
    node_cls().run()
