"""The fleet's copy of every vehicle's incident snapshots: resumable, under a bandwidth bound.

A thread of the fleet's black box (blackbox/fleet/sync_node.py). Every `snapshot_list_every_s`
(wall), and soon after a vehicle's `snapshot` event arrives live, it asks each reachable vehicle
which snapshots it keeps (`blackbox/snapshots`: each with its event, so that the fleet's store
lists one saved while the link was cut) and copies those the fleet lacks, one piece at a time
(`blackbox/snapshot_part`, `snapshot_part_bytes`), paced to `snapshot_bytes_per_s` on average: a
4G uplink shared with the live view and the black box is not filled by a copy.

A copy is resumable: the pieces go to `<name>.part` in the vehicle's folder of the fleet's
snapshots; a link cut, a vehicle that does not answer or a fleet server stopped leaves the part,
and the next try asks from its size on. Once whole, the file is checked against the size the
vehicle listed and the SHA-256 its event carries, then renamed; one that does not match is
removed and copied again at the next listing, at most MISMATCHES_MAX times a run
(`snapshot_copy_failed`, a warning in the vehicle's black box at the fleet: a file that does not
match its event twice is damaged on the vehicle, and copying it again would only spend the link);
each copy done is a `snapshot_copied` event there. Copies and parts older than the retention
(`recording.snapshots.retention_days` of the fleet's configuration) go when the thread starts and
after each copy.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from ares.core.bus import ServiceError
from ares.core.messages import (
    EventLevel,
    KeptSnapshot,
    SnapshotList,
    SnapshotListRequest,
    SnapshotPart,
    SnapshotPartRequest,
)
from blackbox.register import snapshot_files

log = logging.getLogger("blackbox.fleet.snapshot_copy")

PART_SUFFIX = ".part"
MISMATCHES_MAX = 2


@dataclass
class CopyStats:
    listed: int = 0  # listings answered
    copied: int = 0  # files copied whole and checked
    bytes: int = 0  # bytes received in pieces
    resumed: int = 0  # copies that went on from a part an earlier try left
    interrupted: int = 0  # tries a vehicle's silence or a cut link ended
    mismatched: int = 0  # whole files whose size or SHA-256 did not match: removed, copied again
    paced_s: float = 0.0  # time spent waiting for the bandwidth bound
    pruned: int = 0  # copies and parts older than the retention, deleted


@dataclass(frozen=True)
class CopyEvent:
    """What the fleet's black box records in a vehicle's events: a copy done, or one that failed."""

    vehicle_id: str
    kind: str
    level: EventLevel
    message: str
    data: dict


Call = Callable[..., object]  # bus.call(service, request, timeout_s=, vehicle_id=)


class SnapshotCopier:
    def __init__(
        self,
        call: Call,
        folder: Path,
        *,
        bytes_per_s: float,
        part_bytes: int,
        list_every_s: float,
        retry_s: float,
        timeout_s: float,
        retention_days: float,
        now: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], object] | None = None,
    ):
        self.call = call
        self.folder = folder
        self.bytes_per_s = bytes_per_s
        self.part_bytes = part_bytes
        self.list_every_s = list_every_s
        self.retry_s = retry_s
        self.timeout_s = timeout_s
        self.retention_days = retention_days
        self.now = now
        self._stop = threading.Event()
        self.sleep = sleep or self._stop.wait  # a stop ends the wait
        self.stats = CopyStats()
        self.reachable: frozenset[str] = frozenset()  # set by the fleet's loop
        self.listings: list[tuple[str, KeptSnapshot]] = []  # for the loop: events the store may lack
        self.events: list[CopyEvent] = []  # for the loop: copies done or failed
        self._lock = threading.Lock()
        self._next_list: dict[str, float] = {}
        self._wake = threading.Event()
        self._next_send = 0.0  # when the bandwidth bound lets the next piece be asked for
        self._mismatches: dict[tuple[str, str], int] = {}  # (vehicle, file) -> whole copies that did not match

    # ---- the loop's side ----------------------------------------------------------------------------
    def soon(self, vehicle_id: str) -> None:
        """A snapshot event from the vehicle: list it at once."""
        with self._lock:
            self._next_list[vehicle_id] = 0.0
        self._wake.set()

    def take(self) -> tuple[list[tuple[str, KeptSnapshot]], list[CopyEvent]]:
        with self._lock:
            listings, events = self.listings, self.events
            self.listings, self.events = [], []
        return listings, events

    def stop(self) -> None:
        self._stop.set()
        self._wake.set()

    # ---- the thread ---------------------------------------------------------------------------------
    def prune(self) -> int:
        """The copies (and parts) older than the retention go; how many."""
        if not self.folder.is_dir():
            return 0
        gone = 0
        for vehicle_folder in self.folder.iterdir():
            if vehicle_folder.is_dir():
                for pattern in ("*.mcap", "*" + PART_SUFFIX):
                    gone += len(snapshot_files.prune(vehicle_folder, self.retention_days, pattern=pattern))
        return gone

    def run(self) -> None:
        self.stats.pruned += self.prune()
        while not self._stop.is_set():
            for vehicle_id in sorted(self.reachable):
                if self._stop.is_set():
                    return
                with self._lock:
                    due = self._next_list.get(vehicle_id, 0.0) <= self.now()
                if due:
                    ok = self.sync_vehicle(vehicle_id)
                    with self._lock:
                        self._next_list[vehicle_id] = self.now() + (self.list_every_s if ok else self.retry_s)
            self._wake.wait(1.0)
            self._wake.clear()

    def sync_vehicle(self, vehicle_id: str) -> bool:
        """List the vehicle's snapshots and copy those the fleet lacks; False if a call failed."""
        try:
            listing = self.call(
                "blackbox/snapshots", SnapshotListRequest(t=0.0), timeout_s=self.timeout_s, vehicle_id=vehicle_id
            )
        except ServiceError as exc:
            log.info("snapshots of %s not listed: %s", vehicle_id, exc)
            return False
        assert isinstance(listing, SnapshotList)
        self.stats.listed += 1
        with self._lock:
            self.listings.extend((vehicle_id, kept) for kept in listing.snapshots)
        for kept in reversed(listing.snapshots):  # the oldest first
            if self._stop.is_set():
                return True
            if kept.event.vehicle_id != vehicle_id or self.target(vehicle_id, kept.name).is_file():
                continue
            if self._mismatches.get((vehicle_id, kept.name), 0) >= MISMATCHES_MAX:
                continue
            if not self.copy(vehicle_id, kept):
                return False
        return True

    def target(self, vehicle_id: str, name: str) -> Path:
        return snapshot_files.path_of(self.folder / vehicle_id, name)

    def copy(self, vehicle_id: str, kept: KeptSnapshot) -> bool:
        """Copy one file from where an earlier try stopped; False if the vehicle stopped answering."""
        target = self.target(vehicle_id, kept.name)
        part = target.with_name(target.name + PART_SUFFIX)
        target.parent.mkdir(parents=True, exist_ok=True)
        offset = part.stat().st_size if part.exists() else 0
        if offset > kept.size_bytes:  # not a part of this file
            part.unlink()
            offset = 0
        if offset:
            self.stats.resumed += 1
            log.info("copy of %s from %s goes on from byte %d", kept.name, vehicle_id, offset)
        started = self.now()
        with open(part, "ab") as f:
            while offset < kept.size_bytes:
                if self._stop.is_set():
                    return True
                self._pace()
                try:
                    piece = self.call(
                        "blackbox/snapshot_part",
                        SnapshotPartRequest(t=0.0, name=kept.name, offset=offset, max_bytes=self.part_bytes),
                        timeout_s=self.timeout_s,
                        vehicle_id=vehicle_id,
                    )
                except ServiceError as exc:
                    self.stats.interrupted += 1
                    log.info("copy of %s from %s stopped at byte %d: %s", kept.name, vehicle_id, offset, exc)
                    return False
                assert isinstance(piece, SnapshotPart)
                if piece.missing or piece.offset != offset or not len(piece.data):
                    f.close()
                    part.unlink(missing_ok=True)
                    why = "no longer kept on the vehicle" if piece.missing else f"no bytes from {offset} on"
                    self._failed(vehicle_id, kept, why)
                    return True
                f.write(piece.data.tobytes())
                f.flush()
                offset += len(piece.data)
                self.stats.bytes += len(piece.data)
                self._spent(len(piece.data))
        self._finish(vehicle_id, kept, part, target, self.now() - started)
        return True

    def _finish(self, vehicle_id: str, kept: KeptSnapshot, part: Path, target: Path, seconds: float) -> None:
        expected = str(kept.event.data.get("sha256") or "")
        size, digest = part.stat().st_size, snapshot_files.sha256_of(part)
        if size != kept.size_bytes or (expected and digest != expected):
            part.unlink(missing_ok=True)
            self.stats.mismatched += 1
            tries = self._mismatches[(vehicle_id, kept.name)] = self._mismatches.get((vehicle_id, kept.name), 0) + 1
            then = "copied again at the next listing" if tries < MISMATCHES_MAX else f"given up after {tries} copies"
            why = f"{size} bytes, SHA-256 {digest[:12]}…: not the file its event describes; {then}"
            self._failed(vehicle_id, kept, why)
            return
        part.rename(target)
        self.stats.copied += 1
        self.stats.pruned += self.prune()
        message = f"snapshot {kept.name} copied to the fleet: {size / 1e6:.1f} MB in {seconds:.1f} s"
        self._tell(
            CopyEvent(vehicle_id, "snapshot_copied", EventLevel.INFO, message, {"file": kept.name, "bytes": size})
        )

    def _failed(self, vehicle_id: str, kept: KeptSnapshot, why: str) -> None:
        log.warning("copy of %s from %s failed: %s", kept.name, vehicle_id, why)
        self._tell(
            CopyEvent(
                vehicle_id,
                "snapshot_copy_failed",
                EventLevel.WARNING,
                f"snapshot {kept.name} not copied to the fleet: {why}",
                {"file": kept.name, "reason": why},
            )
        )

    def _tell(self, event: CopyEvent) -> None:
        with self._lock:
            self.events.append(event)

    # ---- the bandwidth bound ------------------------------------------------------------------------
    def _pace(self) -> None:
        wait = self._next_send - self.now()
        if wait > 0:
            self.stats.paced_s += wait
            self.sleep(wait)

    def _spent(self, n: int) -> None:
        self._next_send = max(self._next_send, self.now()) + n / self.bytes_per_s
