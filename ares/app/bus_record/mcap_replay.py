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
from ares.app.bus_record.recorder import ENCODING_META, GRID_META, RUN_METADATA, TOPIC_META
from ares.core import cloud_grid, schema, topics
from ares.core.bus import BaseBus
from ares.core.bus_replay import BusReplayResult, replay_from_bus

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

    def messages(self) -> Iterator[Recorded]:
        """The raw bus messages (not the Foxglove views), in the order the recorder received them,
        each payload as it travelled (a compact cloud restored on its sensor's grid)."""
        grids: dict[int, cloud_grid.Grid | None] = {}
        for _schema, channel, message in self.records():
            topic = channel.metadata.get(TOPIC_META)
            if topic is None:
                continue
            payload = message.data
            if channel.message_encoding == cloud_payload.ENCODING:
                if channel.id not in grids:
                    grids[channel.id] = _grid_of(channel)
                payload = cloud_payload.restore(payload, grids[channel.id])
            yield Recorded(
                topic, channel.metadata.get(ENCODING_META, ""), payload, message.log_time, message.publish_time / 1e9
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
    (ares.core.bus_replay: its steps rebuilt from the recording)."""
    recording = open_recording(path)
    cfg = recording.cfg
    try:
        spec = processes.by_name(node_name, wire=bool(cfg.get("wire")))
    except KeyError as exc:
        raise ValueError(exc.args[0]) from None
    result = replay_from_bus(recording.messages(), spec.node_class(), cfg, node_name, max_mismatches)
    if recording.cut_short:
        log.warning("%s: replayed up to where the recording was cut short", path)
    return result
