"""An MCAP recording of the bus read back: what it holds (`info`), played into a bus (`play`), or its
messages fed to the replay of one node (`replay_node`: ares.core.bus_replay rebuilds the node's
steps from them and the replay engine, ares.core.replay, compares its outputs with the recorded ones).

The file is read from start to end, record by record (mcap's StreamReader): a recording whose
writer was killed has no summary and may end in the middle of a record; it is read up to its last
complete chunk, and `Recording.complete` says whether it ended properly.
"""

from __future__ import annotations

import json
import logging
import struct
import threading
import time
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Message, Metadata, Schema
from mcap.stream_reader import StreamReader

from ares.app import processes
from ares.app.bus_record import cloud_payload
from ares.app.bus_record.recorder import ENCODING_META, GRID_META, PACKET_LIDARS_META, RUN_METADATA, TOPIC_META
from ares.core import cloud_grid, config, schema, topics
from ares.core.bus import BaseBus, encoding_name
from ares.core.bus_replay import BusReplayResult, replay_from_bus
from ares.core.messages import LidarPackets, PointCloud
from ares.core.recording import as_record
from ares.core.replay import Mismatch, mismatches
from ares.core.wire.velodyne_packets import PacketDecoder
from drivers.velodyne_node import VelodyneDriver

log = logging.getLogger("ares.app.bus_record.replay")


@dataclass(frozen=True)
class Recorded:
    """One raw bus message of a recording."""

    topic: str
    encoding: str
    payload: bytes
    log_time: int  # ns, wall clock, when the recorder received it
    stamp: float  # its own `t`, stack seconds


@dataclass
class ChannelInfo:
    topic: str
    schema: str
    schema_encoding: str
    message_encoding: str
    messages: int = 0
    bytes: int | None = 0  # None: not counted (read from the file's summary)


@dataclass
class Recording:
    path: Path
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    complete: bool = False  # ended with its footer (closed properly)
    cut_short: str | None = None  # why reading stopped early

    @property
    def run(self) -> dict[str, str]:
        if RUN_METADATA not in self.metadata:
            raise ValueError(f"{self.path}: no {RUN_METADATA!r} metadata: not a recording of `ares record`")
        return self.metadata[RUN_METADATA]

    @property
    def cfg(self) -> dict[str, Any]:
        return dict(json.loads(self.run["config"]))

    def records(self) -> Iterator[tuple[Schema | None, Channel, Message]]:
        """Every message of the file in file order, with its channel and schema; metadata on the way."""
        schemas: dict[int, Schema] = {}
        channels: dict[int, Channel] = {}
        self.complete, self.cut_short = False, None
        with open(self.path, "rb") as f:
            reader = StreamReader(f, skip_magic=False)
            try:
                for record in reader.records:
                    if isinstance(record, Message):
                        channel = channels.get(record.channel_id)
                        if channel is not None:
                            yield schemas.get(channel.schema_id), channel, record
                    elif isinstance(record, Channel):
                        channels[record.id] = record
                    elif isinstance(record, Schema):
                        schemas[record.id] = record
                    elif isinstance(record, Metadata):
                        self.metadata[record.name] = dict(record.metadata)
                self.complete = True
            except (McapError, EOFError, ValueError, OSError, struct.error) as exc:  # a file cut short by a crash
                self.cut_short = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
                log.warning("%s: cut short (%s): read up to its last complete record", self.path, self.cut_short)

    def messages(self, rebuild: bool = True) -> Iterator[Recorded]:
        """The raw bus messages (not the Foxglove views), in the order the recorder received them,
        each payload as it travelled (a compact cloud restored on its sensor's grid), and the clouds
        of the LiDARs whose packets were kept in their place, rebuilt through the driver's decoder
        right after the packets that finished them."""
        grids: dict[int, cloud_grid.Grid | None] = {}
        packet_clouds: PacketClouds | None = None
        for _schema, channel, message in self.records():
            topic = channel.metadata.get(TOPIC_META)
            if topic is None:
                continue
            payload = message.data
            if channel.message_encoding == cloud_payload.ENCODING:
                if channel.id not in grids:
                    grids[channel.id] = _grid_of(channel)
                payload = cloud_payload.restore(payload, grids[channel.id])
            recorded = Recorded(
                topic, channel.metadata.get(ENCODING_META, ""), payload, message.log_time, message.publish_time / 1e9
            )
            yield recorded
            if rebuild and topic.endswith("/packets"):
                packet_clouds = packet_clouds or PacketClouds(self)
                yield from packet_clouds.clouds(recorded)

    @property
    def packet_lidars(self) -> list[str]:
        """The LiDARs whose clouds the recorder left to their packets."""
        return list(json.loads(self.metadata.get(RUN_METADATA, {}).get(PACKET_LIDARS_META, "[]")))


class PacketClouds:
    """The clouds of a recording's packet LiDARs, rebuilt from their packets by the decoder the
    driver used (ares/core/wire/velodyne_packets.py), as the driver's configuration in the run set it."""

    def __init__(self, recording: Recording):
        self.decoders: dict[str, PacketDecoder] = {}
        self.undecodable = 0
        lidars = recording.packet_lidars
        if not lidars:
            return
        cfg = recording.cfg
        core = config.core(cfg)
        params = config.section(cfg, VelodyneDriver.section(), VelodyneDriver.Params)
        devices = core.vehicle_io.lidars if core.vehicle_io is not None else {}
        for name in lidars:
            if name in devices:
                self.decoders[f"lidar/{name}/packets"] = PacketDecoder(name, devices[name], params.truncated_below_deg)
        self.encoding = encoding_name(PointCloud)

    def clouds(self, recorded: Recorded) -> Iterator[Recorded]:
        decoder = self.decoders.get(recorded.topic)
        if decoder is None:
            return
        try:
            packets = schema.decode(recorded.payload, LidarPackets)
        except ValueError:
            self.undecodable += 1
            log.warning("%s: a packets message that does not decode: its clouds are lost", recorded.topic)
            return
        for cloud in decoder.feed(packets):
            yield Recorded(
                f"lidar/{decoder.sensor}/points", self.encoding, bytes(schema.encode(cloud)), recorded.log_time, cloud.t
            )


def _grid_of(channel: Channel) -> cloud_grid.Grid | None:
    try:
        return cloud_payload.grid_from(json.loads(channel.metadata[GRID_META]))
    except (KeyError, ValueError, TypeError, AttributeError):
        log.warning("%s: a compact cloud channel without a readable grid", channel.topic)
        return None


def open_recording(path: str | Path) -> Recording:
    """A recording, its metadata read (the run's configuration is written first)."""
    recording = Recording(Path(path))
    if not recording.path.exists():
        raise ValueError(f"{path}: no such file")
    for _ in recording.records():
        if RUN_METADATA in recording.metadata:
            break
    return recording


def info(path: str | Path) -> dict[str, Any]:
    """Channels (topic, schema, encodings, messages, bytes), span and whether the file is complete:
    from the summary of a file that has one (bytes per channel then unknown: None), else by reading
    it through."""
    summarised = _info_from_summary(Path(path))
    if summarised is not None:
        return summarised
    recording = Recording(Path(path))
    found: dict[int, ChannelInfo] = {}
    first = last = None
    for sch, channel, message in recording.records():
        entry = found.get(channel.id)
        if entry is None:
            entry = found[channel.id] = ChannelInfo(
                channel.topic,
                sch.name if sch is not None else "",
                sch.encoding if sch is not None else "",
                channel.message_encoding,
            )
        entry.messages += 1
        entry.bytes += len(message.data)
        first = message.log_time if first is None else min(first, message.log_time)
        last = message.log_time if last is None else max(last, message.log_time)
    return {
        "file": str(path),
        "size_bytes": Path(path).stat().st_size,
        "complete": recording.complete,
        "cut_short": recording.cut_short,
        "vehicle_id": recording.metadata.get(RUN_METADATA, {}).get("vehicle_id"),
        "messages": sum(c.messages for c in found.values()),
        "duration_s": round((last - first) / 1e9, 3) if first is not None and last is not None else 0.0,
        "channels": [vars(c) for c in sorted(found.values(), key=lambda c: c.topic)],
    }


def _info_from_summary(path: Path) -> dict[str, Any] | None:
    try:
        with open(path, "rb") as f:
            reader = make_reader(f)
            summary = reader.get_summary()
            metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()} if summary is not None else {}
    except (McapError, EOFError, ValueError, OSError):
        return None  # cut short: no summary to read
    if summary is None or summary.statistics is None:
        return None
    stats = summary.statistics
    channels = []
    for channel in summary.channels.values():
        sch = summary.schemas.get(channel.schema_id)
        channels.append(
            vars(
                ChannelInfo(
                    channel.topic,
                    sch.name if sch is not None else "",
                    sch.encoding if sch is not None else "",
                    channel.message_encoding,
                    stats.channel_message_counts.get(channel.id, 0),
                    None,
                )
            )
        )
    return {
        "file": str(path),
        "size_bytes": path.stat().st_size,
        "complete": True,
        "cut_short": None,
        "vehicle_id": metadata.get(RUN_METADATA, {}).get("vehicle_id"),
        "messages": stats.message_count,
        "duration_s": round((stats.message_end_time - stats.message_start_time) / 1e9, 3),
        "channels": sorted(channels, key=lambda c: c["topic"]),
    }


# ---- playing a recording into a bus ---------------------------------------------------------------


def play(
    recording: Recording, bus: BaseBus, speed: float | None = 1.0, stop: threading.Event | None = None
) -> dict[str, int]:
    """Publish the recorded messages on `bus`, in their order, paced by their own stamps (stack
    seconds) divided by `speed`, or as fast as they go (`speed` None). Returns messages per topic."""
    stop = stop or threading.Event()
    sent: dict[str, int] = {}
    anchor: tuple[float, float] | None = None  # (wall, stamp) of the first message
    for rec in recording.messages():
        if stop.is_set():
            break
        entry = topics.find(rec.topic)
        if entry is None or entry.is_pattern and "*" in rec.topic:
            continue
        if speed is not None:
            if anchor is None:
                anchor = (time.monotonic(), rec.stamp)
            due = anchor[0] + (rec.stamp - anchor[1]) / speed
            wait = due - time.monotonic()
            if wait > 0 and stop.wait(wait):
                break
        try:
            msg = schema.decode(rec.payload, entry.schema)
        except ValueError:
            continue
        bus.publisher(rec.topic).put(msg)
        sent[rec.topic] = sent.get(rec.topic, 0) + 1
    return sent


# ---- one node against its recorded outputs ----------------------------------------------------------


def replay_node(path: str | Path, node_name: str, max_mismatches: int = 20) -> BusReplayResult:
    """Feed one node the recorded bus and compare what it publishes with what it published
    (ares.core.bus_replay: its steps rebuilt from the recording); the LiDAR driver's decoding
    from its recorded packets (`replay_driver`)."""
    recording = open_recording(path)
    if node_name == VelodyneDriver.name:
        return replay_driver(recording, max_mismatches)
    cfg = recording.cfg
    try:
        spec = processes.by_name(node_name, wire=bool(cfg.get("wire")))
    except KeyError as exc:
        raise ValueError(exc.args[0]) from None
    result = replay_from_bus(recording.messages(), spec.node_class(), cfg, node_name, max_mismatches)
    if recording.cut_short:
        log.warning("%s: replayed up to where the recording was cut short", path)
    return result


def replay_driver(recording: Recording, max_mismatches: int = 20) -> BusReplayResult:
    """The LiDAR driver's decoding replayed: its recorded packets through the decoder it used, each
    cloud made compared with the one it published, sensor by sensor in order (a recording with
    `recording.driver_lidar: both`). Its sockets are not replayed: what they gave it is the packets.
    A cloud made from the last packets of a recording cut short before it was published is not a
    mismatch (`unrecorded_steps`)."""
    cfg = recording.cfg
    core = config.core(cfg)
    params = config.section(cfg, VelodyneDriver.section(), VelodyneDriver.Params)
    devices = core.vehicle_io.lidars if core.vehicle_io is not None else {}
    decoders = {f"lidar/{n}/packets": PacketDecoder(n, d, params.truncated_below_deg) for n, d in devices.items()}
    result = BusReplayResult(node=VelodyneDriver.name, steps=0, outputs=0)
    made: dict[str, deque[tuple[float, Any]]] = {}  # cloud topic -> clouds made, not yet compared
    published: dict[str, deque[Any]] = {}  # cloud topic -> clouds published, not yet compared
    compared = 0
    for rec in recording.messages(rebuild=False):
        decoder = decoders.get(rec.topic)
        if decoder is not None:
            result.steps += 1
            for cloud in decoder.feed(schema.decode(rec.payload, LidarPackets)):
                made.setdefault(f"lidar/{decoder.sensor}/points", deque()).append(
                    (cloud.t, as_record(schema.encode(cloud)))
                )
        elif rec.topic.endswith("/points") and f"{rec.topic[: -len('/points')]}/packets" in decoders:
            published.setdefault(rec.topic, deque()).append(as_record(rec.payload))
        else:
            continue
        for topic, queue in published.items():
            while queue and made.get(topic):
                t, got = made[topic].popleft()
                if len(result.mismatches) < max_mismatches:
                    result.mismatches += mismatches(compared, t, [[topic, queue.popleft()]], [[topic, got]])
                else:
                    queue.popleft()
                result.outputs += 1
                compared += 1
    if result.steps == 0:
        raise ValueError(f"{recording.path}: no LiDAR packets recorded (recording.driver_lidar: clouds, or no driver)")
    if compared == 0:
        raise ValueError(
            f"{recording.path}: the driver's packets are recorded, its clouds are not "
            "(recording.driver_lidar: packets): record with `both` to compare its decoding with what it published"
        )
    for topic, queue in published.items():
        if queue:  # published, never made again
            result.mismatches.append(Mismatch(compared, None, f"{topic}: clouds", len(queue), 0))
    result.unrecorded_steps = sum(len(queue) for queue in made.values())
    return result
