"""The black box's REST API as a process of the stack (process table entry `api`).

It serves blackbox.api (create_app) over HTTPS from the black-box store the recorder writes. It
runs on the node runtime like every process, in its asyncio variant (ares.core.node.AsyncNode): the
heartbeat and the watch on its parent are tasks on the very event loop that serves the requests,
so a stuck loop (a blocking call in an async handler, a busy loop) stops the heartbeat and the
supervisor restarts the API, and a killed supervisor leaves no API behind. The Zenoh session is
opened in this process before uvicorn starts, and uvicorn runs in this same process and loop
(one worker, no reload): nothing is forked after the session exists.

The listening socket is bound here, before uvicorn starts. If the port is taken (another stack on
this machine, a leftover server), the process does not crash into a restart loop that would
respawn Python every few seconds: it stays up, keeps its heartbeat, publishes one
`api_port_in_use` warning event and retries every PORT_RETRY_S until the port is free.

uvicorn stops gracefully on SIGTERM (the supervisor's stop), with a short grace for open
connections so that it is gone before the supervisor's stop_timeout_s.
"""

from __future__ import annotations

import asyncio
import logging
import signal
import socket
from collections.abc import Mapping

import numpy as np

from ares.core import config
from ares.core.messages import EventLevel
from ares.core.node import AsyncNode, Output
from ares.core.route import RouteError, load_route
from ares.core.signed_command import load_command_key
from blackbox.api import PREFIX, ApiSettings, create_app, uvicorn_config
from blackbox.console.live_hub import GATEWAY_TOPICS, LiveHub
from blackbox.register import snapshot_files
from blackbox.register.recorder import open_configured_store, store_uri
from blackbox.register.store.record_store import StoreSettings

GRACEFUL_SHUTDOWN_S = 1.5  # open connections (streamed exports) get this long on SIGTERM
PORT_RETRY_S = 5.0  # port in use: try binding again this often (wall seconds)

log = logging.getLogger("api")


def api_url(cfg: Mapping) -> str:
    """Where the supervised API serves (HTTPS: it never runs in clear under the supervisor)."""
    try:
        settings = config.section(cfg, "api", ApiSettings)
    except config.ConfigError as exc:  # the API process will say more
        return f"(invalid api configuration: {str(exc).splitlines()[0]})"
    host = f"[{settings.host}]" if ":" in settings.host else settings.host
    return f"https://{host}:{settings.port}{PREFIX}"


def pages_url(cfg: Mapping) -> str:
    """The address of the web pages (the API's, without its prefix)."""
    url = api_url(cfg)
    return url[: -len(PREFIX)] if url.endswith(PREFIX) else url


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


def route_view(core: config.CoreConfig, spacing_m: float = 2.0) -> dict | None:
    """The vehicle's route for the pages' maps, in its local frame: the centre line every
    `spacing_m`, its POIs and zones, the origin (for latitude/longitude)."""
    try:
        route = load_route(core)
    except RouteError:
        return None
    every = np.arange(0.0, route.length, spacing_m)
    x, y = np.interp(every, route.s, route.x), np.interp(every, route.s, route.y)
    pois = []
    for poi in route.pois:
        px, py = float(np.interp(poi.s, route.s, route.x)), float(np.interp(poi.s, route.s, route.y))
        pois.append({"name": poi.name, "s": poi.s, "x": round(px, 2), "y": round(py, 2), "actions": list(poi.actions)})
    return {
        "name": route.name,
        "closed": route.closed,
        "length_m": round(route.length, 1),
        "x": [round(float(v), 2) for v in x],
        "y": [round(float(v), 2) for v in y],
        "pois": pois,
        "zones": [{"kind": z.kind, "s_start": z.s_start, "s_end": z.s_end} for z in route.zones],
    }


class ApiServer(AsyncNode):
    """The black box's REST API over HTTPS: records, events, reliability; users for admins."""

    name = "api"
    Params = ApiSettings
    sections = {"blackbox_store": StoreSettings}
    # an operator's re-arm, mission and body commands (blackbox/api/routes/commands.py)
    calls = ("movement/rearm", "mission/goal", "mission/pause", "mission/resume", "mission/cancel", "mission/body")
    # an operator's request for an incident snapshot (POST /vehicles/{id}/snapshots), to the recorder
    snapshot_requests: Output | None = Output(
        "recording/snapshot_request", doc="an operator asks for an incident snapshot"
    )
    # the live gateway's view of every vehicle on the router (blackbox/console/live_hub.py), for the pages
    fleet_inputs = tuple(GATEWAY_TOPICS)

    def setup(self) -> None:
        settings = self.shared["blackbox_store"]
        self.store = open_configured_store(settings)
        real_time = getattr(self.clock, "speed", None) == 1.0
        self.live = LiveHub(
            self.params.live,
            wall_of=(lambda t: self.clock.utc_epoch + t) if real_time else None,
            not_vehicles=self.not_vehicles(),
        )
        for topic in self.fleet_inputs:
            self.bus.subscribe_fleet(topic, self.live.put)
        self.app = self.make_app()
        self.server_cfg = uvicorn_config(self.app, self.params)
        self.server_cfg.timeout_graceful_shutdown = GRACEFUL_SHUTDOWN_S
        self.server = None
        self.log.info("store %s", store_uri(settings))

    def not_vehicles(self) -> frozenset[str]:
        return frozenset()

    def make_app(self):
        """A vehicle's API: its commands to the managers, the live view, its route."""
        return create_app(
            self.store,
            self.params,
            self.core.vehicle_id,
            self.clock,
            call=self.bus.call,
            live=self.live,
            route=route_view(self.core),
            command_key=load_command_key(self.core.commands),
            snapshots_dir=snapshot_files.folder(self.core.recording.snapshots, self.shared["blackbox_store"]),
            request_snapshot=self.snapshot_requests.put
            if self.core.recording.snapshots.enabled and self.snapshot_requests is not None
            else None,
        )

    async def serve(self) -> None:
        import uvicorn

        sock = await self._bind_when_free(self.server_cfg.host, self.server_cfg.port)
        if sock is None:
            return
        self.log.info("REST API on https://%s:%d%s", self.server_cfg.host, self.server_cfg.port, PREFIX)
        self.server = uvicorn.Server(self.server_cfg)
        if self.stopping:  # asked to stop while the server was being made
            sock.close()
            return
        await self.server.serve(sockets=[sock])

    async def _bind_when_free(self, host: str, port: int) -> socket.socket | None:
        """Bind, waiting (heartbeat going) while the port is taken; None if stopped meanwhile."""
        warned = False
        while not self.stopping:
            try:
                return bind(host, port)
            except OSError as exc:
                if not warned:
                    warned = True
                    self.event(
                        "api_port_in_use",
                        f"REST API cannot listen on {host}:{port}: {exc.strerror}; retrying every {PORT_RETRY_S:g} s",
                        EventLevel.WARNING,
                        host=host,
                        port=port,
                    )
            for _ in range(int(PORT_RETRY_S / 0.1)):
                if self.stopping:
                    break
                await asyncio.sleep(0.1)
        return None

    def request_stop(self) -> None:
        super().request_stop()
        if self.server is not None:
            self.server.should_exit = True

    def loop_forever(self) -> None:
        import uvloop

        # uvicorn re-raises the SIGTERM it handled once it has stopped; with a handler of ours in
        # place the process cleans up and exits 0
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, lambda *_: self.request_stop())
        uvloop.run(self.main())

    def teardown(self) -> None:
        store = getattr(self, "store", None)
        if store is not None:
            store.close()


class FleetApiServer(ApiServer):
    """The fleet server's API (fleet process table): every vehicle's black box from the fleet's
    store, and the live view of every vehicle on the fleet router. No commands: a fleet operator's
    calls go through the vehicles' own APIs and managers, and no single route is the fleet's."""

    name = "fleet_api"
    calls = ()
    snapshot_requests = None  # a snapshot is asked of the vehicle's own API
    # and each vehicle's black-box seconds: a vehicle is heard at least once a second, whatever it runs
    fleet_inputs = (*GATEWAY_TOPICS, "blackbox/record")

    @classmethod
    def section(cls) -> str:
        return "api"  # the same settings as a vehicle's API

    def not_vehicles(self) -> frozenset[str]:
        return frozenset({self.core.vehicle_id})  # the fleet server's own processes: their events only

    def make_app(self):
        return create_app(
            self.store,
            self.params,
            self.core.vehicle_id,
            self.clock,
            live=self.live,
            # the vehicles' snapshots as the fleet's black box copies them (a folder per vehicle)
            snapshots_dir=snapshot_files.folder(self.core.recording.snapshots, self.shared["blackbox_store"]),
        )
