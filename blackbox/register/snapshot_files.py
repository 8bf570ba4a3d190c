"""Where incident snapshots (MCAP files of the bus around an event, ares/app/bus_record/snapshots.py)
are kept, by what names, and for how long: the run's recorder writes them, the API serves them.

Both find the folder the same way: `recording.snapshots.dir`, else `snapshots/` beside the black
box's embedded store (beside `blackbox_store.path` with MongoDB, as the spool is). A file's name
is its vehicle, the event's UTC time and kind and a counter; the API serves nothing whose name is
not of that form, so a request never reaches outside the folder.
"""

from __future__ import annotations

import hashlib
import re
import time
from datetime import datetime
from pathlib import Path

from ares.core.config import SnapshotSettings
from ares.core.messages import SNAPSHOT_NAME
from blackbox.register.store.record_store import StoreSettings, is_mongo

NAME = re.compile(SNAPSHOT_NAME)
FOLDER_NAME = "snapshots"


class SnapshotNameError(ValueError):
    pass


def folder(snapshots: SnapshotSettings, store: StoreSettings) -> Path:
    if snapshots.dir:
        return Path(snapshots.dir).expanduser().resolve()
    where = store.location()
    beside = Path(store.path) if is_mongo(where) else Path(where)
    return beside.expanduser().resolve().parent / FOLDER_NAME


def file_name(vehicle_id: str, utc: datetime, kind: str, number: int) -> str:
    safe = "".join(c if c.isalnum() or c in "-_" else "_" for c in f"{vehicle_id}_{kind}")
    return f"{utc:%Y%m%dT%H%M%S}Z_{safe}_{number}.mcap"


def path_of(where: Path, name: str) -> Path:
    """The file of a snapshot's name in the folder; SnapshotNameError for any other name."""
    if not NAME.fullmatch(name) or ".." in name:
        raise SnapshotNameError(f"not a snapshot's name: {name!r}")
    return where / name


def prune(where: Path, retention_days: float, now: float | None = None, pattern: str = "*.mcap") -> list[str]:
    """Delete the snapshots (files of `pattern`) older than the retention (by their files' times); their names."""
    if not where.is_dir():
        return []
    limit = (time.time() if now is None else now) - retention_days * 86400
    gone = []
    for path in sorted(where.glob(pattern)):
        try:
            if path.stat().st_mtime < limit:
                path.unlink()
                gone.append(path.name)
        except OSError:  # removed meanwhile, or not ours to remove: left
            continue
    return gone


def sha256_of(path: Path) -> str:
    """The file's SHA-256 (hex): a snapshot's event carries it, the fleet's copy is checked against it."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(1 << 20):
            digest.update(chunk)
    return digest.hexdigest()
