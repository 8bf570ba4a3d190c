"""The live bus served to Foxglove over its WebSocket protocol (foxglove-sdk): `ares run --foxglove`.

Every JSON topic of the vehicle is a channel of its own (its key, message encoding `json`, the
message's JSON schema), and the views Foxglove draws (ares.app.bus_record.foxglove_views: the pose
on a map and in 3-D, the clouds, the grid, the plan) are channels under `foxglove/`. Bulk payloads
are served only as their views.

It is a viewer, not a recorder: Zenoh's callbacks keep the latest payload of each key and return;
one worker thread converts and logs what is new, so a slow viewer sees fewer messages, never slows
the stack. A point cloud or the grid is converted only while a client is subscribed to its view.
The server binds to 127.0.0.1 unless told otherwise: the bus is the vehicle's inside.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from typing import Any

import foxglove
from foxglove.websocket import ChannelView, Client

from ares.app.bus_record.foxglove_views import SCHEMAS, FoxgloveViews, View
from ares.core import schema, topics
from ares.core.route import Route

log = logging.getLogger("ares.app.bus_record.live")

DEFAULT_HOST = "127.0.0.1"  # the bus is the vehicle's inside
DEFAULT_PORT = 8765
ROUTE_REPEAT_S = 5.0  # the route is re-sent now and then for viewers that connect later


class _Subscriptions:
    """Which channels Foxglove's clients are subscribed to (foxglove.websocket.ServerListener)."""

    def __init__(self) -> None:
        self.topics: dict[str, int] = {}
        self._lock = threading.Lock()

    def on_subscribe(self, client: Client, channel: ChannelView) -> None:
        with self._lock:
            self.topics[channel.topic] = self.topics.get(channel.topic, 0) + 1

    def on_unsubscribe(self, client: Client, channel: ChannelView) -> None:
        with self._lock:
            left = self.topics.get(channel.topic, 0) - 1
            if left > 0:
                self.topics[channel.topic] = left
            else:
                self.topics.pop(channel.topic, None)

    def wanted(self, topic: str) -> bool:
        return topic in self.topics


class FoxgloveBridge:
    def __init__(
        self,
        cfg: dict[str, Any],
        *,
        utc_epoch: float,
        host: str = DEFAULT_HOST,
        port: int = DEFAULT_PORT,
        route: Route | None = None,
    ):
        self.cfg = cfg
        self.views = FoxgloveViews(cfg, utc_epoch)
        self.route = route
        self.context = foxglove.Context()
        self.subscriptions = _Subscriptions()
        self.server = foxglove.start_server(
            name=f"ARES {cfg.get('vehicle_id', '')}",
            host=host,
            port=port,
            context=self.context,
            server_listener=self.subscriptions,
        )
        self.port = self.server.port
        self.logged = 0
        self._latest: dict[str, tuple[str, bytes]] = {}
        self._lock = threading.Lock()
        self._news = threading.Event()
        self._stop = threading.Event()
        self._channels: dict[str, foxglove.Channel] = {}
        self._handles: list[object] = []
        # the views' channels exist from the start, so a client can subscribe before the first message
        for topic, name in [
            ("foxglove/tf", "FrameTransforms"),
            ("foxglove/pose/location", "LocationFix"),
            ("foxglove/gnss/location", "LocationFix"),
            ("foxglove/perception/grid", "Grid"),
            ("foxglove/path/ahead", "SceneUpdate"),
            ("foxglove/control/mpc/trajectory", "SceneUpdate"),
            ("foxglove/obstacle/area", "SceneUpdate"),
            ("foxglove/route", "SceneUpdate"),
            *((f"foxglove/{frame}/points", "PointCloud") for frame in self.views.lidar_frames),
        ]:
            self._channel(topic, SCHEMAS[name], "protobuf")
        self._thread = threading.Thread(target=self._run, name="foxglove-bridge", daemon=True)

    def attach(self, bus: Any) -> FoxgloveBridge:
        self._handles.append(bus.subscribe_raw("**", self._offer))
        self._thread.start()
        return self

    def _offer(self, topic: str, encoding: str, payload: bytes) -> None:  # a transport thread
        with self._lock:
            self._latest[topic] = (encoding, payload)
        self._news.set()

    def _channel(self, topic: str, fg_schema: foxglove.Schema, encoding: str) -> foxglove.Channel:
        channel = self._channels.get(topic)
        if channel is None:
            channel = self._channels[topic] = foxglove.Channel(
                topic, schema=fg_schema, message_encoding=encoding, context=self.context
            )
        return channel

    def _log_view(self, view: View) -> None:
        self._channel(view.topic, view.schema, "protobuf").log(view.data)
        self.logged += 1

    def _run(self) -> None:
        route_sent = -ROUTE_REPEAT_S
        while not self._stop.is_set():
            self._news.wait(0.5)
            self._news.clear()
            if self.route is not None and time.monotonic() - route_sent >= ROUTE_REPEAT_S:
                self._log_view(self.views.route_view(self.route))
                route_sent = time.monotonic()
            with self._lock:
                latest, self._latest = self._latest, {}
            for topic, (_encoding, payload) in latest.items():
                try:
                    self._forward(topic, payload)
                except Exception:  # one bad message must not end the viewer
                    log.exception("Foxglove bridge: %s", topic)

    def _forward(self, topic: str, payload: bytes) -> None:
        entry = topics.find(topic)
        if entry is None:
            return
        bulk = schema.is_bulk(entry.schema)
        if not bulk:
            key = f"ares/{self.cfg.get('vehicle_id', '')}/{topic}"
            channel = self._channels.get(key)
            if channel is None:
                json_schema = foxglove.Schema(
                    name=entry.schema.schema_name(),
                    encoding="jsonschema",
                    data=json.dumps(entry.schema.model_json_schema()).encode(),
                )
                channel = self._channel(key, json_schema, "json")
            channel.log(payload)
            self.logged += 1
        if not self.views.handles(entry.schema) or (bulk and not self.subscriptions.wanted(f"foxglove/{topic}")):
            return
        try:
            msg = schema.decode(payload, entry.schema)
        except ValueError:
            return
        for view in self.views.views(topic, msg):
            self._log_view(view)

    def close(self, bus: Any = None) -> None:
        self._stop.set()
        self._news.set()
        if self._thread.is_alive():
            self._thread.join(5.0)
        if bus is not None:
            for handle in self._handles:
                try:
                    bus._undeclare(handle)
                except Exception:
                    pass
        self.server.stop()
