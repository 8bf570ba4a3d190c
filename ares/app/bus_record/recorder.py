"""The bus to an MCAP file: every key of the vehicle (or the keys asked for), binary point clouds
included, with a schema per topic, and Foxglove's views of what it can draw.

Each bus key is one *raw* channel, named by its key (`ares/<vehicle_id>/<topic>`), holding the
payloads exactly as they travelled: JSON messages with message encoding `json` and their JSON
schema (`jsonschema`), bulk messages (point clouds, grids) with message encoding `ares.bulk` and a
schema describing the header and arrays (ares/core/schema.py). Replay reads these. Beside them,
the `foxglove/...` channels carry the views of ares.app.bus_record.foxglove_views (protobuf, with
Foxglove's own schemas). A message's log time is when the recorder received it (wall clock, ns),
its publish time its own stamp `t` (stack seconds, in ns); the file keeps the order of receipt.

A LiDAR's sweeps are stored once, compactly. The Velodyne driver's as the packets it received
(`lidar/<name>/packets`; `recording.driver_lidar`), its clouds left out (the file's metadata names
those LiDARs: a replay rebuilds their clouds through the driver's decoder). The simulator's (or the
driver's, by choice) as integers on the sensor's grid (message encoding `ares.cloud-grid`, the
grid in the channel's metadata `ares.grid`; ares.app.bus_record.cloud_payload gives back the
payload byte for byte). A Foxglove preview of each LiDAR every `recording.cloud_view_every_s`.
The light profile keeps only the topics of `recording.light_rates_hz`, each at most at its rate
(by the messages' own stamps), no clouds.

Zenoh's callbacks only queue the payload (bounded in bytes: beyond `max_queued_bytes` a message
is dropped and counted, never waited for); one writer thread decodes what Foxglove needs, writes
and compresses. The file is chunked (zstd) and flushed every `flush_every_s`: closed normally it
ends with MCAP's summary and indexes; cut short by a crash, it is still read up to its last
complete chunk (ares.app.bus_record.mcap_replay reads such a file linearly). The run's
configuration is in the file's metadata (`ares.run`), so a node can be replayed from it alone.
"""

from __future__ import annotations

import json
import logging
import queue
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import orjson
import pydantic
from mcap.writer import CompressionType, Writer

from ares.app.bus_record import cloud_payload
from ares.app.bus_record.foxglove_views import FoxgloveViews, View
from ares.core import cloud_grid, config, messages, schema, topics
from ares.core.config import RecordingSettings
from ares.core.route import Route
from ares.core.schema import MAGIC, BulkMsg, Msg

log = logging.getLogger("ares.app.bus_record.recorder")

RAW_ENCODING_JSON = "json"
RAW_ENCODING_BULK = "ares.bulk"
RUN_METADATA = "ares.run"  # the metadata record holding the run's configuration
TOPIC_META = "ares.topic"  # a raw channel's metadata: its topic and its encoding on the bus
ENCODING_META = "ares.encoding"
STAMP_TOLERANCE_S = 1e-6  # stamps of a 20 Hz topic are 0.05 s apart, give or take a float's rounding
PACKET_LIDARS_META = "clouds_from_packets"  # the LiDARs whose clouds were left to their packets (JSON list)
GRID_META = "ares.grid"  # a compact cloud channel's sensor grid (cloud_grid.Grid.describe)

BATCH_S = 0.05  # the writer wakes this often at most, and writes what came meanwhile
COMPRESSIONS = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}


@dataclass
class RecorderStats:
    messages: int = 0  # raw messages written
    views: int = 0  # Foxglove messages written
    bytes_in: int = 0  # raw payload bytes received
    bytes_stored: int = 0  # raw payload bytes written, before the chunks' compression
    skipped: int = 0  # messages the light profile leaves out (by topic or rate)
    off_grid_points: int = 0  # cloud points kept as float32 (not on their sensor's grid)
    left_to_packets: int = 0  # driver clouds not stored: a replay rebuilds them from the packets
    dropped: int = 0  # messages dropped because the writer was too far behind
    undecodable: int = 0  # payloads with no view (malformed for their topic)
    writer_cpu_s: float = 0.0  # CPU time of the writer thread
    started_wall: float = 0.0
    closed_wall: float = 0.0
    by_topic: dict[str, int] = field(default_factory=dict)
    stored_by_topic: dict[str, int] = field(default_factory=dict)  # bytes written per topic

    def as_dict(self) -> dict[str, Any]:
        return {
            "messages": self.messages,
            "views": self.views,
            "bytes_in": self.bytes_in,
            "bytes_stored": self.bytes_stored,
            "skipped": self.skipped,
            "off_grid_points": self.off_grid_points,
            "left_to_packets": self.left_to_packets,
            "dropped": self.dropped,
            "writer_cpu_s": round(self.writer_cpu_s, 3),
            "wall_s": round(self.closed_wall - self.started_wall, 3),
        }


_STAMP_FIRST = b'{"t":'  # how ares.core.schema encodes every JSON message: its stamp first


def stamp_of(payload: bytes) -> float | None:
    """A payload's own stamp `t` without validating the whole message (None if it has none)."""
    if payload[:5] == _STAMP_FIRST:  # the number up to the next field, not the whole message parsed
        end = payload.find(b",", 5, 40)
        if end < 0:
            end = payload.find(b"}", 5, 40)
        try:
            return float(payload[5:end]) if end > 0 else None
        except ValueError:
            pass  # not a plain number after all: the whole message read below
    try:
        if payload[: len(MAGIC)] == MAGIC:
            head_len = int.from_bytes(payload[4:8], "little")
            value = orjson.loads(payload[8 : 8 + head_len])["fields"].get("t")
        else:
            value = orjson.loads(payload).get("t")
    except (orjson.JSONDecodeError, KeyError, TypeError, AttributeError, ValueError):
        return None
    return float(value) if isinstance(value, (int, float)) else None


def schema_record(msg_schema: type[Msg]) -> tuple[str, bytes, str]:
    """(schema encoding, schema data, message encoding) of a raw channel of this message type."""
    if schema.is_bulk(msg_schema):
        assert issubclass(msg_schema, BulkMsg)
        header = {
            name: pydantic.TypeAdapter(info.annotation).json_schema()
            for name, info in msg_schema.model_fields.items()
            if name not in msg_schema.ARRAYS
        }
        arrays = {
            name: {"dtype": spec.dtype.str, "shape": spec.describe_shape(), "doc": spec.doc}
            for name, spec in msg_schema.ARRAYS.items()
        }
        layout = {
            "layout": 'b"ARB1" | u32 header length | header JSON {"fields", "arrays"} | arrays, each 8-byte aligned',
            "defined_in": "ares/core/schema.py",
            "fields": header,
            "arrays": arrays,
        }
        return RAW_ENCODING_BULK, json.dumps(layout).encode(), RAW_ENCODING_BULK
    return "jsonschema", json.dumps(msg_schema.model_json_schema()).encode(), RAW_ENCODING_JSON


def lidar_grids(cfg: dict[str, Any]) -> dict[str, cloud_grid.Grid]:
    """Each LiDAR's cloud topic and its sensor's grid: the Velodyne driver's calibration where the
    driver decodes the clouds (`--wire`, or a real vehicle), else the simulated sensor's datasheet."""
    try:
        core = config.core(cfg)
    except config.ConfigError:
        return {}  # not a whole run's configuration (a test's, say): clouds stored as they travel
    if cfg.get("wire") or not cfg.get("simulate", True):
        from ares.core.wire.velodyne import load_calibration
        from ares.core.wire.velodyne_grid import VelodyneGrid

        grids: dict[str, cloud_grid.Grid] = {}
        for name, device in core.vehicle_io.lidars.items() if core.vehicle_io is not None else ():
            try:
                grids[f"lidar/{name}/points"] = VelodyneGrid(load_calibration(device.model, device.calibration))
            except (ValueError, OSError) as exc:  # the driver says so too: its clouds stored as they travel
                log.warning("lidar %s: no grid for its clouds (%s)", name, exc)
        return grids
    if core.vehicle_profile is None:
        return {}
    return {
        f"lidar/{name}/points": cloud_grid.SensorGrid(tuple(mount.datasheet().elevations_deg()))
        for name, mount in core.vehicle_profile.lidars.items()
    }


def clouds_from_packets(cfg: dict[str, Any], settings: RecordingSettings) -> list[str]:
    """The LiDARs whose clouds a recording leaves to their packets (`recording.driver_lidar:
    packets`): the Velodyne driver's, which publishes each sensor's packets; a replay rebuilds the
    clouds from them (ares/core/wire/velodyne_packets.py)."""
    if settings.driver_lidar != "packets" or settings.profile == "light":
        return []
    if not (cfg.get("wire") or not cfg.get("simulate", True)):
        return []  # the simulator's clouds: no packets behind them
    try:
        core = config.core(cfg)
    except config.ConfigError:
        return []
    lidars = core.vehicle_io.lidars if core.vehicle_io is not None else {}
    return [name for name in lidars if topics.find(f"lidar/{name}/packets") is not None]  # those the driver reads


def light_rate(settings: RecordingSettings, topic: str) -> float | None:
    """The most the light profile keeps of a topic per second (0: every message); None: not kept."""
    rate = settings.light_rates_hz.get(topic)
    if rate is not None:
        return rate
    for pattern, value in settings.light_rates_hz.items():
        if topics.covers(pattern, topic):
            return value
    return None


class McapRecorder:
    """Records a bus to `path`: attach() to one or more buses, start(), ..., close()."""

    def __init__(
        self,
        path: str | Path,
        cfg: dict[str, Any],
        *,
        utc_epoch: float,
        keys: tuple[str, ...] = ("**",),
        views: FoxgloveViews | None = None,
        route: Route | None = None,
        compression: str = "zstd",
        chunk_size: int = 4 << 20,
        flush_every_s: float = 1.0,
        max_queued_bytes: int = 512 << 20,
        settings: RecordingSettings | None = None,
    ):
        self.path = Path(path)
        self.cfg = cfg
        self.keys = keys
        self.views = views
        self.route = route
        self.utc_epoch = utc_epoch
        self.flush_every_s = flush_every_s
        self.max_queued_bytes = max_queued_bytes
        self.stats = RecorderStats()
        if settings is None:
            try:
                settings = config.core(cfg).recording
            except config.ConfigError:
                settings = RecordingSettings()
        self.settings = settings
        self.light = settings.profile == "light"
        self._grids = lidar_grids(cfg) if settings.cloud_encoding == "grid" and not self.light else {}
        self.packet_lidars = clouds_from_packets(cfg, settings)
        self._unstored = {f"lidar/{name}/points" for name in self.packet_lidars}  # their previews only
        self._rates: dict[str, float | None] = {}  # topic -> its light rate (cached)
        self._last_kept: dict[str, float] = {}  # topic -> stamp of the last message the light profile kept
        self._viewed: dict[str, topics.Topic | None] = {}  # topic -> its table entry if Foxglove views it
        self._last_preview: dict[str, float] = {}  # cloud topic -> stamp of its last Foxglove preview
        self._last_view: dict[str, float] = {}  # other viewed topics -> stamp of their last view
        self._view_every_s = 1.0 / settings.views_max_hz if settings.views_max_hz > 0 else 0.0
        self._compression = COMPRESSIONS[compression]
        self._chunk_size = chunk_size
        self._queue: queue.SimpleQueue[tuple[int, str, str, bytes] | None] = queue.SimpleQueue()
        self._queued_bytes = 0
        self._lock = threading.Lock()
        self._handles: list[object] = []
        self._thread: threading.Thread | None = None
        self._file: IO[bytes] | None = None
        self._writer: Writer | None = None
        self._schemas: dict[str, int] = {}  # schema name -> id
        self._channels: dict[str, int] = {}  # channel topic -> id
        self._error: BaseException | None = None

    # ---- the transport's side: queue and return -------------------------------------------------
    def attach(self, bus: Any) -> None:
        """Subscribe to this recorder's keys on a bus (ares.core.bus.BaseBus.subscribe_raw)."""
        for key in self.keys:
            self._handles.append(bus.subscribe_raw(key, self.offer))

    def offer(self, topic: str, encoding: str, payload: bytes) -> None:
        if self.light and self._light_rate(topic) is None:
            self.stats.skipped += 1  # a topic the light log leaves out: not even queued
            return
        size = len(payload)
        with self._lock:
            if self._queued_bytes + size > self.max_queued_bytes:
                self.stats.dropped += 1
                return
            self._queued_bytes += size
        self._queue.put((time.time_ns(), topic, encoding, payload))

    # ---- the writer thread ------------------------------------------------------------------------
    def start(self, threaded: bool = True) -> McapRecorder:
        """Open the file; with `threaded`, the writer thread that takes what offer() queues (else
        the caller writes, write(), from its own thread: an incident snapshot's)."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = open(self.path, "wb")  # closed by close()
        self._writer = Writer(self._file, chunk_size=self._chunk_size, compression=self._compression)
        self._writer.start(profile="ares", library="ares (mcap python)")
        self._writer.add_metadata(
            RUN_METADATA,
            {
                "vehicle_id": str(self.cfg.get("vehicle_id", "")),
                "utc_epoch": repr(self.utc_epoch),
                "keys": json.dumps(list(self.keys)),
                "profile": self.settings.profile,
                PACKET_LIDARS_META: json.dumps(self.packet_lidars),
                "config": json.dumps(self.cfg),
            },
        )
        self._file.flush()
        self.stats.started_wall = time.monotonic()
        if self.views is not None and self.route is not None:
            self._write_view(self.views.route_view(self.route), time.time_ns())
        if threaded:
            self._thread = threading.Thread(target=self._run, name="mcap-writer", daemon=True)
            self._thread.start()
        return self

    def _run(self) -> None:
        started_cpu = time.thread_time()
        next_flush = time.monotonic() + self.flush_every_s
        try:
            while True:
                try:
                    batch = [self._queue.get(timeout=self.flush_every_s)]
                except queue.Empty:
                    batch = []
                while True:  # what else is queued, in one go
                    try:
                        batch.append(self._queue.get_nowait())
                    except queue.Empty:
                        break
                if self._write_batch(batch):
                    break
                if time.monotonic() >= next_flush:
                    assert self._file is not None
                    self._file.flush()
                    next_flush = time.monotonic() + self.flush_every_s
                # woken once per batch, not once per message (~1,400 a second with three LiDARs)
                time.sleep(BATCH_S)
        except BaseException as exc:  # the file stays readable up to here; the run goes on
            self._error = exc
            log.exception("MCAP recording to %s stopped", self.path)
        finally:
            self.stats.writer_cpu_s = time.thread_time() - started_cpu

    def _write_batch(self, batch: list[tuple[int, str, str, bytes] | None]) -> bool:
        """Write the batch; True when it held the end (close())."""
        for item in batch:
            if item is None:
                return True
            with self._lock:
                self._queued_bytes -= len(item[3])
            self.write(*item)
        return False

    def write(self, log_time: int, topic: str, encoding: str, payload: bytes) -> None:
        """One bus message into the file (the writer thread's, or the caller's without one)."""
        assert self._writer is not None
        stamp = stamp_of(payload)
        self.stats.bytes_in += len(payload)
        if self.light and not self._light_keeps(topic, stamp, log_time):
            self.stats.skipped += 1
            return
        if topic in self._unstored:
            self.stats.left_to_packets += 1
        else:
            self._store(log_time, topic, encoding, payload, stamp)
        if self.views is not None:
            self._view(log_time, topic, payload, stamp)

    def _store(self, log_time: int, topic: str, encoding: str, payload: bytes, stamp: float | None) -> None:
        assert self._writer is not None
        key = f"ares/{self.cfg.get('vehicle_id', '')}/{topic}"
        channel = self._channels.get(key)
        if channel is None:
            channel = self._raw_channel(key, topic, encoding)
        publish_ns = int(round(stamp * 1e9)) if stamp is not None and stamp >= 0 else log_time
        grid = self._grids.get(topic)
        stored = payload
        if grid is not None:
            stored, off_grid = cloud_payload.compact(payload, grid)
            self.stats.off_grid_points += off_grid
        self._writer.add_message(channel, log_time=log_time, data=stored, publish_time=publish_ns)
        self.stats.messages += 1
        self.stats.bytes_stored += len(stored)
        self.stats.by_topic[topic] = self.stats.by_topic.get(topic, 0) + 1
        self.stats.stored_by_topic[topic] = self.stats.stored_by_topic.get(topic, 0) + len(stored)

    def _view(self, log_time: int, topic: str, payload: bytes, stamp: float | None) -> None:
        """The message's Foxglove view, when its topic has one and one is due."""
        assert self.views is not None
        entry = self._viewed.get(topic, False)
        if entry is False:
            found = topics.find(topic)
            entry = self._viewed[topic] = found if found is not None and self.views.handles(found.schema) else None
        if entry is None:
            return
        if entry.schema is messages.PointCloud:
            every = self.settings.cloud_view_every_s or None  # 0: no previews
            if not self._due(self._last_preview, every, topic, stamp, log_time):
                return
        elif not self._due(self._last_view, self._view_every_s, topic, stamp, log_time):
            return
        try:
            msg = schema.decode(payload, entry.schema)
        except ValueError:  # pydantic's ValidationError and BulkDecodeError are ValueErrors
            self.stats.undecodable += 1
            return
        if isinstance(msg, messages.PointCloud):
            views = self.views.cloud_preview(topic, msg, self.settings.cloud_view_stride)
        else:
            views = self.views.views(topic, msg)
        for view in views:
            self._write_view(view, log_time)

    def _light_rate(self, topic: str) -> float | None:
        if topic not in self._rates:
            self._rates[topic] = light_rate(self.settings, topic)
        return self._rates[topic]

    def _light_keeps(self, topic: str, stamp: float | None, log_time: int) -> bool:
        """Whether the light profile keeps this message: at most its topic's rate (0: every one)."""
        rate = self._light_rate(topic)
        every = None if rate is None else (1.0 / rate if rate > 0 else 0.0)
        return self._due(self._last_kept, every, topic, stamp, log_time)

    @staticmethod
    def _due(
        last_by_topic: dict[str, float], every: float | None, topic: str, stamp: float | None, log_time: int
    ) -> bool:
        """Whether a message of this topic is due: `every` seconds after the last kept (0: every
        message; None: never), by the messages' own stamps (the receipt's time if it has none); a
        stamp gone back (a clock jump) starts the count again."""
        if every is None:
            return False
        if every <= 0:
            return True
        now = stamp if stamp is not None else log_time / 1e9
        last = last_by_topic.get(topic)
        if last is not None and last <= now < last + every - STAMP_TOLERANCE_S:
            return False
        last_by_topic[topic] = now
        return True

    def _raw_channel(self, key: str, topic: str, encoding: str) -> int:
        assert self._writer is not None
        entry = topics.find(topic)
        _, _, schema_name = encoding.partition(";")
        if entry is not None:
            schema_name = entry.schema.schema_name()
            schema_id = self._schemas.get(schema_name)
            if schema_id is None:
                schema_encoding, data, message_encoding = schema_record(entry.schema)
                schema_id = self._schemas[schema_name] = self._writer.register_schema(
                    schema_name, schema_encoding, data
                )
            else:
                message_encoding = RAW_ENCODING_BULK if schema.is_bulk(entry.schema) else RAW_ENCODING_JSON
        else:  # a key the topic table does not know: kept, without a schema
            schema_id, message_encoding = 0, encoding.partition(";")[0] or "application/octet-stream"
        metadata = {TOPIC_META: topic, ENCODING_META: encoding}
        grid = self._grids.get(topic)
        if grid is not None:  # restored to the bulk payload its schema describes (cloud_payload.restore)
            message_encoding = cloud_payload.ENCODING
            metadata[GRID_META] = json.dumps(grid.describe())
        channel = self._channels[key] = self._writer.register_channel(
            key, message_encoding, schema_id, metadata=metadata
        )
        return channel

    def _write_view(self, view: View, log_time: int) -> None:
        assert self._writer is not None
        channel = self._channels.get(view.topic)
        if channel is None:
            name = view.schema.name
            schema_id = self._schemas.get(name)
            if schema_id is None:
                schema_id = self._schemas[name] = self._writer.register_schema(
                    name, view.schema.encoding, bytes(view.schema.data)
                )
            channel = self._channels[view.topic] = self._writer.register_channel(view.topic, "protobuf", schema_id)
        self._writer.add_message(channel, log_time=log_time, data=view.data, publish_time=log_time)
        self.stats.views += 1

    # ---- the end ------------------------------------------------------------------------------------
    def detach(self, bus: Any) -> None:
        for handle in self._handles:
            try:
                bus._undeclare(handle)
            except Exception:  # the bus may be closed already
                pass
        self._handles = []

    def close(self, timeout_s: float = 120.0) -> RecorderStats:
        """Write what is queued, then the summary and indexes; idempotent."""
        if self._thread is not None:
            self._queue.put(None)
            self._thread.join(timeout_s)
            if self._thread.is_alive():
                log.error("MCAP writer still busy after %.0f s: %s left without its summary", timeout_s, self.path)
                return self.stats
            self._thread = None
        if self._writer is not None and self._file is not None:
            if self._error is None:
                self._writer.finish()
            self._file.close()
            self._writer = None
            self.stats.closed_wall = time.monotonic()
        return self.stats
