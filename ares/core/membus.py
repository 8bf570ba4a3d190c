"""The bus in memory: nodes tested by feeding them messages and stepping time, no processes.

A `MemoryNetwork` stands for one Zenoh network; each `MemoryBus` on it is one process's bus
with the same interface as ares.core.bus.Bus. Messages are encoded and decoded exactly as on the real
bus (so schemas are checked both ways) and delivered at once, on the publisher's thread, to
every matching subscription of every bus of the network. A service call runs the serving
bus's handler straight away. Liveliness is the set of buses that declared themselves alive.

With ares.core.clock.ManualClock and ares.core.node.Node.step_once this gives deterministic node tests:

    net, clock = MemoryNetwork(), ManualClock()
    node = OdometryManager(cfg, clock=clock, bus=net.bus("odometry_manager", clock))
    feeder = net.bus("test", clock)
    feeder.publish("localization/pose", pose)
    clock.set(1.0); node.step_once()
"""

from __future__ import annotations

import collections
import fnmatch
from collections.abc import Callable, Iterator
from typing import Any

from ares.core import topics
from ares.core.bus import Answer, BaseBus, Query, encoding_name
from ares.core.clock import Clock, ManualClock
from ares.core.config import BusSettings
from ares.core.schema import Payload


class MemoryNetwork:
    def __init__(self, vehicle_id: str = "shuttle01"):
        self.vehicle_id = vehicle_id
        self._subscribers: list[tuple[str, Callable[[str, str, bytes], None]]] = []
        self._services: dict[str, tuple[MemoryBus, Callable[[Query], None]]] = {}  # key -> server, its on_query
        self.alive: set[str] = set()
        self.published: collections.Counter[str] = collections.Counter()

    def bus(
        self, process: str, clock: Clock | None = None, vehicle_id: str | None = None, **settings: Any
    ) -> MemoryBus:
        """A process's bus; `vehicle_id`: of another vehicle on the same network (a fleet's tests)."""
        return MemoryBus(self, process, clock or ManualClock(), BusSettings(**settings), vehicle_id)

    def put(self, key: str, encoding: str, payload: Payload) -> None:
        self.published[key] += 1
        for pattern, callback in list(self._subscribers):
            if _matches(pattern, key) and self.delivers(key, pattern):
                callback(key, encoding, bytes(payload))

    def delivers(self, key: str, pattern: str) -> bool:
        """Whether what is put on `key` reaches a subscription of `pattern` that matches it: always,
        on one network; a test's network that cuts a link says otherwise."""
        return True

    def serves(self, key: str) -> bool:
        """Whether a query on `key` reaches the service declared there: always, as `delivers`."""
        return True


def _matches(pattern: str, key: str) -> bool:
    if "*" not in pattern:
        return pattern == key
    if pattern.endswith("/**"):
        return key.startswith(pattern[:-2])
    return fnmatch.fnmatchcase(key, pattern) and key.count("/") == pattern.count("/")


class MemoryBus(BaseBus):
    def __init__(
        self,
        network: MemoryNetwork,
        process: str,
        clock: Clock,
        settings: BusSettings,
        vehicle_id: str | None = None,
    ):
        vehicle_id = vehicle_id or network.vehicle_id
        super().__init__(vehicle_id, process, clock, settings)
        self.network = network
        self.cfg = {"vehicle_id": vehicle_id, "bus": settings.model_dump()}

    def _declare_publisher(self, key: str, encoding: str, reliable: bool) -> Callable[[Payload], None]:
        return lambda payload: self.network.put(key, encoding, payload)

    def _declare_subscriber(self, key: str, on_payload: Callable[[str, str, bytes], None]) -> object:
        entry = (key, on_payload)
        self.network._subscribers.append(entry)
        return entry

    def _undeclare(self, handle: object) -> None:
        if handle in self.network._subscribers:
            self.network._subscribers.remove(handle)

    def _declare_queryable(self, key: str, on_query: Callable[[Query], None]) -> object:
        self.network._services[key] = (self, on_query)
        return key

    def _query(self, key: str, payload: Payload, encoding: str, timeout_s: float) -> Iterator[Answer]:
        if key not in self.network._services or not self.network.serves(key):
            return
        owner, on_query = self.network._services[key]
        answers: list[Answer] = []
        on_query((payload, lambda p, e: answers.append((True, e, p)), lambda p, e: answers.append((False, e, p))))
        owner.poll_services()
        yield from answers

    def declare_alive(self) -> None:
        self.network.alive.add(self.process)

    def alive_processes(self, timeout_s: float = 0.5) -> set[str]:
        return set(self.network.alive)

    def close(self) -> None:
        self.network.alive.discard(self.process)
        self.network._services = {k: v for k, v in self.network._services.items() if v[0] is not self}
        for sub in list(self._subscriptions):
            self.unsubscribe(sub)

    def inject(self, topic: str, payload: bytes, encoding: str | None = None) -> None:
        """Deliver a recorded payload to every subscription on the network (process replay)."""
        entry = topics.topic(topic)
        self.network.put(self.key(topic), encoding or encoding_name(entry.schema), payload)
