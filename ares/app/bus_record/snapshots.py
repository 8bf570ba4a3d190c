"""Incident snapshots: the last seconds of the whole bus kept in a bounded ring in memory, saved
with the seconds after when something happens, as an MCAP file an auditor downloads from the black
box (docs/recording.md).

A thread of `ares run`'s process, on the supervisor's session, like the recorder: Zenoh's
callbacks only queue; one worker keeps the ring (by the messages' own stamps, `before_s` stack
seconds, and at most `max_ring_mb`: beyond, the oldest go, and a snapshot then covers less,
which its event says) and watches the events. Each event that matches a trigger
(`recording.snapshots.triggers`: an emergency stop, a manual takeover, a level-1 awareness event,
a controller switch to stop) and each request on `recording/snapshot_request` (`ares snapshot`)
starts one snapshot: the ring from `before_s` before the event's stamp, then everything up to
`after_s` after it. One saver thread writes the snapshots one after the other (as a full
recording: clouds on their grid) to a temporary name, renamed when complete, and announces each
on the bus with a `snapshot` event (the file's name, the cause, the window), which the black box
stores beside the event that caused it; a snapshot that cannot be written (a full disk) is a
`snapshot_failed` warning, its partial file removed. Snapshots older than the retention go.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
import uuid
from collections import deque
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import orjson

from ares.app.bus_record.foxglove_views import FoxgloveViews
from ares.app.bus_record.recorder import McapRecorder, stamp_of
from ares.core import config
from ares.core.config import SnapshotSettings, SnapshotTrigger
from ares.core.messages import Event, EventLevel
from ares.core.route import Route
from blackbox.register import snapshot_files

log = logging.getLogger("ares.app.bus_record.snapshots")

REQUEST_TOPIC = "recording/snapshot_request"
EVENT_KIND = "snapshot"
FAILED_KIND = "snapshot_failed"
SOURCE = "recorder"


@dataclass(frozen=True)
class Item:
    log_time: int
    topic: str
    encoding: str
    payload: bytes
    stamp: float


@dataclass
class Pending:
    cause: str  # the event's kind, or "request"
    cause_t: float
    until_t: float
    number: int
    detail: str  # the event's message, or the request's reason
    request_id: str = ""
    ring_short: bool = False  # the ring had lost some of the seconds before (its bound in memory)
    items: list[Item] = field(default_factory=list)
    also: list[tuple[str, float]] = field(default_factory=list)  # later triggers it covers: (kind, stamp)


@dataclass
class KeeperStats:
    ring_bytes: int = 0
    evicted_early: int = 0  # messages the memory bound removed while still within before_s
    triggered: int = 0
    saved: int = 0
    failed: int = 0
    pruned: int = 0
    ring_cpu_s: float = 0.0  # CPU time of the thread keeping the ring and watching the events
    saver_cpu_s: float = 0.0  # ... of the thread writing the snapshots
    saved_files: list[str] = field(default_factory=list)


def matches(trigger: SnapshotTrigger, kind: str, data: dict[str, Any]) -> bool:
    return (
        kind == trigger.kind
        and all(data.get(key) == value for key, value in trigger.where.items())
        and not any(data.get(key) == value for key, value in trigger.unless.items())
    )


class SnapshotKeeper:
    """attach(bus), start(), ..., close(): snapshots of `bus` into `folder`."""

    def __init__(
        self,
        cfg: dict[str, Any],
        settings: SnapshotSettings,
        folder: Path,
        *,
        utc_epoch: float,
        route: Route | None = None,
    ):
        self.cfg = cfg
        self.settings = settings
        self.folder = folder
        self.utc_epoch = utc_epoch
        self.route = route
        self.vehicle_id = str(cfg.get("vehicle_id", ""))
        self.stats = KeeperStats()
        self._recording = config.core(cfg).recording.model_copy(update={"profile": "full"})
        self._max_ring_bytes = int(settings.max_ring_mb * 1e6)
        self._inbox: queue.SimpleQueue[tuple[int, str, str, bytes] | None] = queue.SimpleQueue()
        self._ring: deque[Item] = deque()
        self._pending: list[Pending] = []
        self._to_save: queue.SimpleQueue[Pending | None] = queue.SimpleQueue()
        self._latest_stamp = 0.0
        self._first_stamp: float | None = None
        self._number = 0
        self._bus: Any = None
        self._handles: list[object] = []
        self._threads: list[threading.Thread] = []

    # ---- the transport's side -----------------------------------------------------------------------
    def attach(self, bus: Any) -> None:
        self._bus = bus
        self._handles.append(bus.subscribe_raw("**", self.offer))

    def offer(self, topic: str, encoding: str, payload: bytes) -> None:
        self._inbox.put((time.time_ns(), topic, encoding, payload))

    # ---- the worker: the ring and the triggers ------------------------------------------------------
    def start(self) -> SnapshotKeeper:
        self.folder.mkdir(parents=True, exist_ok=True)
        self.stats.pruned += len(snapshot_files.prune(self.folder, self.settings.retention_days))
        for target, name in ((self._keep, "snapshot-ring"), (self._save_all, "snapshot-saver")):
            thread = threading.Thread(target=target, name=name, daemon=True)
            thread.start()
            self._threads.append(thread)
        return self

    def _keep(self) -> None:
        started = time.thread_time()
        try:
            self._keep_until_closed()
        finally:
            self.stats.ring_cpu_s = time.thread_time() - started

    def _keep_until_closed(self) -> None:
        # a snapshot waits for its seconds after by the stack's clock: if that clock stands still (a
        # lockstep waiting for a process), so does the snapshot, and the end of the run saves it
        while True:
            raw = self._inbox.get()
            if raw is None:
                break
            self.take(*raw)
        for pending in self._pending:  # the run ended: what came is what they cover
            self._to_save.put(pending)
        self._pending = []
        self._to_save.put(None)

    def take(self, log_time: int, topic: str, encoding: str, payload: bytes) -> None:
        """One message into the ring and the snapshots under way; a trigger starts one."""
        stamp = stamp_of(payload)
        if stamp is None or stamp < 0:
            stamp = self._latest_stamp
        self._latest_stamp = max(self._latest_stamp, stamp)
        if self._first_stamp is None:
            self._first_stamp = stamp
        item = Item(log_time, topic, encoding, payload, stamp)
        self._ring.append(item)
        self.stats.ring_bytes += len(payload)
        self._evict()
        for pending in self._pending:
            pending.items.append(item)
        if topic == "events":
            self._on_event(payload, stamp)
        elif topic == REQUEST_TOPIC:
            self._on_request(payload, stamp)
        self._save_finished()

    def _evict(self) -> None:
        horizon = self._latest_stamp - self.settings.before_s - self.settings.after_s
        ring = self._ring
        while ring and (self.stats.ring_bytes > self._max_ring_bytes or ring[0].stamp < horizon):
            gone = ring.popleft()
            self.stats.ring_bytes -= len(gone.payload)
            if gone.stamp >= self._latest_stamp - self.settings.before_s:
                self.stats.evicted_early += 1

    def _on_event(self, payload: bytes, stamp: float) -> None:
        try:
            event = orjson.loads(payload)
            kind, data = str(event.get("kind", "")), event.get("data") or {}
        except (orjson.JSONDecodeError, AttributeError):
            return
        if kind in (EVENT_KIND, FAILED_KIND) or not isinstance(data, dict):
            return
        if not any(matches(trigger, kind, data) for trigger in self.settings.triggers):
            return
        self.stats.triggered += 1
        under_way = next((p for p in self._pending if p.cause != "request" and stamp <= p.until_t), None)
        if under_way is not None and stamp - under_way.cause_t <= self.settings.before_s:
            # the same incident (an emergency stop and the level-1 event that caused it): one
            # snapshot covers both, its end moved to cover the later one's seconds after
            under_way.also.append((kind, stamp))
            under_way.until_t = max(under_way.until_t, stamp + self.settings.after_s)
            return
        self._begin(kind, stamp, str(event.get("message", "")))

    def _on_request(self, payload: bytes, stamp: float) -> None:
        try:
            request = orjson.loads(payload)
            by, reason, request_id = request["requested_by"], request.get("reason", ""), request.get("request_id", "")
        except (orjson.JSONDecodeError, KeyError, TypeError):
            return
        self.stats.triggered += 1
        self._begin("request", stamp, f"asked for by {by}" + (f": {reason}" if reason else ""), str(request_id))

    def _begin(self, cause: str, cause_t: float, detail: str, request_id: str = "") -> None:
        self._number += 1
        start = cause_t - self.settings.before_s
        items = [item for item in self._ring if item.stamp >= start]
        # the ring no longer reaches back to the start, though the run does: its memory bound
        short = bool(self._ring) and self._ring[0].stamp > start and (self._first_stamp or 0.0) < start
        self._pending.append(
            Pending(cause, cause_t, cause_t + self.settings.after_s, self._number, detail, request_id, short, items)
        )
        log.info("snapshot %d: %s at %.2f s", self._number, cause, cause_t)

    def _save_finished(self) -> None:
        done = [p for p in self._pending if self._latest_stamp > p.until_t]
        for pending in done:
            self._pending.remove(pending)
            self._to_save.put(pending)

    # ---- the saver ------------------------------------------------------------------------------------
    def _save_all(self) -> None:
        started = time.thread_time()
        try:
            while True:
                pending = self._to_save.get()
                if pending is None:
                    break
                self.save(pending)
        finally:
            self.stats.saver_cpu_s = time.thread_time() - started

    def save(self, pending: Pending) -> Path | None:
        """Write one snapshot (temporary name, renamed once complete) and announce it."""
        utc = datetime.fromtimestamp(self.utc_epoch + pending.cause_t, tz=UTC)
        name = snapshot_files.file_name(self.vehicle_id, utc, pending.cause, pending.number)
        path = self.folder / name
        partial = path.with_suffix(".partial")
        items = [item for item in pending.items if item.stamp <= pending.until_t]
        try:
            views = FoxgloveViews(self.cfg, self.utc_epoch)
            recorder = McapRecorder(
                partial, self.cfg, utc_epoch=self.utc_epoch, views=views, route=self.route, settings=self._recording
            )
            recorder.start(threaded=False)
            try:
                for item in items:
                    recorder.write(item.log_time, item.topic, item.encoding, item.payload)
            finally:
                recorder.close()
            sha256 = snapshot_files.sha256_of(partial)
            partial.rename(path)
        except OSError as exc:
            partial.unlink(missing_ok=True)
            self.stats.failed += 1
            log.error("snapshot %d (%s) not saved: %s", pending.number, pending.cause, exc)
            self._announce(
                FAILED_KIND,
                f"the snapshot of {pending.cause} at {pending.cause_t:.1f} s could not be saved: {exc}",
                EventLevel.WARNING,
                {
                    "cause": pending.cause,
                    "cause_t": pending.cause_t,
                    "reason": str(exc),
                    "request_id": pending.request_id,
                },
            )
            return None
        size = path.stat().st_size
        first = min((item.stamp for item in items), default=pending.cause_t)
        last = max((item.stamp for item in items), default=pending.cause_t)
        self.stats.saved += 1
        self.stats.saved_files.append(name)
        self._announce(
            EVENT_KIND,
            f"snapshot of {pending.cause} at {pending.cause_t:.1f} s ({pending.detail})"
            + "".join(f", and of {kind} at {t:.1f} s" for kind, t in pending.also)
            + f": {name}, "
            f"{first:.1f} to {last:.1f} s, {size / 1e6:.1f} MB",
            EventLevel.INFO,
            {
                "file": name,
                "cause": pending.cause,
                "cause_t": round(pending.cause_t, 6),
                "also": ", ".join(f"{kind} at {t:.2f} s" for kind, t in pending.also),
                "from_t": round(first, 6),
                "to_t": round(last, 6),
                "messages": len(items),
                "bytes": size,
                "sha256": sha256,  # the fleet's copy is checked against it
                "ring_short": pending.ring_short,
                "request_id": pending.request_id,
            },
        )
        self.stats.pruned += len(snapshot_files.prune(self.folder, self.settings.retention_days))
        return path

    def _announce(self, kind: str, message: str, level: EventLevel, data: dict[str, Any]) -> None:
        if self._bus is None:
            return
        try:
            self._bus.publish(
                "events",
                Event(t=self._latest_stamp, source=SOURCE, kind=kind, level=level, message=message, data=data),
            )
        except Exception:  # the bus closed with the run: the file stays, its event is lost
            log.warning("snapshot event not published (bus closed): %s", message)

    # ---- the end ----------------------------------------------------------------------------------------
    def close(self, timeout_s: float = 120.0) -> KeeperStats:
        """Stop taking messages, save what is under way, wait for the saver."""
        for handle in self._handles:
            try:
                self._bus._undeclare(handle)
            except Exception:  # the bus may be closed already
                pass
        self._handles = []
        if self._threads:
            self._inbox.put(None)
            for thread in self._threads:
                thread.join(timeout_s)
            self._threads = []
        return self.stats


def request_id() -> str:
    return uuid.uuid4().hex[:12]
