"""The black box's REST API as a process of the stack (process table entry `api`).

Inputs:   the black-box store (blackbox.store, as the recorder uses it; `ares run --store URI`)
Outputs:  HTTPS on api.host:api.port (blackbox/api.py: create_app, uvicorn_config);
          heartbeat/api from the server's own event loop; liveliness token alive/api
Params:   the `api:` section (ApiSettings), blackbox.store, blackbox.nice, heartbeat.period_s

The supervisor judges every process by its heartbeat. A uvicorn server has no loop of ours, so
the heartbeat is an asyncio task started in the application's lifespan, on the event loop
that serves the requests: when that loop is stuck (a blocking call in an async handler, a
busy loop), the heartbeat stops and the supervisor restarts the API. The Zenoh session is
opened in this process before uvicorn starts, and uvicorn runs in this same process (one
worker, no reload): nothing is forked after the session exists.

The listening socket is bound here, before uvicorn starts. If the port is taken (another
stack on this machine, a leftover server), the process does not crash into a restart loop that
would respawn Python every few seconds: it stays up, keeps its heartbeat, publishes one
`api_port_in_use` warning event and retries every PORT_RETRY_S until the port is free.

uvicorn stops gracefully on SIGTERM (the supervisor's stop), with a short grace for open
connections so that it is gone before the supervisor's stop_timeout_s.
"""
from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import signal
import socket
import threading
import time
from typing import Mapping

from ares import config
from ares.bus import Bus
from ares.clock import Clock
from ares.messages import Event, EventLevel, Heartbeat
from ares.node import PROCESS_ENV, setup_logging
from blackbox.recorder import lower_priority, open_configured_store, store_uri

NAME = "api"
GRACEFUL_SHUTDOWN_S = 1.5       # open connections (streamed exports) get this long on SIGTERM
PORT_RETRY_S = 5.0              # port in use: try binding again this often (wall seconds)

log = logging.getLogger(NAME)


def api_url(cfg: Mapping) -> str:
    """Where the supervised API serves (HTTPS: it never runs in clear under the supervisor)."""
    from blackbox.api import PREFIX, ApiSettings
    try:
        settings = ApiSettings.from_config(dict(cfg))
    except ValueError as exc:       # pydantic's ValidationError: the API process will say more
        return f"(invalid api configuration: {str(exc).splitlines()[0]})"
    host = f"[{settings.host}]" if ":" in settings.host else settings.host
    return f"https://{host}:{settings.port}{PREFIX}"


class Heartbeats:
    """heartbeat/<name> with one sequence, whoever sends it (the wait for the port, then the
    server's event loop)."""

    def __init__(self, bus: Bus, clock: Clock, name: str, period_s: float):
        self.bus, self.clock, self.name, self.period_s = bus, clock, name, period_s
        self.seq = 0
        self.overruns = 0

    def send(self, lag_ms: float = 0.0) -> None:
        self.bus.publish(f"heartbeat/{self.name}", Heartbeat(
            t=self.clock.now(), process=self.name, seq=self.seq, pid=os.getpid(), wall=time.time(),
            loop_overruns=self.overruns, step_ms=lag_ms))
        self.seq += 1


def add_heartbeat(app, beats: Heartbeats) -> None:
    """Run a heartbeat task on the server's event loop for as long as the app lives."""
    inner = app.router.lifespan_context

    async def beat() -> None:
        lag_ms = 0.0
        while True:
            beats.send(lag_ms)
            started = time.monotonic()
            await asyncio.sleep(beats.period_s)
            # how late the loop woke us: a measure of how busy the server's event loop is
            lag_ms = max(time.monotonic() - started - beats.period_s, 0.0) * 1e3
            if lag_ms > beats.period_s * 1e3:
                beats.overruns += 1

    @contextlib.asynccontextmanager
    async def lifespan(a):
        task = asyncio.create_task(beat(), name=f"heartbeat/{beats.name}")
        try:
            async with inner(a) as state:
                yield state
        finally:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task

    app.router.lifespan_context = lifespan


def bind(host: str, port: int) -> socket.socket:
    """The server's listening socket (uvicorn listens on it); OSError if the port is taken."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind((host, port))
    except OSError:
        sock.close()
        raise
    return sock


def bind_when_free(host: str, port: int, beats: Heartbeats, stop: threading.Event) -> socket.socket | None:
    """Bind, waiting (heartbeat going) while the port is taken; None if stopped meanwhile."""
    warned = False
    while not stop.is_set():
        try:
            return bind(host, port)
        except OSError as exc:
            if not warned:
                warned = True
                log.error("cannot listen on %s:%d (%s): retrying every %g s", host, port, exc.strerror, PORT_RETRY_S)
                beats.bus.publish("events", Event(
                    t=beats.clock.now(), source=beats.name, kind="api_port_in_use", level=EventLevel.WARNING,
                    message=f"REST API cannot listen on {host}:{port}: {exc.strerror}; retrying",
                    data={"host": host, "port": port}))
        deadline = time.monotonic() + PORT_RETRY_S
        while not stop.is_set() and time.monotonic() < deadline:
            beats.send()
            stop.wait(beats.period_s)
    return None


def main() -> None:
    name = os.environ.get(PROCESS_ENV, NAME)
    setup_logging(name)
    cfg = config.current()
    lower_priority(cfg)             # before the heavy imports: the start-up is what competes most
    import uvicorn

    from blackbox.api import PREFIX, ApiSettings, create_app, uvicorn_config
    clock = Clock.from_env()
    settings = ApiSettings.from_config(cfg)
    # uvicorn re-raises the SIGTERM it handled once it has stopped; with a handler of ours in
    # place (it also ends a wait for the port), the clean-up below runs and the process exits 0
    stop = threading.Event()

    def on_signal(sig, _frame) -> None:
        log.info("stopped by %s", signal.Signals(sig).name)
        stop.set()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, on_signal)
    store = open_configured_store(cfg)
    bus = Bus(cfg, name, clock)
    try:
        beats = Heartbeats(bus, clock, name, float(config.get(cfg, "heartbeat.period_s", 0.2)))
        bus.declare_alive()
        app = create_app(store, settings)
        add_heartbeat(app, beats)
        server_cfg = uvicorn_config(app, settings)
        server_cfg.lifespan = "on"      # the heartbeat task lives in the lifespan
        server_cfg.timeout_graceful_shutdown = GRACEFUL_SHUTDOWN_S
        sock = bind_when_free(server_cfg.host, server_cfg.port, beats, stop)
        if sock is None:
            return
        log.info("REST API on https://%s:%d%s, store %s", server_cfg.host, server_cfg.port, PREFIX, store_uri(cfg))
        uvicorn.Server(server_cfg).run(sockets=[sock])
    finally:
        bus.close()
        store.close()


if __name__ == "__main__":
    main()
