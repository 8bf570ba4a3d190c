"""The Zenoh bus every ARES process uses.

- keys are `ares/<vehicle_id>/<topic>`; each topic has one schema (ares.messages.TOPICS);
- services are queryables under `ares/<vehicle_id>/srv/<name>`; a call has a timeout and
  fails with ServiceError naming the service and the reason;
- each process holds a liveliness token `ares/<vehicle_id>/alive/<process>`; heartbeats are
  published by the node loop (ares.node), because a token survives a stuck Python loop;
- a malformed or unknown message is logged and counted, never raised into the receiver.

Zenoh callbacks run on Zenoh's threads and must not block: subscriptions only decode, keep
the latest value and append to a bounded queue; services are queued and answered from the
owning node's loop (poll_services), so handlers run on the node's own thread.
"""
from __future__ import annotations

import collections
import json
import logging
import threading
import time
from dataclasses import dataclass, field
from typing import Callable, Generic, TypeVar

import pydantic
import zenoh

from ares import messages
from ares.clock import Clock
from ares.messages import Msg

log = logging.getLogger("ares.bus")

M = TypeVar("M", bound=Msg)

ALIVE = "alive"
SERVICE_PREFIX = "srv"


class ServiceError(RuntimeError):
    """A service call that did not succeed: no responder, timeout, or an error reply."""

    def __init__(self, service: str, reason: str):
        super().__init__(f"service {service!r}: {reason}")
        self.service = service
        self.reason = reason


def zenoh_config(bus_cfg: dict, mode: str | None = None, listen: list[str] | None = None) -> zenoh.Config:
    """A Zenoh config from the stack's `bus:` section. Multicast scouting is always off: a
    fleet shares one network, and vehicles must only meet through their routers."""
    mode = mode or bus_cfg.get("mode", "peer")
    cfg = zenoh.Config()
    cfg.insert_json5("mode", json.dumps(mode))
    cfg.insert_json5("scouting/multicast/enabled", "false")
    cfg.insert_json5("transport/link/tx/lease", json.dumps(int(bus_cfg.get("lease_ms", 10000))))
    if mode == "router":
        cfg.insert_json5("listen/endpoints", json.dumps(listen or [bus_cfg["router"]]))
    else:
        cfg.insert_json5("connect/endpoints", json.dumps([bus_cfg["router"]]))
        if mode == "peer":
            # peers mesh directly with each other for latency; only over loopback by default
            cfg.insert_json5("listen/endpoints", json.dumps(listen or bus_cfg.get("listen", ["tcp/127.0.0.1:0"])))
    return cfg


def encoding_for(schema: type[Msg]) -> zenoh.Encoding:
    return zenoh.Encoding.APPLICATION_JSON.with_schema(schema.schema_name())


def encode(msg: Msg) -> bytes:
    return msg.model_dump_json().encode()


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


def decode(sample_payload: bytes, encoding: str, expected: type[M] | None, topic: str,
           rejects: RejectCounter) -> M | None:
    """Validate one received payload against the topic's schema; None when rejected."""
    if expected is None:
        rejects.reject("unknown topic", topic)
        return None
    _, _, schema_name = encoding.partition(";")
    if schema_name and schema_name != expected.schema_name():
        rejects.reject("unknown schema", f"{topic}: got {schema_name}, expected {expected.schema_name()}")
        return None
    try:
        return expected.model_validate_json(sample_payload)
    except pydantic.ValidationError as exc:
        rejects.reject("malformed", f"{topic}: {exc.errors(include_url=False)[:2]}")
        return None


@dataclass
class Subscription(Generic[M]):
    """Latest value of a topic, how fresh it is, and (optionally) a bounded queue of all values."""

    topic: str
    clock: Clock
    queue_size: int = 0
    latest: M | None = None
    latest_topic: str = ""
    received_at: float | None = None     # stack time of the last accepted message
    count: int = 0
    rejects: RejectCounter = field(default_factory=lambda: RejectCounter("?"))
    _times: collections.deque = field(default_factory=lambda: collections.deque(maxlen=64))
    _queue: collections.deque | None = None
    _on_message: Callable[[str, M], None] | None = None
    _handle: object = None

    def __post_init__(self) -> None:
        if self.queue_size:
            self._queue = collections.deque(maxlen=self.queue_size)

    def _accept(self, topic: str, msg: M) -> None:
        now = self.clock.now()
        self.latest, self.latest_topic, self.received_at = msg, topic, now
        self.count += 1
        self._times.append(now)
        if self._queue is not None:
            self._queue.append((topic, msg))
        if self._on_message is not None:
            self._on_message(topic, msg)

    def age(self, now: float | None = None) -> float:
        """Stack seconds since the last accepted message (infinite if none yet)."""
        if self.received_at is None:
            return float("inf")
        return (self.clock.now() if now is None else now) - self.received_at

    def alive(self, max_age_s: float) -> bool:
        return self.age() <= max_age_s

    def rate_hz(self, window_s: float = 2.0) -> float:
        """Accepted messages per stack second over the last window."""
        now = self.clock.now()
        recent = [t for t in list(self._times) if now - t <= window_s]
        if len(recent) < 2:
            return 0.0
        return (len(recent) - 1) / max(recent[-1] - recent[0], 1e-9)

    def rate_ok(self, min_hz: float, window_s: float = 2.0) -> bool:
        return self.rate_hz(window_s) >= min_hz

    def drain(self) -> list[tuple[str, M]]:
        """Every queued (topic, message) since the last drain, oldest first."""
        if self._queue is None:
            raise RuntimeError(f"subscription to {self.topic} has no queue")
        out = []
        while self._queue:
            out.append(self._queue.popleft())
        return out


class Publisher(Generic[M]):
    def __init__(self, bus: "Bus", topic: str, schema: type[M], block: bool = False):
        self.topic, self.schema = topic, schema
        # latest-value topics may drop under congestion; events and commands must not
        congestion = zenoh.CongestionControl.BLOCK if block else zenoh.CongestionControl.DROP
        self._pub = bus.session.declare_publisher(bus.key(topic), encoding=encoding_for(schema),
                                                  congestion_control=congestion)

    def put(self, msg: M) -> None:
        if not isinstance(msg, self.schema):
            raise TypeError(f"{self.topic} carries {self.schema.__name__}, not {type(msg).__name__}")
        self._pub.put(encode(msg))


class Bus:
    def __init__(self, cfg: dict, process: str, clock: Clock | None = None,
                 session: zenoh.Session | None = None, mode: str | None = None):
        self.cfg = cfg
        self.process = process
        self.vehicle_id = cfg["vehicle_id"]
        self.prefix = f"ares/{self.vehicle_id}"
        self.clock = clock or Clock()
        bus_cfg = cfg["bus"]
        self.service_timeout_s = float(bus_cfg.get("service_timeout_s", 2.0))
        self.session = session or zenoh.open(zenoh_config(bus_cfg, mode=mode))
        self._owns_session = session is None
        self._publishers: dict[str, Publisher] = {}
        self._subscriptions: list[Subscription] = []
        self._services: list[tuple[str, object, Callable]] = []
        self._token = None
        self.rejects = RejectCounter(process)

    # ---- keys ---------------------------------------------------------------------------
    def key(self, topic: str) -> str:
        return f"{self.prefix}/{topic}"

    def topic_of(self, key: str) -> str:
        return key[len(self.prefix) + 1:] if key.startswith(self.prefix + "/") else key

    # ---- pub/sub ------------------------------------------------------------------------
    def publisher(self, topic: str, block: bool | None = None) -> Publisher:
        pub = self._publishers.get(topic)
        if pub is None:
            schema = messages.schema_for_topic(topic)
            if schema is None:
                raise KeyError(f"no schema for topic {topic!r}; add it to ares.messages.TOPICS")
            if block is None:
                block = topic in messages.BLOCKING_TOPICS
            pub = self._publishers[topic] = Publisher(self, topic, schema, block)
        return pub

    def publish(self, topic: str, msg: Msg) -> None:
        self.publisher(topic).put(msg)

    def subscribe(self, topic: str, queue: int = 0,
                  on_message: Callable[[str, Msg], None] | None = None) -> Subscription:
        """Subscribe to a topic (or a pattern such as `heartbeat/*`). `on_message` runs on a
        Zenoh thread and must return at once."""
        sub: Subscription = Subscription(topic=topic, clock=self.clock, queue_size=queue,
                                         rejects=self.rejects, _on_message=on_message)
        fixed_schema = messages.schema_for_topic(topic) if "*" not in topic else None

        def on_sample(sample: zenoh.Sample) -> None:
            try:
                key_topic = self.topic_of(str(sample.key_expr))
                schema = fixed_schema or messages.schema_for_topic(key_topic)
                msg = decode(sample.payload.to_bytes(), str(sample.encoding), schema, key_topic, self.rejects)
                if msg is not None:
                    sub._accept(key_topic, msg)
            except Exception:  # a bad message must never take the receiver down
                self.rejects.reject("receiver error", repr(sample.key_expr))
                log.exception("error handling a sample on %s", topic)

        sub._handle = self.session.declare_subscriber(self.key(topic), on_sample)
        self._subscriptions.append(sub)
        return sub

    def unsubscribe(self, sub: Subscription) -> None:
        kept = [s for s in self._subscriptions if s is not sub]
        if len(kept) < len(self._subscriptions):
            self._subscriptions = kept
            sub._handle.undeclare()

    # ---- services -----------------------------------------------------------------------
    def serve(self, name: str, handler: Callable[[Msg], Msg]) -> None:
        """Offer a service. Requests are queued and answered by poll_services() on the
        caller's thread, so a hung node does not answer (and its callers time out)."""
        if name not in messages.SERVICES:
            raise KeyError(f"no schema for service {name!r}; add it to ares.messages.SERVICES")
        queryable = self.session.declare_queryable(self.key(f"{SERVICE_PREFIX}/{name}"),
                                                   zenoh.handlers.FifoChannel(64))
        self._services.append((name, queryable, handler))

    def poll_services(self) -> int:
        handled = 0
        for name, queryable, handler in self._services:
            while True:
                query = queryable.try_recv()
                if query is None:
                    break
                self._answer(name, query, handler)
                handled += 1
        return handled

    def _answer(self, name: str, query: zenoh.Query, handler: Callable[[Msg], Msg]) -> None:
        req_schema, reply_schema = messages.SERVICES[name]
        raw = query.payload.to_bytes() if query.payload is not None else b"{}"
        try:
            request = req_schema.model_validate_json(raw or b"{}")
        except pydantic.ValidationError as exc:
            self.rejects.reject("malformed request", f"{name}: {exc.errors(include_url=False)[:2]}")
            err = messages.ServiceErrorReply(t=self.clock.now(), error="invalid request",
                                             detail=str(exc.errors(include_url=False)[:3]))
            query.reply_err(encode(err), encoding=encoding_for(messages.ServiceErrorReply))
            query.drop()
            return
        try:
            reply = handler(request)
            if not isinstance(reply, reply_schema):
                raise TypeError(f"handler returned {type(reply).__name__}, expected {reply_schema.__name__}")
            query.reply(query.key_expr, encode(reply), encoding=encoding_for(reply_schema))
        except Exception as exc:
            log.exception("service %s failed", name)
            err = messages.ServiceErrorReply(t=self.clock.now(), error="handler failed", detail=repr(exc))
            query.reply_err(encode(err), encoding=encoding_for(messages.ServiceErrorReply))
        finally:
            query.drop()

    def call(self, name: str, request: Msg | None = None, timeout_s: float | None = None) -> Msg:
        """Call a service and return its validated reply, or raise ServiceError."""
        if name not in messages.SERVICES:
            raise ServiceError(name, "unknown service")
        req_schema, reply_schema = messages.SERVICES[name]
        request = request if request is not None else req_schema(t=self.clock.now())
        if not isinstance(request, req_schema):
            raise ServiceError(name, f"request must be {req_schema.__name__}")
        timeout_s = self.service_timeout_s if timeout_s is None else timeout_s
        started = time.monotonic()
        replies = self.session.get(self.key(f"{SERVICE_PREFIX}/{name}"), payload=encode(request),
                                   encoding=encoding_for(req_schema), timeout=timeout_s)
        for reply in replies:
            if reply.ok is not None:
                msg = decode(reply.ok.payload.to_bytes(), str(reply.ok.encoding), reply_schema,
                             f"srv/{name}", self.rejects)
                if msg is None:
                    raise ServiceError(name, "malformed reply")
                return msg
            err = reply.err
            if err.payload.to_bytes() == b"Timeout" and not str(err.encoding).endswith(";ServiceErrorReply"):
                # zenoh itself ends an unanswered query with this error reply (zenoh 1.10)
                break
            try:
                detail = messages.ServiceErrorReply.model_validate_json(err.payload.to_bytes())
                raise ServiceError(name, f"{detail.error}: {detail.detail}")
            except pydantic.ValidationError:
                raise ServiceError(name, f"error reply: {err.payload.to_bytes()[:200]!r}") from None
        waited = time.monotonic() - started
        if waited < timeout_s * 0.9:
            raise ServiceError(name, "no process offers this service (is it running?)")
        raise ServiceError(name, f"no reply within {timeout_s:.1f} s (process dead or hung?)")

    # ---- liveliness ---------------------------------------------------------------------
    def declare_alive(self) -> None:
        if self._token is None:
            self._token = self.session.liveliness().declare_token(self.key(f"{ALIVE}/{self.process}"))

    def alive_processes(self, timeout_s: float = 0.5) -> set[str]:
        replies = self.session.liveliness().get(self.key(f"{ALIVE}/*"), timeout=timeout_s)
        return {str(r.ok.key_expr).rsplit("/", 1)[-1] for r in replies if r.ok is not None}

    def watch_alive(self, on_change: Callable[[str, bool], None]) -> object:
        """Calls on_change(process, alive) as tokens appear and disappear (on a Zenoh thread)."""
        def on_sample(sample: zenoh.Sample) -> None:
            process = str(sample.key_expr).rsplit("/", 1)[-1]
            on_change(process, sample.kind == zenoh.SampleKind.PUT)
        return self.session.liveliness().declare_subscriber(self.key(f"{ALIVE}/*"), on_sample, history=True)

    # ---- shutdown -----------------------------------------------------------------------
    def close(self) -> None:
        if self._token is not None:
            try:
                self._token.undeclare()
            except Exception:
                pass
            self._token = None
        if self._owns_session and not self.session.is_closed():
            self.session.close()
