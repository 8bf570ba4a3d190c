"""The event register as a process (process table entry `blackbox`, ARES §3.8).

What a record holds, when it is written and how the writer survives a store that is down are
`blackbox.register.recorder`'s (its docstring says it all); this node latches the inputs, builds a record
whenever stack time crosses a whole second, hands records and events to the writer thread and
turns the writer's notices into events (both as every black box does: blackbox.register.blackbox_node).

For the fleet: each record is also published (`blackbox/record`) as it is handed to the writer,
and the last `fleet_memory_s` of them are kept in memory, from which `blackbox/records` answers
the fleet's store when it asks for the seconds a lost link kept from it (blackbox/fleet/sync.py);
an older second is read from the vehicle's own store (blackbox.register.answer), through a
handle of its own whose every read is bounded by `answer_read_timeout_s`; a store that failed
is left alone for `answer_store_retry_s`, memory answering meanwhile.

A store that keeps what the fleet has not acknowledged (`keep_until_acknowledged`) grows past the
retention while the fleet is away: every `unacknowledged_check_s` the recorder asks it how many
records wait so, and says it (`blackbox_unacknowledged_kept`, a warning the awareness manager and
the pages see) until the fleet's acknowledgement lets the purge take them; a disk that fills up
meanwhile is the writer's fault event.

The fleet also copies the incident snapshots the vehicle keeps: `blackbox/snapshots` lists them
with their events (from the store), `blackbox/snapshot_part` answers a piece of one's file
(blackbox.register.snapshot_answer).
"""

from __future__ import annotations

import collections
import math
import time
import uuid
from datetime import UTC, datetime

from ares.core import topics
from ares.core.geodesy import LocalFrame
from ares.core.messages import (
    Acknowledgement,
    AcknowledgementReply,
    BlackboxRecord,
    BlackboxStatus,
    EventLevel,
    RecordBatch,
    RecordRange,
    SnapshotList,
    SnapshotListRequest,
    SnapshotPart,
    SnapshotPartRequest,
    VehicleRecord,
)
from ares.core.node import Input, InputGroup, Output, service
from blackbox.register import snapshot_files
from blackbox.register.answer import answer_range, take_acknowledgement
from blackbox.register.blackbox_node import BlackboxNode
from blackbox.register.recorder import (
    SENSOR_TOPICS,
    RecorderParams,
    Snapshot,
    build_record,
    open_configured_store,
    store_uri,
    stored_event,
)
from blackbox.register.snapshot_answer import kept_snapshots, snapshot_part
from blackbox.register.store.record_store import RecordStore, StoreSettings, StoreUnavailable


class Recorder(BlackboxNode):
    """The event register: a record of the vehicle's state per second, every event as it happens."""

    name = "blackbox"
    Params = RecorderParams
    sections = {"blackbox_store": StoreSettings}
    pose = Input("localization/pose", max_age="max_age_s", doc="position")
    car = Input("dbw/car_state", max_age="max_age_s", doc="speed, steering, drive mode")
    controller = Input("control/status", max_age="max_age_s", doc="the active controller and its target speed")
    setpoint = Input(
        "control/setpoint", max_age="max_age_s", doc="the controller's output the control manager forwards"
    )
    supervisor = Input("supervisor/state", max_age="max_age_s", doc="process health")
    awareness = Input("awareness/state", max_age="max_age_s", doc="the self-awareness level")
    mission = Input("mission/status", max_age="max_age_s", doc="the mission's state or the POI action running")
    corrections = Input("gnss/corrections", max_age="max_age_s", doc="the RTK corrections' link and age")
    fix = Input("gnss/fix", max_age="max_age_s", doc="the fix type (GGA quality) the corrections gave")
    scores = InputGroup(topics.score_topics(), max_age="max_age_s", doc="every manager's score")
    sensors = InputGroup(SENSOR_TOPICS, doc="message rates -> sensor health")
    events = Input("events", queue="event_queue", doc="recorded as they arrive")
    published = Output("blackbox/record", rate=1.0, doc="each record as it is written, for the fleet's store")
    health = Output("blackbox/status", rate=1.0, doc="the writer's counts each second: no failure goes unseen")

    def setup(self) -> None:
        p = self.params
        self.store_settings = self.shared["blackbox_store"]
        self.vehicle_id = self.core.vehicle_id
        self.frame = LocalFrame(self.core.origin_utm)
        self.sensor_min_hz = p.sensor_min_hz.model_dump()
        self.start_writer(self.store_settings, self.vehicle_id)
        # this start's records are told apart from another's of the same second (a clock set back)
        self.run_id = uuid.uuid4().hex[:16]

        # the first second crossed from now on; a restart in the same run picks up from here
        self.next_k = math.floor(self.clock.now()) + 1
        self.event_counts: collections.Counter[int] = collections.Counter()
        self.memory: collections.deque[VehicleRecord] = collections.deque(maxlen=max(p.fleet_memory_s, 1))
        self._events_overflowed = 0
        self.reader: RecordStore | None = None  # the answers' own handle on the store, opened when first needed
        self.reader_retry_at = 0.0
        self.newest_recorded: int | None = None  # the newest second recorded (UTC epoch s)
        self.acknowledgements_refused = 0
        self.unacknowledged_check_at = self.clock.now()  # the first loop asks
        self.snapshots_dir = snapshot_files.folder(self.core.recording.snapshots, self.store_settings)
        self.log.info(
            "recording %s to %s (spool %s)", self.vehicle_id, store_uri(self.store_settings), self.writer.spool.path
        )

    def step(self, now: float) -> None:
        if self.events.overflowed > self._events_overflowed:
            lost = self.events.overflowed - self._events_overflowed
            self._events_overflowed = self.events.overflowed
            self.event(
                "blackbox_events_lost",
                f"{lost} events arrived faster than they could be recorded "
                f"(event_queue {self.params.event_queue}): not stored",
                EventLevel.FAULT,
                lost=lost,
                lost_total=self._events_overflowed,
            )
        for _, ev in self.events.drain():
            self.submit(stored_event(self.vehicle_id, self.clock.utc(ev.t), ev))
            # the record of second k counts the events of [k - 1, k); one that comes after its
            # record was written goes to the next one
            self.event_counts[max(math.floor(ev.t) + 1, self.next_k)] += 1
        crossed = False
        while self.next_k <= now:
            k = self.next_k
            record = build_record(
                self.vehicle_id,
                self.clock.utc(k),
                k,
                self.snapshot(now),
                self.frame,
                self.sensor_min_hz,
                self.event_counts.pop(k, 0),
                run=self.run_id,
            )
            self.submit(record)
            if self.params.fleet_memory_s > 0:
                self.memory.append(record)
            self.published.put(BlackboxRecord(t=float(k), record=record))
            self.newest_recorded = math.floor(record.time.timestamp())
            self.next_k = k + 1
            crossed = True
        self.publish_notices()
        if crossed:
            self.health.put(self.status(now))
        if self.store_settings.keep_until_acknowledged and now >= self.unacknowledged_check_at:
            self.unacknowledged_check_at = now + self.params.unacknowledged_check_s
            self._tell_unacknowledged()

    def _tell_unacknowledged(self) -> None:
        """How many records the purge keeps past the retention for want of an acknowledgement."""
        store = self._answer_store()
        if store is None:
            return
        try:
            count, oldest = store.unacknowledged_expired(self.vehicle_id)
            mark = store.acknowledged(self.vehicle_id)
        except StoreUnavailable as exc:
            self.log.warning("the store cannot say what waits for the fleet's acknowledgement: %s", exc)
            return
        if not count:
            return
        since = "nothing" if mark is None else f"up to {datetime.fromtimestamp(mark, UTC).isoformat()}"
        self.event(
            "blackbox_unacknowledged_kept",
            f"{count} records older than the retention kept: the fleet has acknowledged {since}",
            EventLevel.WARNING,
            kept=count,
            oldest_epoch_s=oldest,
            acknowledged_epoch_s=mark,
        )

    def status(self, now: float) -> BlackboxStatus:
        return self.writer.status(now, self.lost)

    def teardown(self) -> None:
        if getattr(self, "reader", None) is not None:
            self.reader.close()
        super().teardown()
        if getattr(self, "writer", None) is not None:  # the counts after the last flush, for whoever listens
            self.health.put(self.status(self.clock.now()))

    @service("blackbox/records")
    def _records(self, request: RecordRange) -> RecordBatch:
        batch, why_not = answer_range(
            self.clock.now(),
            self.memory,
            self._answer_store(),
            self.vehicle_id,
            request,
            self.params.answer_max_records,
        )
        if why_not:
            self.reader_retry_at = time.monotonic() + self.params.answer_store_retry_s
            self.log.warning("gap request answered from memory only: %s", why_not)
        return batch

    @service("blackbox/acknowledge")
    def _acknowledge(self, request: Acknowledgement) -> AcknowledgementReply:
        reply = take_acknowledgement(
            self.clock.now(), self._answer_store(), self.vehicle_id, request, self.newest_recorded
        )
        if reply.refused:
            self.acknowledgements_refused += 1
            self.log.warning(
                "the fleet's acknowledgement (%s refused so far): %s", self.acknowledgements_refused, reply.refused
            )
        return reply

    @service("blackbox/snapshots")
    def _snapshots(self, request: SnapshotListRequest) -> SnapshotList:
        store = self._answer_store()
        if store is None:
            return SnapshotList(t=self.clock.now())
        try:
            return kept_snapshots(store, self.snapshots_dir, self.vehicle_id, request)
        except StoreUnavailable as exc:
            self.reader_retry_at = time.monotonic() + self.params.answer_store_retry_s
            self.log.warning("the snapshots' list not read from the store: %s", exc)
            return SnapshotList(t=self.clock.now())

    @service("blackbox/snapshot_part")
    def _snapshot_part(self, request: SnapshotPartRequest) -> SnapshotPart:
        return snapshot_part(self.snapshots_dir, request)

    def _answer_store(self) -> RecordStore | None:
        """The answers' handle on the store, with reads bounded to answer_read_timeout_s; None
        while a store that failed is left alone."""
        if time.monotonic() < self.reader_retry_at:
            return None
        if self.reader is None:
            bound_s = self.params.answer_read_timeout_s
            bound_ms = max(int(bound_s * 1000), 1)
            quick = self.store_settings.model_copy(
                update={
                    "busy_timeout_s": min(self.store_settings.busy_timeout_s, bound_s),
                    "query_timeout_s": min(self.store_settings.query_timeout_s, bound_s),
                    "mongo_server_selection_timeout_ms": bound_ms,
                    "mongo_connect_timeout_ms": bound_ms,
                    "mongo_socket_timeout_ms": bound_ms,
                    "mongo_timeout_ms": bound_ms,
                }
            )
            try:
                self.reader = open_configured_store(quick)
            except StoreUnavailable as exc:
                self.reader_retry_at = time.monotonic() + self.params.answer_store_retry_s
                self.log.warning("the store cannot be opened for the fleet's answers: %s", exc)
                return None
        return self.reader

    def snapshot(self, now: float) -> Snapshot:
        window = self.params.sensor_window_s
        return Snapshot(
            pose=self.pose.fresh(now),
            car=self.car.fresh(now),
            controller=self.controller.fresh(now),
            setpoint=self.setpoint.fresh(now),
            supervisor=self.supervisor.fresh(now),
            awareness=self.awareness.fresh(now),
            mission=self.mission.fresh(now),
            corrections=self.corrections.fresh(now),
            fix=self.fix.fresh(now),
            scores={name: float(msg.score) for name, sub in self.scores.items() if (msg := sub.fresh(now)) is not None},
            sensor_rates={name: sub.rate_hz(window, now) for name, sub in self.sensors.items()},
        )
