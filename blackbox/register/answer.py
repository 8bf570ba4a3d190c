"""The vehicle's answers to the fleet: its acknowledgement taken into the store (the purge may
then delete up to it), and its gap request (`blackbox/records`): from memory where it
holds the seconds, from the vehicle's own store for any older second it still keeps.

An answer is bounded (at most `max_records`, a range of at most what the fleet asks for) and says
up to where it is complete (`complete_to_epoch_s`): every second of the range before it was sent
or was never recorded, so the fleet closes those and asks again from there. A store that cannot
be read answers what memory has and is complete only where memory is authoritative (from its
oldest second on: memory holds every second this run recorded since). Nothing here raises on a
store that is down; the caller bounds how long a read may take (the reader's timeouts).
"""

from __future__ import annotations

from collections.abc import Sequence
from datetime import UTC, datetime

from ares.core.messages import Acknowledgement, AcknowledgementReply, RecordBatch, RecordRange, VehicleRecord
from blackbox.register.store.record_store import RecordStore, StoreUnavailable


def answer_range(
    t: float,
    memory: Sequence[VehicleRecord],
    store: RecordStore | None,
    vehicle_id: str,
    request: RecordRange,
    max_records: int,
) -> tuple[RecordBatch, str]:
    """The answer, and why the store was not read ('' when it was, or was not needed)."""
    start, end = request.start_epoch_s, request.end_epoch_s
    memory_oldest = int(memory[0].time.timestamp()) if memory else None
    held = [r for r in memory if start <= int(r.time.timestamp()) < end]
    if memory_oldest is not None and start >= memory_oldest:  # memory alone is authoritative
        records = held[:max_records]
        complete = end if len(held) <= max_records else int(records[-1].time.timestamp()) + 1
        return RecordBatch(t=t, records=records, oldest_epoch_s=memory_oldest, complete_to_epoch_s=complete), ""
    if store is None:
        return RecordBatch(t=t, records=held[:max_records], oldest_epoch_s=memory_oldest, complete_to_epoch_s=start), (
            "no store to read"
        )
    try:
        rows = store.records(
            vehicle_id, datetime.fromtimestamp(start, UTC), datetime.fromtimestamp(end, UTC), limit=max_records + 1
        )
    except StoreUnavailable as exc:
        return RecordBatch(t=t, records=held[:max_records], oldest_epoch_s=memory_oldest, complete_to_epoch_s=start), (
            str(exc)
        )
    stored = [VehicleRecord.model_validate(row) for row in rows]
    # what memory holds and the writer has not stored yet is sent from memory
    by_second = {int(r.time.timestamp()): r for r in held}
    by_second.update({int(r.time.timestamp()): r for r in stored})
    ordered = [by_second[k] for k in sorted(by_second)]
    records = ordered[:max_records]
    complete = end if len(ordered) <= max_records else int(records[-1].time.timestamp()) + 1
    return RecordBatch(t=t, records=records, oldest_epoch_s=memory_oldest, complete_to_epoch_s=complete), ""


def take_acknowledgement(
    t: float, store: RecordStore | None, vehicle_id: str, request: Acknowledgement, newest_recorded: int | None
) -> AcknowledgementReply:
    """The fleet's acknowledgement, kept in the store: one naming a second this recorder has not
    recorded yet (a fleet's clock or bookkeeping gone wrong) is cut to the newest it recorded,
    one behind the mark does not lower it, and either is said in `refused` for the caller to count."""
    if store is None:
        return AcknowledgementReply(t=t, refused="the store cannot be read now")
    refused = ""
    try:
        mark = store.acknowledged(vehicle_id)
        upto = request.upto_epoch_s
        if upto is not None and (newest_recorded is None or upto > newest_recorded):
            refused = f"acknowledged up to {upto}, ahead of the newest second recorded ({newest_recorded})"
            upto = newest_recorded
        if upto is not None and mark is not None and upto < mark:
            refused = refused or f"acknowledged up to {upto}, behind the mark {mark}: the mark stays"
        elif upto is not None:
            mark = store.acknowledge(vehicle_id, upto)
        return AcknowledgementReply(
            t=t, acknowledged_epoch_s=mark, oldest_held_epoch_s=store.oldest_second(vehicle_id), refused=refused
        )
    except StoreUnavailable as exc:
        return AcknowledgementReply(t=t, refused=f"the store cannot be written now: {exc}")
