"""The recorder's answers to the fleet's copy of the incident snapshots (blackbox/fleet/snapshot_copy.py):
which snapshots the vehicle keeps, and a piece of one's file.

A snapshot is listed only when the vehicle's black box holds its `snapshot` event (as the
vehicle's API serves only those) and its file is still kept; the event goes with it, so that the
fleet's store lists it even when the link was cut as it was saved. Nothing here writes.
"""

from __future__ import annotations

from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from ares.core.messages import (
    KeptSnapshot,
    SnapshotList,
    SnapshotListRequest,
    SnapshotPart,
    SnapshotPartRequest,
    StoredEvent,
)
from blackbox.register import snapshot_files
from blackbox.register.store.record_store import RETENTION, RecordStore

LISTED_MAX = 100  # the newest; older ones are copied once these are


def kept_snapshots(
    store: RecordStore, folder: Path, vehicle_id: str, request: SnapshotListRequest, now: datetime | None = None
) -> SnapshotList:
    """The snapshots whose event the store holds (within the retention) and whose file is kept, newest first."""
    now = now or datetime.now(UTC)
    rows = store.events(vehicle_id, now - RETENTION, now, kinds=["snapshot"], limit=10_000)
    kept: list[KeptSnapshot] = []
    for row in reversed(rows):
        name = str((row.get("data") or {}).get("file", ""))
        try:
            path = snapshot_files.path_of(folder, name)
            size = path.stat().st_size
        except (snapshot_files.SnapshotNameError, OSError):  # pruned, or not a snapshot's name
            continue
        event = StoredEvent.model_validate({k: row[k] for k in StoredEvent.model_fields if k in row})
        kept.append(KeptSnapshot(name=name, size_bytes=size, event=event))
        if len(kept) == LISTED_MAX:
            break
    return SnapshotList(t=request.t, snapshots=kept)


def snapshot_part(folder: Path, request: SnapshotPartRequest) -> SnapshotPart:
    """The file's bytes from the offset asked (none past its end); `missing` if it is not kept."""
    try:
        with open(snapshot_files.path_of(folder, request.name), "rb") as f:
            size = f.seek(0, 2)
            f.seek(min(request.offset, size))
            data = f.read(request.max_bytes)
    except (snapshot_files.SnapshotNameError, OSError):
        return SnapshotPart(
            t=request.t,
            name=request.name,
            offset=request.offset,
            size_bytes=0,
            missing=True,
            data=np.zeros(0, np.uint8),
        )
    return SnapshotPart(
        t=request.t,
        name=request.name,
        offset=min(request.offset, size),
        size_bytes=size,
        data=np.frombuffer(data, dtype=np.uint8),
    )
