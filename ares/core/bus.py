"""The bus every ARES process uses: typed pub/sub and services over Zenoh (or in memory, for tests).

- keys are `ares/<vehicle_id>/<topic>`; each topic's schema, encoding and reliability come from
  the topic table (ares.core.topics): publishing or subscribing to a topic that is not there is a
  KeyError, at once;
- services are queryables under `ares/<vehicle_id>/srv/<name>`; a call has a timeout and fails
  with ServiceError naming the service and the reason;
- each process holds a liveliness token `ares/<vehicle_id>/alive/<process>`; heartbeats are
  published by the node loop (ares.core.node), because a token survives a stuck Python loop;
- a malformed or unknown message is logged and counted, never raised into the receiver.

Freshness is always judged from a message's own stamp `t` against the receiver's stack clock.

Zenoh callbacks run on Zenoh's threads and must not block: subscriptions only decode, keep the
latest value and append to a bounded queue; services are queued and answered from the owning
node's loop (poll_services), so handlers run on the node's own thread. A *latched* subscription
(what nodes use) holds what arrives until the node latches it at the start of its step, so a
step sees one consistent set of inputs, which is also what process replay records.

`BaseBus` holds everything but the transport; `Bus` is Zenoh, ares.core.membus.MemoryBus is the
in-memory one for deterministic node tests.
"""

from __future__ import annotations

import collections
import logging
import re
import threading
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Generic, TypeVar, cast

import orjson
import pydantic

from ares.core import schema, topics
from ares.core.clock import Clock, WallClock
from ares.core.config import VEHICLE_ID_PATTERN, BusSettings, ConfigError, read_secret
from ares.core.messages import ServiceErrorReply
from ares.core.schema import Msg, Payload

if TYPE_CHECKING:
    import zenoh  # imported where used: a process on the in-memory bus never loads it

VEHICLE_ID = re.compile(VEHICLE_ID_PATTERN)  # what subscribe_fleet takes from a key

log = logging.getLogger("ares.core.bus")

M = TypeVar("M", bound=Msg)
Item = TypeVar("Item")  # what a deque holds

ALIVE = "alive"
SERVICE_PREFIX = "srv"

Reply = Callable[[Payload, str], None]  # answers a query with (payload, encoding)
Query = tuple[Payload, Reply, Reply]  # (request payload, reply, reply_err)
Answer = tuple[bool, str, Payload]  # (ok, encoding, payload) of one reply


class BusError(RuntimeError):
    """The bus cannot be joined as configured (a credentials file missing or unreadable)."""


class ServiceError(RuntimeError):
    """A service call that did not succeed: no responder, timeout, or an error reply."""

    def __init__(self, service: str, reason: str):
        super().__init__(f"service {service!r}: {reason}")
        self.service = service
        self.reason = reason


def encoding_name(msg_schema: type[Msg]) -> str:
    name = _ENCODINGS.get(msg_schema)
    if name is None:
        media = "application/octet-stream" if schema.is_bulk(msg_schema) else "application/json"
        name = _ENCODINGS[msg_schema] = f"{media};{msg_schema.schema_name()}"
    return name


_ENCODINGS: dict[type[Msg], str] = {}  # schema -> its encoding: asked for every received message


class ServiceInbox:
    """Requests waiting for the owning node's loop. Filled on the transport's thread, which must
    never block: when full, a request is refused at once ("busy") instead of waiting; a request
    older than the callers' timeout is dropped unanswered, since its caller has already given up."""

    def __init__(self, capacity: int, max_wait_s: float):
        self.capacity = capacity
        self.max_wait_s = max_wait_s
        self._queue: collections.deque[tuple[float, Query]] = collections.deque()
        self._lock = threading.Lock()
        self.refused = 0
        self.expired = 0

    def offer(self, query: Query) -> bool:
        """Queue a (payload, reply, reply_err) query; False (not queued) when full."""
        with self._lock:
            if len(self._queue) >= self.capacity:
                self.refused += 1
                return False
            self._queue.append((time.monotonic(), query))
            return True

    @property
    def waiting(self) -> int:
        """How many requests wait for the owning node's loop."""
        with self._lock:
            return len(self._queue)

    def take(self) -> Query | None:
        """The oldest query still worth answering, or None."""
        while True:
            with self._lock:
                if not self._queue:
                    return None
                arrived, query = self._queue.popleft()
            if time.monotonic() - arrived <= self.max_wait_s:
                return query
            self.expired += 1


SERVICE_INBOX_CAPACITY = 64


class RejectCounter:
    """Counts rejected messages by reason and logs the first of each reason, then every 100th."""

    def __init__(self, where: str):
        self.where = where
        self.by_reason: collections.Counter[str] = collections.Counter()
        self._lock = threading.Lock()

    def reject(self, reason: str, detail: str = "") -> None:
        with self._lock:
            self.by_reason[reason] += 1
            n = self.by_reason[reason]
        if n == 1 or n % 100 == 0:
            log.warning("%s: rejected message (%s, %d so far): %s", self.where, reason, n, detail[:300])

    @property
    def total(self) -> int:
        return sum(self.by_reason.values())


def decode(payload: Payload, encoding: str, expected: type[M] | None, topic: str, rejects: RejectCounter) -> M | None:
    """Validate one received payload against the topic's schema; None when rejected."""
    if expected is None:
        rejects.reject("unknown topic", topic)
        return None
    if encoding != encoding_name(expected):  # what our publishers send passes on one comparison
        _, _, schema_name = encoding.partition(";")
        if schema_name and schema_name != expected.schema_name():
            rejects.reject("unknown schema", f"{topic}: got {schema_name}, expected {expected.schema_name()}")
            return None
    try:
        return schema.decode(payload, expected)
    except pydantic.ValidationError as exc:
        rejects.reject("malformed", f"{topic}: {exc.errors(include_url=False)[:2]}")
    except (schema.BulkDecodeError, ValueError) as exc:
        rejects.reject("malformed", f"{topic}: {exc}")
    return None


@dataclass(frozen=True)
class SubscriptionState(Generic[M]):
    """What a subscription holds, copied (Subscription.copy_state): its latest message, its counts,
    the stamps its rate is measured from, its queue and what waits for the next latch."""

    latest: M | None
    latest_topic: str
    count: int
    overflowed: int
    first_stamp: float | None
    stamps: collections.deque[float]
    queue: collections.deque[tuple[str, M]] | None
    staged: collections.deque[tuple[str, M, bytes | None]]
    staged_stamps: list[float]


def _copied(queue: collections.deque[Item]) -> collections.deque[Item]:
    return collections.deque(queue, maxlen=queue.maxlen)


class Subscription(Generic[M]):
    """The latest value of a topic (or a `/*` family), how fresh it is, and optionally a bounded
    queue of every value. Ages and rates come from the messages' own stamps."""

    def __init__(
        self,
        topic: str,
        clock: Clock,
        *,
        queue: int = 0,
        max_age: float | None = None,
        latched: bool = False,
        on_message: Callable[[str, M], None] | None = None,
        rejects: RejectCounter | None = None,
        tap: Callable[[str, bytes | None], None] | None = None,
    ):
        self.topic = topic
        self.clock = clock
        self.max_age = max_age
        self.latched = latched
        self.latest: M | None = None
        self.latest_topic = ""
        self.count = 0
        self.overflowed = 0  # queued messages pushed out unread by newer ones (queue full)
        self.rejects = rejects or RejectCounter(topic)
        self.tap = tap  # process replay's recorder: given here, so it misses nothing
        self._stamps: collections.deque[float] = collections.deque(maxlen=1024)  # rates of up to 500 Hz over 2 s
        self._first_stamp: float | None = None
        self._queue: collections.deque[tuple[str, M]] | None = collections.deque(maxlen=queue) if queue else None
        self._on_message = on_message
        # what arrived since the last latch: only what a step can still use (the latest value, or
        # as many as the queue holds), so a node that stalls holds no more than one step's worth;
        # every stamp is kept, for the rate
        self._staged: collections.deque[tuple[str, M, bytes | None]] = collections.deque(maxlen=max(queue, 1))
        self._staged_stamps: list[float] = []
        self._lock = threading.Lock()
        self.handle: object = None

    # ---- arrival (a transport thread) -----------------------------------------------------
    def deliver(self, topic: str, msg: M, payload: bytes | None = None) -> None:
        with self._lock:
            if self.latched:
                if self._queue is not None and len(self._staged) == self._staged.maxlen:
                    self.overflowed += 1
                self._staged.append((topic, msg, payload if self.tap is not None else None))
                self._staged_stamps.append(msg.t)
            else:
                self._count(msg.t)
                self._apply(topic, msg, payload)
        if self._on_message is not None:
            self._on_message(topic, msg)

    def latch(self) -> int:
        """Take in what arrived since the last latch (a node does this at the start of each step);
        returns how many messages arrived."""
        if not self._staged_stamps:  # read unlocked: a message arriving now waits for the next latch
            return 0
        with self._lock:
            staged, self._staged = list(self._staged), collections.deque(maxlen=self._staged.maxlen)
            stamps, self._staged_stamps = self._staged_stamps, []
            for t in stamps:
                self._count(t)
            for topic, msg, payload in staged:
                self._apply(topic, msg, payload)
        return len(stamps)

    @property
    def waiting(self) -> int:
        """How many messages wait for the next latch: no more than one step can use (the latest
        value, or as many as the queue holds), however many arrived."""
        return len(self._staged)

    def copy_state(self) -> SubscriptionState[M]:
        """What the subscription holds now, copied: `restore_state` puts it back. Process replay
        from a recording of the bus tries a step latching different inputs, and puts the node and
        its subscriptions back between tries (Node.copy_state)."""
        with self._lock:
            return SubscriptionState(
                self.latest, self.latest_topic, self.count, self.overflowed, self._first_stamp, _copied(self._stamps),
                None if self._queue is None else _copied(self._queue), _copied(self._staged),
                list(self._staged_stamps),
            )  # fmt: skip

    def restore_state(self, state: SubscriptionState[M]) -> None:
        """Hold again what `state` was copied from (copied once more: a state can be put back many times)."""
        with self._lock:
            self.latest, self.latest_topic, self.count = state.latest, state.latest_topic, state.count
            self.overflowed, self._first_stamp = state.overflowed, state.first_stamp
            self._stamps = _copied(state.stamps)
            self._queue = None if state.queue is None else _copied(state.queue)
            self._staged = _copied(state.staged)
            self._staged_stamps = list(state.staged_stamps)

    def _count(self, t: float) -> None:
        self.count += 1
        self._stamps.append(t)
        if self._first_stamp is None:
            self._first_stamp = t

    def _apply(self, topic: str, msg: M, payload: bytes | None) -> None:
        self.latest, self.latest_topic = msg, topic
        if self._queue is not None:
            if len(self._queue) == self._queue.maxlen:
                self.overflowed += 1
            self._queue.append((topic, msg))
        if self.tap is not None:
            self.tap(topic, payload)

    # ---- reading --------------------------------------------------------------------------
    def age(self, now: float | None = None) -> float:
        """Stack seconds since the latest message was produced (infinite if none yet)."""
        if self.latest is None:
            return float("inf")
        return (self.clock.now() if now is None else now) - self.latest.t

    def fresh(self, now: float | None = None, max_age: float | None = None) -> M | None:
        """The latest message if it is no older than max_age (default: the declared one)."""
        limit = self.max_age if max_age is None else max_age
        if limit is None:
            raise ValueError(f"subscription to {self.topic} has no max_age: give one")
        return self.latest if self.age(now) <= limit else None

    def alive(self, max_age_s: float) -> bool:
        return self.age() <= max_age_s

    def rate_hz(self, window_s: float = 2.0, now: float | None = None) -> float:
        """Messages per stack second produced over the last window (a topic that stopped fades
        to 0 within the window; one that began within it is measured over its own span)."""
        now = self.clock.now() if now is None else now
        recent = [t for t in list(self._stamps) if now - window_s < t <= now]
        if self._first_stamp is not None and now - self._first_stamp >= window_s:
            return len(recent) / window_s
        if len(recent) < 2:
            return 0.0
        return (len(recent) - 1) / max(max(recent) - min(recent), 1e-9)

    def rate_ok(self, min_hz: float, window_s: float = 2.0) -> bool:
        return self.rate_hz(window_s) >= min_hz

    def drain(self) -> list[tuple[str, M]]:
        """Every queued (topic, message) since the last drain, oldest first."""
        if self._queue is None:
            raise RuntimeError(f"subscription to {self.topic} has no queue")
        with self._lock:
            out = list(self._queue)
            self._queue.clear()
        return out


class _KeyReaders:
    """The subscriptions of one bus to one key, and the transport subscriber they share."""

    def __init__(self) -> None:
        self.subs: list[Subscription[Msg]] = []
        self.handle: object = None


class Publisher(Generic[M]):
    def __init__(self, bus: BaseBus, topic: str, entry: topics.Topic, reliable: bool):
        self.topic, self.schema = topic, entry.schema
        self.last_stamp: float | None = None
        self.count = 0
        self.tap: Callable[[str, Payload], None] | None = None  # process replay's recorder
        self._put = bus._declare_publisher(bus.key(topic), encoding_name(entry.schema), reliable)

    def put(self, msg: M) -> None:
        if not isinstance(msg, self.schema):
            raise TypeError(f"{self.topic} carries {self.schema.__name__}, not {type(msg).__name__}")
        payload = schema.encode(msg)
        self._put(payload)
        self.last_stamp = msg.t
        self.count += 1
        if self.tap is not None:
            self.tap(self.topic, payload)


class PublisherFamily:
    """The publishers of a family of keys (`sim/clock/*`), each made when first used:
    `family["localization"]` publishes on `sim/clock/localization`."""

    def __init__(self, bus: BaseBus, pattern: str, tap: Callable[[str, Payload], None] | None = None):
        self.topic = pattern
        self._bus = bus
        self._tap = tap
        self._made: dict[str, Publisher[Msg]] = {}

    @property
    def tap(self) -> Callable[[str, Payload], None] | None:
        """What every publisher of the family hands what it publishes to, as Publisher.tap (process
        replay's recorder, or a replay's capture): given to those made so far and those made later."""
        return self._tap

    @tap.setter
    def tap(self, tap: Callable[[str, Payload], None] | None) -> None:
        self._tap = tap
        for pub in self._made.values():
            pub.tap = tap

    def __getitem__(self, name: str) -> Publisher[Msg]:
        pub = self._made.get(name)
        if pub is None:
            pub = self._made[name] = self._bus.publisher(self.topic.replace("*", name))
            pub.tap = self._tap
        return pub


class BaseBus:
    """Typed pub/sub and services over a transport; subclasses provide the `_declare_*`,
    `_query` and liveliness methods."""

    def __init__(self, vehicle_id: str, process: str, clock: Clock | None, settings: BusSettings):
        self.vehicle_id = vehicle_id
        self.process = process
        self.prefix = f"ares/{vehicle_id}"
        self.clock = clock or WallClock()
        self.settings = settings
        self.service_timeout_s = settings.service_timeout_s
        self.rejects = RejectCounter(process)
        self._publishers: dict[str, Publisher[Msg]] = {}
        # with the simulator driving the clock every message counts (a step must see what was sent
        # before it): no topic may drop under congestion, a slow reader slows the simulation instead
        self._every_message_counts = self.clock.mode == "driven"
        self._subscriptions: list[Subscription[Msg]] = []
        self._by_key: dict[str, _KeyReaders] = {}  # topic (one key) -> the subscriptions sharing its subscriber
        self._services: list[tuple[str, ServiceInbox, Callable[[Msg], Msg]]] = []
        self._queryables: list[object] = []
        self._fleet_subscriptions: list[object] = []

    # ---- keys -------------------------------------------------------------------------------
    def key(self, topic: str) -> str:
        return f"{self.prefix}/{topic}"

    def topic_of(self, key: str) -> str:
        return key[len(self.prefix) + 1 :] if key.startswith(self.prefix + "/") else key

    # ---- pub/sub ----------------------------------------------------------------------------
    def publisher(self, topic: str, reliable: bool | None = None) -> Publisher[Msg]:
        pub = self._publishers.get(topic)
        if pub is None:
            entry = topics.topic(topic)
            if "*" in topic:
                raise KeyError(f"cannot publish on the pattern {topic!r}: name one key of it")
            if reliable is None:
                reliable = entry.reliable or self._every_message_counts
            pub = self._publishers[topic] = Publisher(self, topic, entry, reliable)
        return pub

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
        """Subscribe to a topic of the table, a family such as `heartbeat/*`, or a pattern of several
        topics (`sensors/*`: each message checked against its own topic's schema). `on_message` runs
        on a transport thread and must return at once."""
        if "*" not in topic or topics.find(topic) is not None:
            topics.topic(topic)  # a KeyError naming the topic if it is not in the table
        elif not topics.matching(topic):
            raise KeyError(f"pattern {topic!r} matches no topic of the topic table (ares/core/topics.py)")
        sub: Subscription[Msg] = Subscription(
            topic,
            self.clock,
            queue=queue,
            max_age=max_age,
            latched=latched,
            on_message=on_message,
            rejects=self.rejects,
            tap=tap,
        )
        if "*" in topic:
            sub.handle = self._declare_subscriber(self.key(topic), self._pattern_receiver(sub))
        else:
            self._join_key_readers(topic, sub)
        self._subscriptions.append(sub)
        return sub

    def _pattern_receiver(self, sub: Subscription[Msg]) -> Callable[[str, str, bytes], None]:
        """The transport callback of a subscription to a pattern: each key checked against its own topic."""

        def on_payload(key: str, encoding: str, payload: bytes) -> None:
            try:
                key_topic = self.topic_of(key)
                found = topics.find(key_topic)
                msg = decode(payload, encoding, found.schema if found is not None else None, key_topic, self.rejects)
                if msg is not None:
                    sub.deliver(key_topic, msg, payload)
            except Exception as exc:  # a bad message must never take the receiver down
                self.rejects.reject("receiver error", f"{key}: {exc!r}")

        return on_payload

    def _join_key_readers(self, topic: str, sub: Subscription[Msg]) -> None:
        """Subscriptions of this bus to one key share one transport subscriber, and each message is
        decoded once and handed to all of them, the same object: every transport subscriber costs
        a thread wake-up per message (the simulator reads clock/done twice, as its input and in
        the lockstep)."""
        readers = self._by_key.get(topic)
        if readers is None:
            readers = self._by_key[topic] = _KeyReaders()
            expected = topics.topic(topic).schema

            def on_payload(key: str, encoding: str, payload: bytes) -> None:
                try:
                    msg = decode(payload, encoding, expected, topic, self.rejects)
                except Exception as exc:  # a bad message must never take the receiver down
                    self.rejects.reject("receiver error", f"{key}: {exc!r}")
                    return
                if msg is None:
                    return
                for reader in readers.subs:  # one reader's failure is its own, as with a subscriber each
                    try:
                        reader.deliver(topic, msg, payload)
                    except Exception as exc:
                        self.rejects.reject("receiver error", f"{key}: {exc!r}")

            readers.handle = self._declare_subscriber(self.key(topic), on_payload)
        readers.subs = [*readers.subs, sub]  # a new list: the transport thread may be going through the old one
        sub.handle = readers.handle

    def subscribe_raw(self, pattern: str, on_payload: Callable[[str, str, bytes], None]) -> object:
        """Every key of this vehicle matching `pattern` (`**`: all of them), undecoded:
        on_payload(topic, encoding, payload) on a transport thread, which must return at once.
        For what reads the bus as bytes (recorders, load counters), not for nodes."""

        def on_key(key: str, encoding: str, payload: bytes) -> None:
            on_payload(self.topic_of(key), encoding, payload)

        return self._declare_subscriber(self.key(pattern), on_key)

    def subscribe_fleet(self, topic: str, on_message: Callable[[str, str, Msg], None]) -> object:
        """One topic of the table from every vehicle on the network (`ares/*/<topic>`): on_message(
        vehicle_id, topic, msg) runs on a transport thread and must return at once. For the fleet's
        views (the API's live gateway); a stack's own processes read their own vehicle only."""
        entry = topics.topic(topic)
        if entry.is_pattern:
            raise KeyError(f"subscribe_fleet takes one topic, not the family {topic!r}")

        def on_payload(key: str, encoding: str, payload: bytes) -> None:
            try:
                parts = key.split("/", 2)
                if len(parts) != 3 or not VEHICLE_ID.fullmatch(parts[1]):
                    self.rejects.reject("bad vehicle id", key[:80])  # a key no stack of ours publishes
                    return
                msg = decode(payload, encoding, entry.schema, topic, self.rejects)
                if msg is not None:
                    on_message(parts[1], topic, msg)
            except Exception as exc:  # a bad message must never take the receiver down
                self.rejects.reject("receiver error", f"{key}: {exc!r}")

        handle = self._declare_subscriber(f"ares/*/{topic}", on_payload)
        self._fleet_subscriptions.append(handle)  # held: a dropped subscriber is undeclared
        return handle

    def unsubscribe(self, sub: Subscription[Msg]) -> None:
        kept = [s for s in self._subscriptions if s is not sub]
        if len(kept) < len(self._subscriptions):
            self._subscriptions = kept
            readers = self._by_key.get(sub.topic)
            if readers is not None and readers.handle is sub.handle:
                readers.subs = [s for s in readers.subs if s is not sub]
                if readers.subs:
                    return  # the others still read the key
                del self._by_key[sub.topic]
            self._undeclare(sub.handle)

    # ---- services ---------------------------------------------------------------------------
    def serve(self, name: str, handler: Callable[[Msg], Msg]) -> None:
        """Offer a service. Requests are queued and answered by poll_services() on the
        caller's thread, so a hung node does not answer (and its callers time out)."""
        topics.service(name)
        inbox = ServiceInbox(SERVICE_INBOX_CAPACITY, self.service_timeout_s)

        def on_query(query: Query) -> None:
            if not inbox.offer(query):
                self.rejects.reject("service busy", name)
                err = ServiceErrorReply(
                    t=self.clock.now(), error="busy", detail=f"{inbox.capacity} requests already waiting"
                )
                query[2](schema.encode(err), encoding_name(ServiceErrorReply))

        self._queryables.append(self._declare_queryable(self.key(f"{SERVICE_PREFIX}/{name}"), on_query))
        self._services.append((name, inbox, handler))

    def poll_services(self) -> int:
        handled = 0
        for name, inbox, handler in self._services:
            while (query := inbox.take()) is not None:
                self._answer(name, query, handler)
                handled += 1
        return handled

    def _answer(self, name: str, query: Query, handler: Callable[[Msg], Msg]) -> None:
        raw, reply, reply_err = query
        entry = topics.service(name)
        try:
            request = entry.request.model_validate_json(raw or b"{}")
        except pydantic.ValidationError as exc:
            self.rejects.reject("malformed request", f"{name}: {exc.errors(include_url=False)[:2]}")
            err = ServiceErrorReply(
                t=self.clock.now(), error="invalid request", detail=str(exc.errors(include_url=False)[:3])
            )
            reply_err(schema.encode(err), encoding_name(ServiceErrorReply))
            return
        try:
            answer = handler(request)
            if not isinstance(answer, entry.reply):
                raise TypeError(f"handler returned {type(answer).__name__}, expected {entry.reply.__name__}")
            reply(schema.encode(answer), encoding_name(entry.reply))
        except Exception as exc:
            log.exception("service %s failed", name)
            err = ServiceErrorReply(t=self.clock.now(), error="handler failed", detail=repr(exc))
            reply_err(schema.encode(err), encoding_name(ServiceErrorReply))

    def call(
        self, name: str, request: Msg | None = None, timeout_s: float | None = None, vehicle_id: str | None = None
    ) -> Msg:
        """Call a service and return its validated reply, or raise ServiceError. `vehicle_id`: a
        service of another vehicle on the network (the fleet's calls), else this bus's own."""
        try:
            entry = topics.service(name)
        except KeyError:
            raise ServiceError(name, "unknown service") from None
        request = request if request is not None else entry.request(t=self.clock.now())
        if not isinstance(request, entry.request):
            raise ServiceError(name, f"request must be {entry.request.__name__}")
        timeout_s = self.service_timeout_s if timeout_s is None else timeout_s
        started = time.monotonic()
        if vehicle_id is not None and not VEHICLE_ID.fullmatch(vehicle_id):
            raise ServiceError(name, f"not a vehicle id: {vehicle_id!r}")
        prefix = self.prefix if vehicle_id is None else f"ares/{vehicle_id}"
        for ok, encoding, payload in self._query(
            f"{prefix}/{SERVICE_PREFIX}/{name}", schema.encode(request), encoding_name(entry.request), timeout_s
        ):
            if ok:
                msg = decode(payload, encoding, entry.reply, f"srv/{name}", self.rejects)
                if msg is None:
                    raise ServiceError(name, "malformed reply")
                return msg
            if payload == b"Timeout" and not encoding.endswith(";ServiceErrorReply"):
                break  # zenoh itself ends an unanswered query with this error reply (zenoh 1.10)
            try:
                detail = ServiceErrorReply.model_validate_json(payload)
            except pydantic.ValidationError:
                raise ServiceError(name, f"error reply: {payload[:200]!r}") from None
            raise ServiceError(name, f"{detail.error}: {detail.detail}")
        if time.monotonic() - started < timeout_s * 0.9:
            raise ServiceError(name, "no process offers this service (is it running?)")
        raise ServiceError(name, f"no reply within {timeout_s:.1f} s (process dead or hung?)")

    # ---- transport (subclasses) -------------------------------------------------------------
    def _declare_publisher(self, key: str, encoding: str, reliable: bool) -> Callable[[Payload], None]:
        raise NotImplementedError

    def _declare_subscriber(self, key: str, on_payload: Callable[[str, str, bytes], None]) -> object:
        raise NotImplementedError

    def _undeclare(self, handle: object) -> None:
        raise NotImplementedError

    def _declare_queryable(self, key: str, on_query: Callable[[Query], None]) -> object:
        """Calls on_query((payload, reply(payload, encoding), reply_err(payload, encoding))) for
        each request, on the transport's thread."""
        raise NotImplementedError

    def _query(self, key: str, payload: Payload, encoding: str, timeout_s: float) -> Iterator[Answer]:
        """Yields (ok, encoding, payload) of each reply."""
        raise NotImplementedError

    def declare_alive(self) -> None:
        raise NotImplementedError

    def alive_processes(self, timeout_s: float = 0.5) -> set[str]:
        raise NotImplementedError

    def close(self) -> None:
        raise NotImplementedError


# ---- Zenoh ------------------------------------------------------------------------------------


def _credentials(settings: BusSettings, process: str | None) -> tuple[str, str] | None:
    """(user, password) for a router that asks for credentials: bus.user and its password_file, or
    the process's own line of bus.credentials_file (its user is its name)."""
    try:
        if settings.user is not None and settings.password_file is not None:
            return settings.user, read_secret(settings.password_file, "bus.password_file")
        if settings.credentials_file is None or process is None:
            return None
        for line in read_secret(settings.credentials_file, "bus.credentials_file").splitlines():
            user, sep, password = line.partition(":")
            if sep and user.strip() == process and password.strip():
                return process, password.strip()
    except ConfigError as exc:
        raise BusError(str(exc)) from None
    raise BusError(f"bus.credentials_file {settings.credentials_file}: no line `{process}:<password>` for this process")


def zenoh_config(
    settings: BusSettings, mode: str | None = None, listen: list[str] | None = None, process: str | None = None
) -> zenoh.Config:
    """A Zenoh config from the stack's `bus:` section, logged in as `process` with
    bus.credentials_file. Multicast scouting is always off: a fleet shares one network, and
    vehicles must only meet through their routers."""
    import json

    import zenoh

    mode = mode or settings.mode
    cfg = zenoh.Config()
    cfg.insert_json5("mode", json.dumps(mode))
    cfg.insert_json5("scouting/multicast/enabled", "false")
    cfg.insert_json5("transport/link/tx/lease", json.dumps(int(settings.lease_ms)))
    # a deployment's router asks every link for credentials (docs/deploy.md)
    credentials = None if mode == "router" and settings.credentials_file else _credentials(settings, process)
    if credentials is not None:
        cfg.insert_json5("transport/auth/usrpwd", json.dumps({"user": credentials[0], "password": credentials[1]}))
    if mode == "router":
        cfg.insert_json5("listen/endpoints", json.dumps(listen or [settings.router]))
    else:
        cfg.insert_json5("connect/endpoints", json.dumps([settings.router]))
        if mode == "peer":
            # peers mesh directly with each other for latency; only over loopback by default
            cfg.insert_json5("listen/endpoints", json.dumps(listen or settings.listen))
    return cfg


def bus_settings(cfg: Mapping[str, Any]) -> BusSettings:
    return BusSettings.model_validate(cfg.get("bus") or {})


class Bus(BaseBus):
    """The bus over Zenoh: `cfg` is a run configuration (its vehicle_id and bus sections)."""

    def __init__(
        self,
        cfg: Mapping[str, Any],
        process: str,
        clock: Clock | None = None,
        session: zenoh.Session | None = None,
        mode: str | None = None,
        login: str | None = None,
    ):
        """`login`: the user of bus.credentials_file to log in as, when not the process's name (the
        read-only tools log in as the observer)."""
        import zenoh

        settings = bus_settings(cfg)
        super().__init__(cfg["vehicle_id"], process, clock, settings)
        self.cfg = cfg
        self.session = session or zenoh.open(zenoh_config(settings, mode=mode, process=login or process))
        self._owns_session = session is None
        self._token: zenoh.LivelinessToken | None = None
        self._zenoh_publishers: dict[str, zenoh.Publisher] = {}

    def _declare_publisher(self, key: str, encoding: str, reliable: bool) -> Callable[[Payload], None]:
        import zenoh

        # latest-value topics may drop under congestion; events and commands must not
        congestion = zenoh.CongestionControl.BLOCK if reliable else zenoh.CongestionControl.DROP
        pub = self.session.declare_publisher(key, encoding=zenoh.Encoding(encoding), congestion_control=congestion)
        self._zenoh_publishers[key] = pub
        return pub.put

    def matched(self, topic: str) -> bool:
        """Whether a subscriber anywhere on the network matches this bus's publisher of `topic`."""
        pub = self._zenoh_publishers.get(self.key(topic))
        # zenoh 1.10's stub says bool, but the property gives a MatchingStatus
        return pub is not None and cast("zenoh.MatchingStatus", pub.matching_status).matching

    def _declare_subscriber(self, key: str, on_payload: Callable[[str, str, bytes], None]) -> object:
        def on_sample(sample: zenoh.Sample) -> None:
            on_payload(str(sample.key_expr), str(sample.encoding), sample.payload.to_bytes())

        def on_key_sample(sample: zenoh.Sample) -> None:  # one key, known: not asked of every sample
            on_payload(key, str(sample.encoding), sample.payload.to_bytes())

        return self.session.declare_subscriber(key, on_sample if "*" in key else on_key_sample)

    def _undeclare(self, handle: object) -> None:
        cast("zenoh.Subscriber[None]", handle).undeclare()

    def _declare_queryable(self, key: str, on_query: Callable[[Query], None]) -> object:
        import zenoh

        def on_zenoh_query(query: zenoh.Query) -> None:
            raw = query.payload.to_bytes() if query.payload is not None else b""

            def reply(payload: Payload, encoding: str) -> None:
                try:
                    query.reply(query.key_expr, payload, encoding=zenoh.Encoding(encoding))
                finally:
                    query.drop()

            def reply_err(payload: Payload, encoding: str) -> None:
                try:
                    query.reply_err(payload, encoding=zenoh.Encoding(encoding))
                finally:
                    query.drop()

            on_query((raw, reply, reply_err))

        return self.session.declare_queryable(key, on_zenoh_query)

    def _query(self, key: str, payload: Payload, encoding: str, timeout_s: float) -> Iterator[Answer]:
        import zenoh

        replies = self.session.get(key, payload=payload, encoding=zenoh.Encoding(encoding), timeout=timeout_s)
        for r in replies:
            if r.ok is not None:
                yield True, str(r.ok.encoding), r.ok.payload.to_bytes()
            elif r.err is not None:  # a reply is one or the other
                yield False, str(r.err.encoding), r.err.payload.to_bytes()

    # ---- liveliness -------------------------------------------------------------------------
    def declare_alive(self) -> None:
        if self._token is None:
            self._token = self.session.liveliness().declare_token(self.key(f"{ALIVE}/{self.process}"))

    def alive_processes(self, timeout_s: float = 0.5) -> set[str]:
        replies = self.session.liveliness().get(self.key(f"{ALIVE}/*"), timeout=timeout_s)
        return {str(r.ok.key_expr).rsplit("/", 1)[-1] for r in replies if r.ok is not None}

    def watch_alive(self, on_change: Callable[[str, bool], None]) -> object:
        """Calls on_change(process, alive) as tokens appear and disappear (on a Zenoh thread)."""
        import zenoh

        def on_sample(sample: zenoh.Sample) -> None:
            on_change(str(sample.key_expr).rsplit("/", 1)[-1], sample.kind == zenoh.SampleKind.PUT)

        return self.session.liveliness().declare_subscriber(self.key(f"{ALIVE}/*"), on_sample, history=True)

    def close(self) -> None:
        if self._token is not None:
            try:
                self._token.undeclare()
            except Exception:
                pass
            self._token = None
        if self._owns_session and not self.session.is_closed():
            self.session.close()


def json_of(payload: bytes | None) -> object:
    """A recorded JSON payload as data (for replay files and diffs)."""
    return None if payload is None else orjson.loads(payload)
