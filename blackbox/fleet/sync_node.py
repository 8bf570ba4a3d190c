"""The fleet's black box as a process of the fleet server (fleet process table entry `fleet_sync`).

Every vehicle's records (`blackbox/record`) and events arrive from the fleet router
(bus.subscribe_fleet) and go to the fleet's store through the same writer as a vehicle's
recorder (spooled to disk while the store is down; blackbox.register.blackbox_node: what every black box does
with its writer, down to publishing its last notices at teardown). The store is idempotent per vehicle and
second, so a record that arrives twice is stored once. After a lost link the ledger
(blackbox/fleet/sync.py) asks the vehicle's recorder for the seconds it missed
(`blackbox/records`, a call the fleet router allows); the calls run on a thread of their own, so
the loop never waits on a vehicle. A vehicle silent for `unreachable_after_s` gets a
`vehicle_unreachable` event in its black box, and `vehicle_reachable` when it is heard again.

The fleet also tells each vehicle up to where its store holds every record
(`blackbox/acknowledge`, ledger.acknowledgements): an acknowledgement waits until the writer has
settled every item submitted before it was due (the writer keeps their order), and is not sent,
the range opened again instead, if the writer lost any item meanwhile; so a vehicle that keeps
its records until they are acknowledged deletes none that the fleet's store does not hold.
Answers to the fleet's own requests are taken however old (the door's future bound still
holds): a vehicle that kept a week of unacknowledged seconds gets them acknowledged.

Incident snapshots are copied from every reachable vehicle into the fleet's snapshots folder, one
folder per vehicle (blackbox/fleet/snapshot_copy.py: resumable, paced to a bandwidth), on a
thread of their own; the events of those saved while the link was cut come with the listing.

A vehicle's events carry its stack time; they are stored at the UTC time its records map that
stack time to (before its first record, at the time they arrive). Events that a cut link kept
from the fleet stay in the vehicle's own store: only records are filled in.
"""

from __future__ import annotations

import math
import queue
import threading
import time
from datetime import UTC, datetime

from ares.core.bus import ServiceError
from ares.core.messages import (
    Acknowledgement,
    AcknowledgementReply,
    BlackboxRecord,
    Event,
    EventLevel,
    RecordRange,
    StoredEvent,
    VehicleRecord,
)
from blackbox.fleet.door import Refusals, StampWindow, epoch_or_none
from blackbox.fleet.snapshot_copy import SnapshotCopier
from blackbox.fleet.sync import FleetLedger, FleetSyncParams, Reachability, epoch_of
from blackbox.register import snapshot_files
from blackbox.register.blackbox_node import BlackboxNode
from blackbox.register.recorder import open_configured_store, store_uri, stored_event
from blackbox.register.store.record_store import RETENTION, StoreSettings, StoreUnavailable


class FleetSync(BlackboxNode):
    """Every vehicle's black box into the fleet's store: live, gaps filled after a lost link."""

    name = "fleet_sync"
    Params = FleetSyncParams
    sections = {"blackbox_store": StoreSettings}
    fleet_inputs = ("blackbox/record", "events")
    calls = ("blackbox/records", "blackbox/acknowledge", "blackbox/snapshots", "blackbox/snapshot_part")

    def setup(self) -> None:
        p = self.params
        settings = self.shared["blackbox_store"]
        self.wall = time.time  # reachability is the wall's (a test gives its own)
        self.ledger = FleetLedger(p)
        self.window = StampWindow(p.oldest_accepted_s, p.future_tolerance_s)
        self.refusals = Refusals(p.refusal_report_s)
        self.arrived: queue.SimpleQueue[tuple[str, float, object]] = queue.SimpleQueue()
        self._known_from_store(settings)
        self.start_writer(settings, self.core.vehicle_id)
        self.asks: queue.SimpleQueue[tuple[str, int, int] | tuple[str, int | None] | None] = queue.SimpleQueue()
        self.answers: queue.SimpleQueue[tuple[str, list[VehicleRecord] | None, int | None, int | None, str]] = (
            queue.SimpleQueue()
        )
        self.replies: queue.SimpleQueue[tuple[str, AcknowledgementReply | None, str]] = queue.SimpleQueue()
        # acknowledgements waiting for the writer: (vehicle, up to, items submitted, losses then)
        self.unsettled: list[tuple[str, int, int, int]] = []
        self.acknowledgements_refused = 0
        self.acknowledgements_withheld = 0  # the writer lost items before them: the range asked again
        self.asker = threading.Thread(target=self._ask_vehicles, name="fleet-backfill", daemon=True)
        self.asker.start()
        self.snapshots_dir = snapshot_files.folder(self.core.recording.snapshots, settings)
        self.snapshots_listed: set[tuple[str, str]] = self._snapshot_events_stored(settings)  # (vehicle, file)
        self.copier: SnapshotCopier | None = None
        if p.snapshot_copy:
            self.copier = SnapshotCopier(
                self.bus.call,
                self.snapshots_dir,
                bytes_per_s=p.snapshot_bytes_per_s,
                part_bytes=p.snapshot_part_bytes,
                list_every_s=p.snapshot_list_every_s,
                retry_s=p.snapshot_retry_s,
                timeout_s=p.backfill_timeout_s,
                retention_days=self.core.recording.snapshots.retention_days,
            )
            threading.Thread(target=self.copier.run, name="fleet-snapshots", daemon=True).start()
        for topic in self.fleet_inputs:
            self.bus.subscribe_fleet(topic, self._arrived)
        self.log.info("fleet black box to %s", store_uri(settings))

    def _arrived(self, vehicle_id: str, _topic: str, msg: object) -> None:
        self.arrived.put((vehicle_id, self.wall(), msg))  # on the transport's thread: queued, nothing more

    def _known_from_store(self, settings: StoreSettings) -> None:
        """The newest second stored of each vehicle: a gap since then is filled too."""
        try:
            store = open_configured_store(settings)
        except StoreUnavailable as exc:
            self.log.warning("store unavailable at start (%s): gaps from before this start are not known", exc)
            return
        try:
            for vehicle_id in store.vehicles():
                latest = store.latest(vehicle_id)
                if latest is None:
                    continue
                newest = epoch_of(latest["time"])
                why = self.window.why_refused(newest, self.wall())
                if why is None:
                    self.ledger.known(vehicle_id, int(newest))
                else:  # stored before the door refused such stamps: no gap is measured from it
                    self.log.warning("the newest second stored of %s is not taken as its newest: %s", vehicle_id, why)
        except StoreUnavailable as exc:
            self.log.warning("store unavailable at start (%s): gaps from before this start are not known", exc)
        finally:
            store.close()

    def _snapshot_events_stored(self, settings: StoreSettings) -> set[tuple[str, str]]:
        """The snapshots the fleet's store lists already (its `snapshot` events within the retention)."""
        try:
            store = open_configured_store(settings)
        except StoreUnavailable:
            return set()
        try:
            end = datetime.now(UTC)
            return {
                (vehicle_id, str((row.get("data") or {}).get("file", "")))
                for vehicle_id in store.vehicles()
                for row in store.events(vehicle_id, end - RETENTION, end, kinds=["snapshot"], limit=100_000)
            }
        except StoreUnavailable:
            return set()
        finally:
            store.close()

    def step(self, now: float) -> None:
        wall = self.wall()
        while True:
            try:
                vehicle_id, arrived_wall, msg = self.arrived.get_nowait()
            except queue.Empty:
                break
            if vehicle_id != self.core.vehicle_id:  # the fleet server's own events: no vehicle's
                self._reachability(self.ledger.heard(vehicle_id, arrived_wall))
            if isinstance(msg, BlackboxRecord):
                self._live_record(vehicle_id, msg.record, arrived_wall)
            elif isinstance(msg, Event):
                self._live_event(vehicle_id, msg, arrived_wall)
        while True:
            try:
                vehicle_id, records, oldest, complete_to, error = self.answers.get_nowait()
            except queue.Empty:
                break
            if records is None:
                self.ledger.failed(vehicle_id)
                self.log.info("gap of %s not filled yet: %s", vehicle_id, error)
                continue
            self._answer(vehicle_id, records, oldest, complete_to, wall)
        self._take_replies()
        for change in self.ledger.silent(wall):
            self._reachability(change)
        for ask in self.ledger.requests(wall):
            self.asks.put(ask)
        self._acknowledge(wall)
        self._snapshots()
        for vehicle_id, cause, count, example in self.refusals.due(wall):
            self.event(
                "fleet_record_refused",
                f"{count} from {vehicle_id} refused ({cause}), the latest: {example}: not stored",
                EventLevel.WARNING,
                vehicle=vehicle_id,
                cause=cause,
                refused=count,
            )
        self.publish_notices()

    def _live_record(self, vehicle_id: str, record: VehicleRecord, wall: float) -> None:
        epoch = self._accepted_second(vehicle_id, record, wall)
        if epoch is None:
            return
        self.ledger.record(vehicle_id, epoch, record.t)
        self.submit(record)

    def _live_event(self, vehicle_id: str, msg: Event, arrived_wall: float) -> None:
        known = self.ledger.vehicles.get(vehicle_id)  # the fleet's own events have no ledger
        offset = None if known is None else known.utc_offset_s
        stamp = arrived_wall if offset is None else offset + msg.t
        why = self.window.why_refused(stamp, arrived_wall)
        if why is not None:
            self.refusals.note(vehicle_id, "event time", f"an event at stack time {msg.t!r}: {why}")
            return
        self.submit(stored_event(vehicle_id, datetime.fromtimestamp(stamp, UTC), msg))
        if msg.kind == "snapshot" and vehicle_id != self.core.vehicle_id:
            self.snapshots_listed.add((vehicle_id, str(msg.data.get("file", ""))))
            if self.copier is not None:
                self.copier.soon(vehicle_id)

    def _snapshots(self) -> None:
        """The copier's news into the store: events of snapshots the store does not list yet (saved
        while the link was cut), and its copies done or failed, in the vehicles' events."""
        if self.copier is None:
            return
        self.copier.reachable = frozenset(v for v, ledger in self.ledger.vehicles.items() if ledger.reachable)
        listings, copies = self.copier.take()
        for vehicle_id, kept in listings:
            if (vehicle_id, kept.name) not in self.snapshots_listed:
                self.snapshots_listed.add((vehicle_id, kept.name))
                self.submit(kept.event)
        for copy in copies:
            self._vehicle_event(copy.vehicle_id, copy.kind, copy.level, copy.message, copy.data)

    def _vehicle_event(self, vehicle_id: str, kind: str, level: EventLevel, message: str, data: dict) -> None:
        """An event about a vehicle, raised by the fleet now: at the fleet's wall time, and at the
        vehicle's stack time as far as its clock's offset is known (0 before)."""
        ledger = self.ledger.vehicle(vehicle_id)
        wall = self.wall()
        stack_t = wall - ledger.utc_offset_s if ledger.utc_offset_s is not None else 0.0
        self.submit(
            StoredEvent(
                vehicle_id=vehicle_id,
                time=datetime.fromtimestamp(wall, UTC),
                t=stack_t,
                source=self.name,
                kind=kind,
                level=level,
                message=message,
                data=data,
            )
        )

    def _answer(
        self, vehicle_id: str, records: list[VehicleRecord], oldest: int | None, complete_to: int | None, wall: float
    ) -> None:
        """The recorder's answer: of its records, those of the range asked for are stored."""
        asked = self.ledger.vehicle(vehicle_id).in_flight
        if asked is None:
            return
        seconds = set()
        for record in records:
            epoch = self._accepted_second(vehicle_id, record, wall, asked=True)
            if epoch is None:
                continue
            if not asked[0] <= epoch < asked[1]:
                self.refusals.note(vehicle_id, "answer outside the range asked", f"{epoch} for {asked}")
                continue
            seconds.add(epoch)
            self.submit(record)
        self.ledger.answered(vehicle_id, seconds, oldest, complete_to)
        ledger = self.ledger.vehicle(vehicle_id)
        self.log.info(
            "gap of %s: %d seconds filled so far, %d open, %d left on the vehicle",
            vehicle_id,
            ledger.filled,
            self.ledger.open_seconds(vehicle_id),
            ledger.left_on_vehicle,
        )

    def _acknowledge(self, wall: float) -> None:
        """Acknowledgements due wait for the writer; those it settled without a loss are sent."""
        for vehicle_id, upto in self.ledger.acknowledgements(wall):
            if upto is None:
                self.asks.put((vehicle_id, None))  # the vehicle's mark: nothing is stored by asking
            else:
                self.unsettled.append((vehicle_id, upto, self.writer.accepted, self.writer.losses + self.lost))
        waiting = []
        for vehicle_id, upto, submitted, losses in self.unsettled:
            if not self.writer.settled_through(submitted):
                waiting.append((vehicle_id, upto, submitted, losses))
            elif self.writer.losses + self.lost == losses:
                self.asks.put((vehicle_id, upto))
            else:  # an item of those behind it may be one of this vehicle's records: asked again
                start = self.ledger.lost_before(vehicle_id, upto)
                self.acknowledgements_withheld += 1
                self.log.warning(
                    "the writer lost items before %s's acknowledgement up to %d: seconds from %d asked for again",
                    vehicle_id,
                    upto,
                    start,
                )
        self.unsettled = waiting

    def _take_replies(self) -> None:
        while True:
            try:
                vehicle_id, reply, error = self.replies.get_nowait()
            except queue.Empty:
                return
            if reply is None or (reply.refused and reply.acknowledged_epoch_s is None):
                self.ledger.acknowledgement_failed(vehicle_id)
                self.log.info("no acknowledgement taken by %s yet: %s", vehicle_id, error or reply.refused)
                continue
            if reply.refused:
                self.acknowledgements_refused += 1
                self.log.warning("%s's store kept its own mark: %s", vehicle_id, reply.refused)
            self.ledger.acknowledged(vehicle_id, reply.acknowledged_epoch_s, reply.oldest_held_epoch_s)

    def _accepted_second(self, vehicle_id: str, record: VehicleRecord, wall: float, asked: bool = False) -> int | None:
        """The second a vehicle's record stands for, or None (the refusal counted) when the fleet
        does not take it: another vehicle's, or stamped outside the window (of any age when the
        fleet `asked` for its range)."""
        if record.vehicle_id != vehicle_id:  # the key's id is the one access control checked
            self.refusals.note(
                vehicle_id,
                "record of another vehicle",
                f"a record for {record.vehicle_id[:80]!r} under ares/{vehicle_id}",
            )
            return None
        if not math.isfinite(record.t):  # the bus's schema refuses it; a record built in-process may not
            self.refusals.note(vehicle_id, "record stack time", f"a record at stack time {record.t!r}")
            return None
        epoch = epoch_or_none(record.time)
        why = "a time out of range" if epoch is None else self.window.why_refused(epoch, wall, any_age=asked)
        if epoch is None or why is not None:
            self.refusals.note(vehicle_id, "record time", f"a record stamped {record.time.isoformat()}: {why}")
            return None
        return int(epoch)

    def _ask_vehicles(self) -> None:
        """The backfill and acknowledgement calls, one at a time, off the loop."""
        while (ask := self.asks.get()) is not None:
            if len(ask) == 2:
                self._send_acknowledgement(*ask)
                continue
            vehicle_id, start, end = ask
            try:
                batch = self.bus.call(
                    "blackbox/records",
                    RecordRange(t=self.clock.now(), start_epoch_s=start, end_epoch_s=end),
                    timeout_s=self.params.backfill_timeout_s,
                    vehicle_id=vehicle_id,
                )
                self.answers.put((vehicle_id, list(batch.records), batch.oldest_epoch_s, batch.complete_to_epoch_s, ""))
            except ServiceError as exc:
                self.answers.put((vehicle_id, None, None, None, str(exc)))

    def _send_acknowledgement(self, vehicle_id: str, upto: int | None) -> None:
        try:
            reply = self.bus.call(
                "blackbox/acknowledge",
                Acknowledgement(t=self.clock.now(), upto_epoch_s=upto),
                timeout_s=self.params.backfill_timeout_s,
                vehicle_id=vehicle_id,
            )
            self.replies.put((vehicle_id, reply, ""))
        except ServiceError as exc:
            self.replies.put((vehicle_id, None, str(exc)))

    def _reachability(self, change: Reachability | None) -> None:
        if change is None:
            return
        if change.reachable:
            kind, level = "vehicle_reachable", EventLevel.INFO
            message = f"{change.vehicle_id} heard on the fleet router"
            if self.ledger.open_seconds(change.vehicle_id):
                message += f"; {self.ledger.open_seconds(change.vehicle_id)} black-box seconds to fill"
        else:
            kind, level = "vehicle_unreachable", EventLevel.WARNING
            message = f"{change.vehicle_id} unreachable: nothing heard for {change.silent_s:.1f} s"
        self.log.log(20 if change.reachable else 30, "%s", message)
        self._vehicle_event(change.vehicle_id, kind, level, message, {"silent_s": round(change.silent_s, 2)})

    def teardown(self) -> None:
        asks = getattr(self, "asks", None)
        if asks is not None:
            asks.put(None)
        copier = getattr(self, "copier", None)
        if copier is not None:
            copier.stop()
        super().teardown()
