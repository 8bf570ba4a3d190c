"""The base of every ARES process: config, clock, bus, a periodic loop, heartbeat, shutdown.

A node subclasses Node, sets `name` and `rate_key` (where its rate lives in config), and
overrides setup(), step(now) and teardown(). `python -m <module>` runs it through
`run_node(NodeClass)`, which is what each module's main() calls.

The heartbeat is sent from the loop itself (not a thread), so a loop that is stuck — even one
busy-looping while holding the GIL, which keeps the liveliness token alive — stops its
heartbeat and the supervisor notices.

A node whose parent (the supervisor) has gone, killed rather than stopped, stops too: no orphan
keeps driving a bus nobody watches. The drive-by-wire board brakes when its bridge goes quiet.
"""
from __future__ import annotations

import logging
import os
import signal
import sys
import threading
import time

from ares import config
from ares.bus import Bus
from ares.clock import Clock
from ares.messages import Event, EventLevel, Heartbeat

PROCESS_ENV = "ARES_PROCESS_NAME"


class Node:
    name: str = "node"
    rate_key: str | None = None     # dotted config key of the loop rate (stack Hz)
    default_rate_hz: float = 10.0

    def __init__(self, cfg: dict | None = None, clock: Clock | None = None, name: str | None = None):
        self.cfg = cfg if cfg is not None else config.current()
        self.clock = clock or Clock.from_env()
        self.name = name or os.environ.get(PROCESS_ENV) or self.name
        self.log = logging.getLogger(self.name)
        self.rate_hz = float(config.get(self.cfg, self.rate_key, self.default_rate_hz)) if self.rate_key else self.default_rate_hz
        self.bus = Bus(self.cfg, self.name, self.clock)
        self._stop = threading.Event()
        self._hb_period_s = float(config.get(self.cfg, "heartbeat.period_s", 0.2))
        self._hb_seq = 0
        self._hb_last_wall = 0.0
        self.loop_overruns = 0
        self._last_step_ms = 0.0
        self._parent_pid = os.getppid()

    # ---- to override --------------------------------------------------------------------
    def setup(self) -> None:
        pass

    def step(self, now: float) -> None:
        raise NotImplementedError

    def teardown(self) -> None:
        pass

    # ---- helpers ------------------------------------------------------------------------
    def event(self, kind: str, message: str, level: EventLevel = EventLevel.INFO, **data) -> None:
        self.log.log(logging.WARNING if level != EventLevel.INFO else logging.INFO, "%s: %s", kind, message)
        self.bus.publish("events", Event(t=self.clock.now(), source=self.name, kind=kind, level=level,
                                         message=message, data=data))

    def stop(self) -> None:
        self._stop.set()

    @property
    def stopping(self) -> bool:
        return self._stop.is_set()

    def _heartbeat(self) -> None:
        wall = time.time()
        if wall - self._hb_last_wall < self._hb_period_s:
            return
        self._hb_last_wall = wall
        self.bus.publish(f"heartbeat/{self.name}", Heartbeat(
            t=self.clock.now(), process=self.name, seq=self._hb_seq, pid=os.getpid(), wall=wall,
            loop_overruns=self.loop_overruns, step_ms=self._last_step_ms))
        self._hb_seq += 1

    # ---- the loop -----------------------------------------------------------------------
    def run(self) -> None:
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, lambda *_: self._stop.set())
        period = 1.0 / self.rate_hz
        try:
            self.setup()
            self.bus.declare_alive()
            next_t = self.clock.now()
            while not self._stop.is_set():
                started = time.perf_counter()
                now = self.clock.now()
                self.bus.poll_services()
                self.step(now)
                self._last_step_ms = (time.perf_counter() - started) * 1e3
                self._heartbeat()
                if os.getppid() != self._parent_pid:
                    self.log.warning("parent process %d is gone: stopping", self._parent_pid)
                    break
                next_t += period
                lag = self.clock.now() - next_t
                if lag > period:
                    self.loop_overruns += 1
                    next_t = self.clock.now()   # don't try to catch up with a burst of steps
                self._stop.wait(self.clock.wall_for(next_t - self.clock.now()))
        finally:
            try:
                self.teardown()
            finally:
                self.bus.close()


def setup_logging(name: str) -> None:
    level = os.environ.get("ARES_LOG_LEVEL", "INFO").upper()
    logging.basicConfig(level=level, stream=sys.stderr,
                        format=f"%(asctime)s {name} %(levelname)s %(name)s: %(message)s")


def run_node(node_cls: type[Node]) -> None:
    """Entry point used by each process module's main()."""
    setup_logging(os.environ.get(PROCESS_ENV, node_cls.name))
    node_cls().run()
