"""The event register (ARES §3.8): one record of the vehicle's state per second, and every event.

It writes to the black-box store (the `blackbox_store` section: VehicleRecord per second,
StoredEvent per event) and reports on its own health with events: blackbox_store_down (warning),
blackbox_store_up, blackbox_spool_flushed, blackbox_spool_overflow / blackbox_queue_overflow /
blackbox_rejected (fault). Every score topic of the topic table is recorded under its name.

Records. Whenever stack time crosses a whole second k, the record for k is built from the
latest value of each input: time = clock.utc(k), i.e. the vehicle's time of stack time t = k.
A value older than max_age_s is left out (null) rather than passed off as current. Position:
the fused pose's local x, y plus the origin give UTM easting/northing, and the `utm` package
gives latitude/longitude. Sensor health: each sensor's message rate over the last
sensor_window_s against its minimum (docs/design.md §3 awareness figures: GNSS ≥ 4 Hz, IMU ≥ 30 Hz).
`events` counts the events of the second that ended at k (event t in [k − 1, k)); an event that
arrives after its record was written is counted in the next record, so each event is counted
once. If the loop falls behind and several seconds are crossed at once, each of them gets its
record (never skipped, never written twice); a restarted recorder starts at the next second.

Events are stored as they arrive, with time = clock.utc(event.t).

Never blocking. The node's loop (blackbox.register.recorder_node) only builds documents and hands them to a
writer thread through a bounded queue; the writer batches inserts. When an insert fails (StoreUnavailable or
any other error), the batch goes to a disk spool (blackbox/register/spool.py) and the writer retries with
a growing backoff; once the store answers, the spool is flushed in order and removed. When the
spool fails too (a full disk), the newest `memory_max_entries` items wait in memory and the
older are dropped and counted; every such failure is a `blackbox_fault` event, the store counts
as down, and `blackbox/status` (each second) carries the writer's counts: written, dropped,
faults, what waits where. One writer per spool: a second recorder on the same store and vehicle
is refused at start (SpoolBusy). Record inserts are idempotent per (vehicle, second, run): each
recorder start has its own run id, so a batch retried after an uncertain failure never
duplicates a record, and a clock set back between two runs never drops the second run's records
(the store keeps both; its queries give the first stored). Events are re-sent only when their
own insert failed. On SIGTERM
the writer gets shutdown_flush_s to write what is queued; the rest is spooled. A spool left
over from an earlier run is flushed first. Health timing (backoff) is in wall seconds: it
judges the store and the computer, not the simulated vehicle.

Where the store is: `blackbox_store.uri`, a mongodb:// URI or the embedded store's file; by
default the embedded store's `blackbox_store.path`, `data/blackbox.sqlite` under the working
directory of `ares run` (it persists across runs: the black box keeps 7 days); `ares run --store
URI` overrides it, and tests point it into their temporary directory. A relative path is made
absolute by `ares run` so every process of the run agrees. The spool lives next to the
embedded store (for MongoDB: under data/), one file per vehicle,
`blackbox-spool-<vehicle_id>.sqlite`, so that the next start finds what was left.

Vehicle time is the calendar time of stack time t: at `--speed 5` it runs ahead of the wall clock, and so do the
record times of a simulated run.
"""

from __future__ import annotations

import collections
import logging
import math
import queue
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path

from ares.core.config import Params, param
from ares.core.geodesy import LocalFrame
from ares.core.messages import (
    AwarenessState,
    BlackboxStatus,
    CarState,
    CommandRecord,
    ControllerStatus,
    CorrectionsRecord,
    CorrectionsStatus,
    Event,
    EventLevel,
    GnssFix,
    MissionStatus,
    Pose,
    Position,
    ProcessHealth,
    SensorHealth,
    Setpoint,
    StoredEvent,
    SupervisorState,
    VehicleRecord,
)
from blackbox.register.spool import Item, Spool, SpoolLock, split
from blackbox.register.store.open_store import open_store
from blackbox.register.store.record_store import RecordStore, StoreSettings, StoreUnavailable, is_mongo

log = logging.getLogger("blackbox")

DROPPED_REPORT_EVERY_S = 10.0  # wall; the running count makes the notices in between redundant
FAULT_REPORT_EVERY_S = 10.0  # wall; a failure that lasts is told again this often, not at each retry

SENSOR_TOPICS = {"gnss": "sensors/gnss", "imu": "sensors/imu", "can": "sensors/can"}


class SensorMinimums(Params):
    """The slowest rate at which each sensor still counts as working (docs/design.md §3: GNSS > 4 Hz,
    IMU > 30 Hz)."""

    gnss: float = param(4.0, "GNSS receiver (sensors/gnss)", unit="Hz", ge=0)
    imu: float = param(30.0, "IMU (sensors/imu)", unit="Hz", ge=0)
    can: float = param(10.0, "CAN bus (sensors/can)", unit="Hz", ge=0)


class StoreWriterParams(Params):
    """How a black box writes to its store (StoreWriter): the recorder's, and the fleet's."""

    spool: str | None = param(
        None,
        "disk spool while the store is down; null: blackbox-spool-<vehicle_id>.sqlite "
        "next to the embedded store's file (with MongoDB: under data/)",
    )
    spool_max_entries: int = param(
        1_000_000, "~8 days of records (691,200) plus events; beyond it the oldest go first (FAULT event)", ge=1
    )
    memory_max_entries: int = param(
        7200,
        "neither the store nor the spool can take items (a full disk): the newest this many wait in memory, "
        "the older are dropped and counted (blackbox_fault)",
        ge=1,
    )
    queue_size: int = param(10000, "loop -> writer thread; fills only if a store call hangs for hours", ge=1)
    batch_max: int = param(500, "items per insert call", ge=1)
    batch_wait_s: float = param(
        0.5, "the writer waits this long (wall) for a first item; the batch is what has queued by then", unit="s", gt=0
    )
    retry_min_s: float = param(0.5, "store down: retry after this (wall), doubling up to retry_max_s", unit="s", gt=0)
    retry_max_s: float = param(4.0, "longest wait between retries", unit="s", gt=0)
    shutdown_flush_s: float = param(
        1.5,
        "SIGTERM: this long to write what is queued, the rest is spooled (the supervisor waits 3 s)",
        unit="s",
        gt=0,
    )


class RecorderParams(StoreWriterParams):
    rate_hz: float = param(
        5.0, "loop: a record is built as each whole second of stack time is crossed", unit="Hz", gt=0
    )
    max_age_s: float = param(
        2.0, "an input older than this (stack s) is recorded as missing (null), not as current", unit="s", gt=0
    )
    event_queue: int = param(4096, "events buffered between two loops", ge=1)
    sensor_window_s: float = param(2.0, "sensor message rates are measured over this window (stack s)", unit="s", gt=0)
    sensor_min_hz: SensorMinimums = param(doc="each sensor's minimum rate for `ok`", factory=SensorMinimums)
    fleet_memory_s: int = param(
        3600,
        "the last seconds kept in memory for the fleet's store to fill a gap after a lost link (blackbox/records)",
        unit="s",
        ge=0,
    )
    answer_max_records: int = param(600, "records in one answer to the fleet's gap request (blackbox/records)", ge=1)
    answer_read_timeout_s: float = param(
        0.5, "an answer's read of the vehicle's store waits at most this (it runs on the loop)", unit="s", gt=0
    )
    answer_store_retry_s: float = param(
        10.0,
        "a store that failed an answer's read is tried again after this (wall); memory answers meanwhile",
        unit="s",
        gt=0,
    )
    unacknowledged_check_s: float = param(
        600.0,
        "with keep_until_acknowledged: how often (stack s) the store is asked how many records past the "
        "retention wait for the fleet's acknowledgement (a blackbox_unacknowledged_kept warning if any)",
        unit="s",
        gt=0,
    )


# ---- where the store and the spool are --------------------------------------------------------


def store_uri(settings: StoreSettings) -> str:
    """The configured store: a MongoDB URI as it is, a file path made absolute (against the working
    directory) so that processes started elsewhere find the same file."""
    where = settings.location()
    return where if is_mongo(where) else str(Path(where).expanduser().resolve())


def spool_path(params: StoreWriterParams, settings: StoreSettings, vehicle_id: str) -> Path:
    if params.spool:
        return Path(params.spool).expanduser().resolve()
    uri = store_uri(settings)
    folder = Path(settings.path).parent.resolve() if is_mongo(uri) else Path(uri).parent
    return folder / f"blackbox-spool-{vehicle_id}.sqlite"


def open_configured_store(settings: StoreSettings) -> RecordStore:
    uri = store_uri(settings)
    if not is_mongo(uri):
        Path(uri).parent.mkdir(parents=True, exist_ok=True)
    return open_store(uri, settings=settings)


# ---- one record from the latest values -------------------------------------------------------


def position_of(pose: Pose, frame: LocalFrame) -> Position | None:
    """Local x, y (+ origin) -> UTM -> latitude/longitude; None if it has no valid projection."""
    easting, northing = frame.utm_of(pose.x, pose.y)
    try:
        lat, lon = frame.to_latlon(pose.x, pose.y)
    except ValueError:  # a pose beyond what UTM can express
        return None
    return Position(
        x=pose.x,
        y=pose.y,
        z=pose.z,
        easting=easting,
        northing=northing,
        zone=frame.zone,
        hemisphere="N" if frame.northern else "S",
        lat=lat,
        lon=lon,
    )


@dataclass
class Snapshot:
    """The latest usable value of each input when a record is built (None: missing or stale)."""

    pose: Pose | None = None
    car: CarState | None = None
    controller: ControllerStatus | None = None
    setpoint: Setpoint | None = None
    supervisor: SupervisorState | None = None
    awareness: AwarenessState | None = None
    mission: MissionStatus | None = None
    corrections: CorrectionsStatus | None = None
    fix: GnssFix | None = None
    scores: dict[str, float] = field(default_factory=dict)
    sensor_rates: dict[str, float] = field(default_factory=dict)


def build_record(
    vehicle_id: str,
    time: datetime,
    k: int,
    snap: Snapshot,
    frame: LocalFrame,
    sensor_min_hz: Mapping[str, float],
    events: int,
    run: str = "",
) -> VehicleRecord:
    return VehicleRecord(
        vehicle_id=vehicle_id,
        time=time,
        t=float(k),
        position=position_of(snap.pose, frame) if snap.pose is not None else None,
        speed_mps=snap.car.speed_mps if snap.car is not None else None,
        steering_wheel_deg=snap.car.steering_wheel_deg if snap.car is not None else None,
        mode=snap.car.mode if snap.car is not None else None,
        scores=dict(snap.scores),
        controller=snap.controller.controller if snap.controller is not None else None,
        sensors={
            name: SensorHealth(rate_hz=round(rate, 2), ok=rate >= float(sensor_min_hz[name]))
            for name, rate in snap.sensor_rates.items()
        },
        processes={
            p.name: ProcessHealth(state=p.state, restarts=p.restarts)
            for p in (snap.supervisor.processes if snap.supervisor is not None else [])
        },
        awareness_level=snap.awareness.level if snap.awareness is not None else None,
        mission_state=mission_state(snap.mission),
        corrections=corrections_of(snap.corrections, snap.fix),
        command=command_of(snap.controller, snap.setpoint, snap.car),
        events=events,
        run=run,
    )


def corrections_of(status: CorrectionsStatus | None, fix: GnssFix | None) -> CorrectionsRecord | None:
    if status is None and fix is None:
        return None
    return CorrectionsRecord(
        link=status.link if status is not None else None,
        age_s=status.age_s if status is not None else None,
        fix_quality=fix.quality if fix is not None else None,
    )


def command_of(
    status: ControllerStatus | None, setpoint: Setpoint | None, car: CarState | None
) -> CommandRecord | None:
    """The second's demands: the target speed, the controller's output, the command executed."""
    if status is None and setpoint is None and car is None:
        return None
    return CommandRecord(
        target_speed_mps=status.target_speed if status is not None else None,
        controller=setpoint.source if setpoint is not None else None,
        controller_speed_mps=setpoint.v if setpoint is not None else None,
        controller_curvature=setpoint.kappa if setpoint is not None else None,
        commanded_speed_mps=car.v_command if car is not None else None,
        commanded_curvature=car.kappa_command if car is not None else None,
        emergency=car.emergency if car is not None else None,
    )


def mission_state(status: MissionStatus | None) -> str | None:
    """The mission's state, or at a POI the action running (OPENING_DOORS, ...): one value to plot."""
    if status is None:
        return None
    return status.action if status.state == "AT_POI" and status.action else status.state


def stored_event(vehicle_id: str, time: datetime, ev: Event) -> StoredEvent:
    return StoredEvent(
        vehicle_id=vehicle_id,
        time=time,
        t=ev.t,
        source=ev.source,
        kind=ev.kind,
        level=ev.level,
        message=ev.message,
        data=dict(ev.data),
    )


# ---- the writer thread -----------------------------------------------------------------------


@dataclass(frozen=True)
class Notice:
    """Something the writer wants published as an Event (by the node's own thread)."""

    kind: str
    message: str
    level: EventLevel
    data: dict


def store_writer(params: StoreWriterParams, settings: StoreSettings, spool_name: str) -> StoreWriter:
    """The writer a black box's node runs (not started)."""
    return StoreWriter(
        lambda: open_configured_store(settings),
        Spool(spool_path(params, settings, spool_name), params.spool_max_entries),
        memory_max_entries=params.memory_max_entries,
        queue_size=params.queue_size,
        batch_max=params.batch_max,
        batch_wait_s=params.batch_wait_s,
        retry_min_s=params.retry_min_s,
        retry_max_s=params.retry_max_s,
    )


class StoreWriter:
    """Takes records and events from a bounded queue and writes them to the store in batches;
    spools them to disk while the store fails, and flushes the spool once it is back.

    The store is opened (and used) only on the writer's thread. Health timing is in wall
    seconds (time.monotonic): it judges the store and the computer, not the simulated vehicle.

    Supervised: no failure ends the thread quietly. When the spool cannot take a batch either (a
    full disk holds the store and the spool alike), the items wait in memory, the newest
    `memory_max_entries` of them, and what falls out is counted (`dropped`); each such failure
    is a `blackbox_fault` event, and the store counts as down (`blackbox_store_down`) until the
    backlog reached it. What is waiting (spool, memory) is retried in order, oldest first.
    `status()` is the figure the node publishes: written, dropped, faults, what waits where.
    """

    def __init__(
        self,
        open_store_fn: Callable[[], RecordStore],
        spool: Spool,
        *,
        memory_max_entries: int = 7200,
        queue_size: int = 10000,
        batch_max: int = 500,
        batch_wait_s: float = 0.5,
        retry_min_s: float = 0.5,
        retry_max_s: float = 4.0,
    ):
        self._open_store = open_store_fn
        self.spool = spool
        self.batch_max = int(batch_max)
        self.batch_wait_s = float(batch_wait_s)
        self.retry_min_s, self.retry_max_s = float(retry_min_s), float(retry_max_s)
        self.notices: queue.SimpleQueue[Notice] = queue.SimpleQueue()
        self.store: RecordStore | None = None
        self.lock = SpoolLock(spool.path)
        self.records_written = 0  # records the store confirmed holding (new, or already there from a retry)
        self.events_written = 0
        self.records_dropped = 0  # records and events lost: memory full while store and spool failed
        self.events_dropped = 0
        self.store_faults = 0  # failed store calls, failed spool appends, writer errors
        # in the order taken: items that left the writer's keeping (stored, refused by the store,
        # or dropped), an earlier run's spool first; with `accepted` this says what is settled
        self.settled = 0
        self.accepted = 0  # items submit() took this run
        self.spool_dropped = 0  # the spool's oldest entries dropped to stay within its bound
        self._backlog_at_start = 0
        self._held: collections.deque[Item] = collections.deque()  # in order, after the spool's entries
        self.memory_max_entries = int(memory_max_entries)
        self._dropped_reported_at = -math.inf
        self._fault_reported_at = -math.inf
        self._queue: queue.Queue[Item] = queue.Queue(maxsize=int(queue_size))
        self._down_since: float | None = None  # monotonic time of the failure; None: healthy
        self._last_error = ""
        self._retry_delay = self.retry_min_s
        self._retry_at = 0.0
        self._inflight: list[Item] = []  # what the thread holds outside queue and spool
        self._stopping = threading.Event()
        self._deadline = math.inf
        self._thread = threading.Thread(target=self._run, name="blackbox-writer", daemon=True)

    # ---- the node's side --------------------------------------------------------------------
    def take_notices(self) -> list[Notice]:
        """What the writer's thread has to say (store down, back, spool overflow), for the node to
        publish as events from its loop."""
        out = []
        while True:
            try:
                out.append(self.notices.get_nowait())
            except queue.Empty:
                return out

    def stopped_summary(self, lost: int) -> str:
        return (
            f"stopped: {self.records_written} records and {self.events_written} events written, "
            f"{len(self.spool)} spooled, {len(self._held)} held in memory and not kept, "
            f"{self.records_dropped + self.events_dropped} dropped, {lost} lost"
        )

    def start(self) -> None:
        """Claim the spool (SpoolBusy if another writer has it) and start the thread."""
        self.lock.acquire()
        self._backlog_at_start = len(self.spool)
        self._thread.start()

    def status(self, t: float = 0.0, lost: int = 0) -> BlackboxStatus:
        """What the writer has done and what waits, at stack time t; `lost`: what the node's
        submissions found no room for in the queue (the node counts it)."""
        return BlackboxStatus(
            t=t,
            store_up=self.store_up,
            written=self.records_written,
            events_written=self.events_written,
            dropped=self.records_dropped,
            events_dropped=self.events_dropped,
            lost=lost,
            store_faults=self.store_faults,
            spooled=len(self.spool),
            in_memory=len(self._held),
            last_error=self._last_error,
        )

    def submit(self, item: Item) -> bool:
        """Queue one record or event; False if the queue is full (never waits)."""
        try:
            self._queue.put_nowait(item)
        except queue.Full:
            return False
        self.accepted += 1
        return True

    def settled_through(self, accepted: int) -> bool:
        """Whether the first `accepted` items submitted this run have all left the writer's
        keeping: in the store, unless `losses` grew meanwhile. The writer keeps the order of
        what it takes (queue, spool, memory, oldest first), so a count says it."""
        return self.settled - self._backlog_at_start >= accepted

    @property
    def losses(self) -> int:
        """Items taken and not stored: dropped from memory or from the spool."""
        return self.records_dropped + self.events_dropped + self.spool_dropped

    @property
    def store_up(self) -> bool:
        return self._down_since is None and self.store is not None

    def close(self, deadline_s: float) -> None:
        """Write what is queued within deadline_s (wall), spool the rest, stop the thread."""
        self._deadline = time.monotonic() + deadline_s
        self._stopping.set()
        self._thread.join(deadline_s)
        if self._thread.is_alive():
            # stuck in a store call: keep on disk what it holds and what is still queued (a
            # duplicate, should the call still succeed, is absorbed by the idempotent insert)
            left = list(self._inflight) + self._take(0.0)
            log.warning("store call still running at shutdown: spooling %d items", len(left))
            self._park(left)
        elif self.store is not None:
            try:
                self.store.close()
            except Exception:
                log.exception("closing the store")
        if self._held:  # memory does not outlive the process: one last try to keep it on disk
            self._park_held()
        if self._held:  # neither store nor spool took them: lost with the process, and counted so
            self._drop_held_at_stop()
        try:
            self.spool.close()
        except Exception as exc:
            self._fault("closing the spool", exc)
        self.lock.release()

    # ---- the thread ----------------------------------------------------------------------
    def _run(self) -> None:
        self._ensure_store()
        while True:
            stopping = self._stopping.is_set()
            items = self._take(0.0 if stopping else self.batch_wait_s)
            if stopping and not items:
                if self.spool.pending or self._held:
                    self._flush_backlog()  # the last chance for what waits: the store may be back
                return
            self._inflight = items
            try:
                self._write(items, stopping)
            except Exception as exc:  # a bug here must not end the black box: keep the items
                log.exception("writer error; keeping %d items", len(items))
                self._went_down(exc)
                self._park(items)
            self._inflight = []

    def _take(self, wait_s: float) -> list[Item]:
        items: list[Item] = []
        try:
            items.append(self._queue.get(timeout=wait_s) if wait_s > 0 else self._queue.get_nowait())
        except queue.Empty:
            return items
        while len(items) < self.batch_max:
            try:
                items.append(self._queue.get_nowait())
            except queue.Empty:
                break
        return items

    def _write(self, items: list[Item], stopping: bool) -> None:
        if self.spool.pending or self._held or not self.store_up:
            # keep the order: new items queue up behind what already waits
            self._park(items)
            if not stopping and time.monotonic() >= self._retry_at:
                self._flush_backlog()
            return
        if not items:
            return
        try:
            self._insert(items)
        except Exception as exc:
            self._went_down(exc)
            self._park(items)

    def _insert(self, items: Sequence[Item]) -> None:
        records, events = split(items)
        store = self.store
        if store is None:
            raise StoreUnavailable("the store is not open")
        try:
            if records:
                store.insert_records(records)
            if events:
                store.insert_events(events)
        except (ValueError, TypeError) as exc:
            if isinstance(exc, StoreUnavailable):
                raise
            self._insert_one_by_one(items, exc)
            return
        self.records_written += len(records)
        self.events_written += len(events)
        self.settled += len(items)

    def _insert_one_by_one(self, items: Sequence[Item], exc: Exception) -> None:
        """A data error (not an unreachable store): find the items the store refuses and drop
        only those, so that one bad document cannot stall the black box forever."""
        log.warning("the store refused a batch (%r): inserting one by one", exc)
        settled_before = self.settled
        for item in items:
            try:
                if isinstance(item, VehicleRecord):
                    self.store.insert_records([item])
                    self.records_written += 1
                else:
                    self.store.insert_events([item])
                    self.events_written += 1
                self.settled += 1
            except (ValueError, TypeError) as item_exc:
                if isinstance(item_exc, StoreUnavailable):
                    self.settled = settled_before  # the whole batch is kept and taken again
                    raise
                self.settled += 1
                self._notify(
                    "blackbox_rejected",
                    f"the store refused a {type(item).__name__} at t={item.t}: {item_exc!r}; dropped",
                    EventLevel.FAULT,
                    t=item.t,
                    error=repr(item_exc)[:200],
                )

    def _park(self, items: list[Item]) -> None:
        """Keep items that cannot go to the store now: on disk, else in memory (in order)."""
        if not items:
            return
        if self._held:  # behind what already waits in memory
            self._hold(items)
            return
        try:
            dropped = self.spool.append(items)
        except Exception as exc:
            self._fault(f"spooling {len(items)} items to {self.spool.path}", exc)
            self._hold(items)
            return
        self._spool_dropped(dropped)
        if dropped:
            self._notify(
                "blackbox_spool_overflow",
                f"black-box spool full ({self.spool.max_entries} entries): dropped the {dropped} oldest",
                EventLevel.FAULT,
                dropped=dropped,
                dropped_total=self.spool.dropped_total,
            )

    def _hold(self, items: list[Item]) -> None:
        self._held.extend(items)
        over = len(self._held) - self.memory_max_entries
        if over <= 0:
            return
        records = 0
        for _ in range(over):  # the oldest go: the newest say most about what happened last
            records += isinstance(self._held.popleft(), VehicleRecord)
        self.records_dropped += records
        self.events_dropped += over - records
        self.settled += over
        now = time.monotonic()
        if now - self._dropped_reported_at >= DROPPED_REPORT_EVERY_S:
            self._dropped_reported_at = now
            self._notify(
                "blackbox_fault",
                f"neither the store nor the spool takes items: {self.records_dropped} records and "
                f"{self.events_dropped} events dropped so far (the newest {self.memory_max_entries} kept in memory)",
                EventLevel.FAULT,
                dropped=self.records_dropped,
                events_dropped=self.events_dropped,
                in_memory=len(self._held),
            )

    def _park_held(self) -> None:
        """Move what waits in memory to the spool, if the spool takes it now."""
        held = list(self._held)
        try:
            dropped = self.spool.append(held)
        except Exception as exc:
            self._fault(f"spooling {len(held)} items held in memory", exc)
            return
        self._held.clear()
        self._spool_dropped(dropped)
        if dropped:
            self._notify(
                "blackbox_spool_overflow",
                f"black-box spool full ({self.spool.max_entries} entries): dropped the {dropped} oldest",
                EventLevel.FAULT,
                dropped=dropped,
                dropped_total=self.spool.dropped_total,
            )

    def _drop_held_at_stop(self) -> None:
        """What still waits in memory when the writer stops (the store and the spool refusing it):
        counted as dropped and told, so that written + dropped is every item the writer took."""
        records = sum(isinstance(item, VehicleRecord) for item in self._held)
        events = len(self._held) - records
        self._held.clear()
        self.records_dropped += records
        self.events_dropped += events
        self.settled += records + events
        self._notify(
            "blackbox_fault",
            f"stopping with the store and the spool refusing: {records} records and {events} events held in "
            f"memory are not kept ({self.records_dropped} records and {self.events_dropped} events dropped in all)",
            EventLevel.FAULT,
            dropped=records,
            events_dropped=events,
        )

    def _spool_dropped(self, dropped: int) -> None:
        self.spool_dropped += dropped
        self.settled += dropped

    def _fault(self, what: str, exc: Exception) -> None:
        """A failure of the black box's own keeping (not the store's answer): a FAULT event, and the
        store counts as down so that the backlog is retried and its return is told."""
        self._went_down(exc)
        now = time.monotonic()
        if now - self._fault_reported_at < FAULT_REPORT_EVERY_S:  # the same failure, retried
            return
        self._fault_reported_at = now
        log.error("black box: %s failed: %r", what, exc)
        self._notify(
            "blackbox_fault",
            f"black box: {what} failed ({type(exc).__name__}: {exc})"[:300],
            EventLevel.FAULT,
            error=f"{type(exc).__name__}: {exc}"[:300],
            store_faults=self.store_faults,
        )

    def _ensure_store(self) -> bool:
        if self.store is None:
            try:
                self.store = self._open_store()
            except Exception as exc:
                self._went_down(exc)
                return False
        return True

    def _flush_backlog(self) -> None:
        """The spool's entries, then what waits in memory, to the store, oldest first."""
        if self._held:
            self._park_held()
        if not self._ensure_store():
            return
        flushed = 0
        while self.spool.pending:
            if self._stopping.is_set() and time.monotonic() >= self._deadline:
                return
            settled_before = self.settled
            try:
                upto, chunk = self.spool.peek(self.batch_max)
                self._insert(chunk)
                self.spool.ack(upto)
            except Exception as exc:
                self.settled = settled_before  # still in the spool: taken again
                self._went_down(exc)
                return
            flushed += len(chunk)
        while self._held:
            if self._stopping.is_set() and time.monotonic() >= self._deadline:
                return
            chunk = [self._held[i] for i in range(min(self.batch_max, len(self._held)))]
            try:
                self._insert(chunk)
            except Exception as exc:
                self._went_down(exc)
                return
            for _ in chunk:
                self._held.popleft()
            flushed += len(chunk)
        self._came_up(flushed)

    def _went_down(self, exc: Exception) -> None:
        now = time.monotonic()
        self.store_faults += 1
        self._last_error = f"{type(exc).__name__}: {exc}"[:300]
        if self._down_since is None:
            self._down_since = now
            self._retry_delay = self.retry_min_s
            self._notify(
                "blackbox_store_down",
                f"black-box store unavailable ({self._last_error}); spooling to {self.spool.path}",
                EventLevel.WARNING,
                error=self._last_error,
            )
        else:
            self._retry_delay = min(self._retry_delay * 2.0, self.retry_max_s)
        self._retry_at = now + self._retry_delay

    def _came_up(self, flushed: int) -> None:
        if self._down_since is not None:
            down_s = time.monotonic() - self._down_since
            self._notify(
                "blackbox_store_up",
                f"black-box store back after {down_s:.1f} s; {flushed} spooled items written",
                EventLevel.INFO,
                down_s=round(down_s, 2),
                flushed=flushed,
            )
        elif flushed:
            self._notify(
                "blackbox_spool_flushed",
                f"{flushed} items left in the spool by an earlier run written to the store",
                EventLevel.INFO,
                flushed=flushed,
            )
        self._down_since = None
        self._fault_reported_at = -math.inf  # a new failure is told at once
        self._retry_delay = self.retry_min_s
        self._retry_at = 0.0

    def _notify(self, kind: str, message: str, level: EventLevel, **data) -> None:
        self.notices.put(Notice(kind, message, level, data))
