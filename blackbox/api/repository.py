"""The REST API's only owner of store calls and caches: `Repository`, and what turns store rows
into pages, reports and export files (CSV, JSON Lines), with the checks of the parameters
those need (the time window, record fields, event kinds).

Nothing here changes a record or an event: the API's only writes are users and its own
security events (an address blacklisted).
"""

import csv
import io
import logging
import time
from collections.abc import Callable, Iterator
from datetime import UTC, datetime, timedelta
from typing import Any, NamedTuple

from fastapi import HTTPException

from ares.core.messages import CommandRecord, EventLevel, StoredEvent, VehicleRecord
from blackbox.api.credentials import Claims, NoSuchUser, Passwords, UserError, add_user, delete_user
from blackbox.api.models import json_bytes
from blackbox.api.security import blacklist_event
from blackbox.api.settings import LimitSettings
from blackbox.register import reliability as rel
from blackbox.register.store.record_store import RETENTION, RecordStore, StoreUnavailable, User

log = logging.getLogger(__name__)

RECORD_FIELDS = tuple(VehicleRecord.model_fields)
ALWAYS_SELECTED = ("time",)  # a selection without the time would be a bag of values


def _utc(dt: datetime) -> datetime:
    return dt.astimezone(UTC)


def _utc_clamped(dt: datetime) -> tuple[datetime, bool]:
    """(`dt` in UTC, True); a date-time whose UTC reading falls outside the years 1-9999
    (0001-01-01T00:00+01:00, 9999-12-31T23:59-01:00): (the earliest or latest there is, False)."""
    try:
        return dt.astimezone(UTC), True
    except OverflowError:
        return (datetime.min if dt.year == 1 else datetime.max).replace(tzinfo=UTC), False


class Window(NamedTuple):
    """A time window as served: [start, end), in UTC; `clipped` when it is not the one asked for."""

    start: datetime
    end: datetime
    clipped: bool


class Repository:
    """Every store call of the API, and its caches: the latest record per vehicle, the vehicle list."""

    def __init__(self, store: RecordStore, limits: LimitSettings, own_vehicle_id: str, stack_time: Callable[[], float]):
        self.store = store
        self.limits = limits
        self.own_vehicle_id = own_vehicle_id  # whose events the API's own events are
        self.stack_time = stack_time  # t of the events the API writes
        self._latest: dict[str, tuple[float, bytes, dict]] = {}  # vehicle -> (expires, JSON, record)
        self._vehicles: tuple[float, list[str]] = (0.0, [])
        # (vehicle, piece start) -> ((its record count, its fault count), Segment): settled pieces' reliability
        self.reliability_pieces: dict[tuple[str, datetime], tuple[tuple[int, int] | None, rel.Segment]] = {}
        self.grace = timedelta(seconds=limits.start_grace_s)

    def ping(self) -> None:
        self.store.ping()

    def vehicles(self, fresh: bool = False) -> list[str]:
        expires, ids = self._vehicles
        now = time.monotonic()
        if fresh or now >= expires:
            ids = self.store.vehicles()
            self._vehicles = (now + self.limits.vehicles_cache_s, ids)
        return ids

    def vehicle_summaries(self) -> list[dict]:
        """Every vehicle the black box holds, with the time and mode of its latest record."""
        out = []
        for vid in self.vehicles(fresh=True):
            hit = self.latest(vid)
            doc = hit[1] if hit else {}
            out.append({"vehicle_id": vid, "last_seen": doc.get("time"), "mode": doc.get("mode")})
        return out

    def require_vehicle(self, vehicle_id: str) -> None:
        # a vehicle recorded since the cache was filled must not look unknown: re-read once
        if vehicle_id not in self.vehicles() and vehicle_id not in self.vehicles(fresh=True):
            raise HTTPException(
                404,
                f"unknown vehicle {vehicle_id!r}: the black box holds nothing for it "
                "(GET /api/v1/vehicles lists the known ones)",
            )

    def cached_latest(self, vehicle_id: str) -> tuple[bytes, dict] | None:
        hit = self._latest.get(vehicle_id)
        if hit is not None and hit[0] > time.monotonic():
            return hit[1], hit[2]
        return None

    def latest(self, vehicle_id: str) -> tuple[bytes, dict] | None:
        """The latest record as JSON bytes (and as a dict), cached for latest_cache_s."""
        hit = self.cached_latest(vehicle_id)
        if hit is not None:
            return hit
        doc = self.store.latest(vehicle_id)
        if doc is None:
            return None
        # validated once per cache fill (cheap at <= 1 Hz): the response matches its schema
        record = VehicleRecord.model_validate({k: v for k, v in doc.items() if k in RECORD_FIELDS})
        body = record.model_dump_json().encode()
        if self.limits.latest_cache_s > 0:
            if len(self._latest) > 10_000:
                self._latest.clear()
            self._latest[vehicle_id] = (time.monotonic() + self.limits.latest_cache_s, body, doc)
        return body, doc

    def window(self, start: datetime | None, end: datetime | None) -> Window:
        """The window served for the one asked: [start, end), omitted bounds defaulted (end: now;
        start: the last default_window_s before end). Any date-time is a valid bound (the schema
        says so): a start before the retention (the last 7 days) moves up to it, and a window that
        is then empty or was reversed (end <= start) serves nothing, at end = start. `clipped`
        tells the caller that the window served is not the one asked for."""
        now = _utc(self.store.now())
        oldest = now - RETENTION
        asked_end, exact_end = _utc_clamped(end) if end is not None else (now, True)
        exact_start = True
        if start is not None:
            asked_start, exact_start = _utc_clamped(start)
        elif asked_end > oldest + timedelta(seconds=self.limits.default_window_s):
            asked_start = asked_end - timedelta(seconds=self.limits.default_window_s)
        else:
            asked_start = oldest
        # a start a moment before the retention's (a client's "now - 7 days") is served as asked
        served_start = oldest if asked_start < oldest - self.grace else asked_start
        served_end = max(asked_end, served_start)
        clipped = (served_start, served_end) != (asked_start, asked_end) or not (exact_start and exact_end)
        return Window(served_start, served_end, clipped)

    def records_page(
        self, vehicle_id: str, window: Window, page: int, page_size: int, fields: list[str] | None
    ) -> bytes:
        """The page as JSON. Every field (no selection): the stored documents are spliced in as
        they are, which is ~5x faster than decoding them into dicts and encoding them again."""
        start, end = window.start, window.end
        total = self.store.count_records(vehicle_id, start, end)
        head = {
            "vehicle_id": vehicle_id,
            "start": start,
            "end": end,
            "clipped": window.clipped,
            "page": page,
            "page_size": page_size,
            "total": total,
            "fields": fields,
        }
        skip = (page - 1) * page_size
        if fields is None:
            records = self.store.records_json(vehicle_id, start, end, skip=skip, limit=page_size)
            return json_bytes(head)[:-1] + b',"records":' + records + b"}"
        rows = self.store.records(vehicle_id, start, end, skip=skip, limit=page_size)
        return json_bytes({**head, "records": [{k: r.get(k) for k in fields} for r in rows]})

    def iter_records(self, vehicle_id: str, start: datetime, end: datetime, batch: int) -> Iterator[dict]:
        """Every record of the window, oldest first, fetched by time cursor (no growing OFFSET)."""
        cursor = start
        while True:
            rows = self.store.records(vehicle_id, cursor, end, limit=batch)
            yield from rows
            if len(rows) < batch:
                return
            last = rows[-1]["time"]
            cursor = (last if last.tzinfo else last.replace(tzinfo=UTC)) + timedelta(microseconds=1)

    def export(self, vehicle_id: str, window: Window, fmt: str) -> Iterator[bytes]:
        """The export file of the window in `fmt` (csv or jsonl), chunk by chunk."""
        return export_chunks(self.iter_records(vehicle_id, window.start, window.end, self.limits.export_batch), fmt)

    def events_page(self, vehicle_id: str, window: Window, kinds: list[str] | None, page: int, page_size: int) -> dict:
        start, end = window.start, window.end
        rows = self.store.events(vehicle_id, start, end, kinds=kinds, skip=(page - 1) * page_size, limit=page_size + 1)
        fields = StoredEvent.model_fields
        return {
            "vehicle_id": vehicle_id,
            "start": start,
            "end": end,
            "clipped": window.clipped,
            "page": page,
            "page_size": page_size,
            "has_more": len(rows) > page_size,
            "events": [{k: e.get(k) for k in fields} for e in rows[:page_size]],
        }

    def snapshot_event(self, vehicle_id: str, name: str) -> dict | None:
        """The `snapshot` event of the vehicle that names this file, within the retention; None if none."""
        now = _utc(self.store.now())
        skip, batch = 0, self.limits.export_batch
        while True:
            rows = self.store.events(vehicle_id, now - RETENTION, now, kinds=["snapshot"], skip=skip, limit=batch)
            for row in rows:
                if (row.get("data") or {}).get("file") == name:
                    return row
            if len(rows) < batch:
                return None
            skip += batch

    def fault_times(self, vehicle_id: str, start: datetime, end: datetime) -> list[datetime]:
        out, skip, batch = [], 0, self.limits.reliability_batch
        while True:
            rows = self.store.events(vehicle_id, start, end, skip=skip, limit=batch)
            out += [
                _utc(e["time"])
                for e in rows
                if getattr(e.get("level"), "value", e.get("level")) == EventLevel.FAULT.value
            ]
            if len(rows) < batch:
                return out
            skip += batch

    def reliability(self, vehicle_id: str, window: Window, t_hours: float) -> dict:
        """The window's figures, chained from its pieces (reliability_piece_s, an hour): each
        settled whole piece's Segment comes from the cache, so a week's report reads its records
        once, not at every call (after that: its two partial hours and what is new)."""
        start, end = window.start, window.end
        now = _utc(self.store.now())
        until = max(min(end, now), start)
        faults = [f for f in self.fault_times(vehicle_id, start, end) if f <= until]
        settled = now - timedelta(seconds=self.limits.reliability_settle_s)
        segments = (
            self._segment(vehicle_id, lo, hi, [f for f in faults if lo <= f < hi], whole and hi <= settled)
            for lo, hi, whole in pieces(start, until, end, self.limits.reliability_piece_s)
        )
        tally, count = rel.chain(segments, until=until)
        return {
            "vehicle_id": vehicle_id,
            "start": start,
            "end": end,
            "clipped": window.clipped,
            "records": count,
            "open_failures": tally.open_failures,
            **tally.figures(t_hours).as_dict(),
        }

    def _segment(self, vehicle_id: str, lo: datetime, hi: datetime, faults: list[datetime], cacheable: bool):
        """The Segment of [lo, hi). A cached piece is used while its record and fault counts are
        those it was made from (a late upload or a replayed spool changes them)."""
        key = (vehicle_id, lo)
        stamp = (self.store.count_records(vehicle_id, lo, hi), len(faults)) if cacheable else None
        hit = self.reliability_pieces.get(key)
        if hit is not None and hit[0] == stamp:
            return hit[1]
        seg = rel.segment(self.iter_records(vehicle_id, lo, hi, self.limits.reliability_batch), faults)
        if cacheable:
            if len(self.reliability_pieces) >= self.limits.reliability_cache_pieces:
                del self.reliability_pieces[next(iter(self.reliability_pieces))]  # the oldest filled
            self.reliability_pieces[key] = (stamp, seg)
        return seg

    def authenticate(self, passwords: Passwords, name: str, password: str) -> User | None:
        return passwords.authenticate(self.store, name, password)

    def users(self) -> list[User]:
        return self.store.list_users()

    def add_user(self, passwords: Passwords, name: str, role: str, password: str, min_password_length: int) -> User:
        if self.store.get_user(name) is not None:
            raise HTTPException(409, f"user {name!r} already exists")
        try:
            return add_user(self.store, passwords, name, role, password, min_password_length)
        except UserError as exc:
            raise HTTPException(422, str(exc)) from None

    def revoke_token(self, claims: Claims) -> None:
        self.store.revoke_token(claims.token_id, datetime.fromtimestamp(claims.expires, UTC))

    def change_user(self, change: Callable[[RecordStore], User]) -> User:
        """`change`, a credentials function over the store (set_role, set_disabled, ...): an
        unknown user is a 404, a refused value a 422."""
        try:
            return change(self.store)
        except NoSuchUser as exc:
            raise HTTPException(404, str(exc)) from None
        except UserError as exc:
            raise HTTPException(422, str(exc)) from None

    def delete_user(self, name: str) -> None:
        try:
            delete_user(self.store, name)
        except NoSuchUser as exc:
            raise HTTPException(404, str(exc)) from None

    def record_blacklisting(self, ip: str, reason: str, duration_s: float) -> None:
        """Log and store the event that tells those responsible; a store that is down loses only the event."""
        log.warning("REST API: %s blacklisted for %g s (%s)", ip, duration_s, reason)
        try:
            self.store.insert_events(
                [
                    blacklist_event(
                        self.own_vehicle_id, ip, reason, duration_s, _utc(self.store.now()), self.stack_time()
                    )
                ]
            )
        except StoreUnavailable as exc:
            log.error("could not record the blacklisting of %s: %s", ip, exc)


EPOCH = datetime(1970, 1, 1, tzinfo=UTC)


def pieces(
    start: datetime, until: datetime, end: datetime, piece_s: float
) -> Iterator[tuple[datetime, datetime, bool]]:
    """[start, until) cut at multiples of piece_s since 1970 (UTC), then [until, end) whole (a
    window may end in the year 9999: what lies past now is one piece): (lo, hi, whether
    [lo, hi) is a whole piece)."""
    step = timedelta(seconds=piece_s)
    lo = start
    while lo < until:
        piece_start = EPOCH + step * ((lo - EPOCH) // step)
        piece_end = piece_start + step  # until is at most now: no overflow
        hi = min(piece_end, until)
        yield lo, hi, lo == piece_start and hi == piece_end
        lo = hi
    if until < end:
        yield until, end, False


# ---- parameters ----------------------------------------------------------------------------------


def parse_fields(text: str | None) -> list[str] | None:
    """The comma-separated field selection (the schema's array of RECORD_FIELDS, style form, not
    exploded): each name once; the time always comes first. No `fields`: None (every field); an
    empty one names the field "", which no record has (schemathesis' fuzzing found it accepted)."""
    if text is None:
        return None
    names = text.split(",")
    unknown = [n for n in names if n not in RECORD_FIELDS]
    if unknown:
        raise HTTPException(
            422,
            f"unknown field(s) {', '.join(repr(n) for n in unknown)}; fields of a record: {', '.join(RECORD_FIELDS)}",
        )
    if len(set(names)) < len(names):
        raise HTTPException(422, "a field is named twice in fields")
    return [*ALWAYS_SELECTED, *(n for n in names if n not in ALWAYS_SELECTED)]


def parse_kinds(text: str | None) -> list[str] | None:
    if not text:
        return None
    return list(dict.fromkeys(k.strip() for k in text.split(",") if k.strip())) or None


# ---- export formats ------------------------------------------------------------------------------

CSV_SCALARS = (
    "vehicle_id",
    "time",
    "t",
    "speed_mps",
    "steering_wheel_deg",
    "mode",
    "controller",
    "awareness_level",
    "mission_state",
    "events",
)
CSV_POSITION = tuple(
    f"position.{k}" for k in ("x", "y", "z", "easting", "northing", "zone", "hemisphere", "lat", "lon")
)
CSV_CORRECTIONS = tuple(f"corrections.{k}" for k in ("link", "age_s", "fix_quality"))
CSV_COMMAND = tuple(f"command.{k}" for k in CommandRecord.model_fields)
CSV_MAPPINGS = ("scores", "sensors", "processes")  # keys vary per record: one JSON cell each
CSV_COLUMNS = (*CSV_SCALARS, *CSV_POSITION, *CSV_CORRECTIONS, *CSV_COMMAND, *CSV_MAPPINGS)


def _cell(value: Any) -> Any:
    if value is None:
        return ""
    if isinstance(value, datetime):
        return value.astimezone(UTC).isoformat().replace("+00:00", "Z")
    if isinstance(value, (dict, list)):
        return json_bytes(value).decode()
    return getattr(value, "value", value)


def csv_row(record: dict) -> list:
    position = record.get("position") or {}
    corrections = record.get("corrections") or {}
    command = record.get("command") or {}
    return (
        [_cell(record.get(k)) for k in CSV_SCALARS]
        + [_cell(position.get(k.split(".", 1)[1])) for k in CSV_POSITION]
        + [_cell(corrections.get(k.split(".", 1)[1])) for k in CSV_CORRECTIONS]
        + [_cell(command.get(k.split(".", 1)[1])) for k in CSV_COMMAND]
        + [_cell(record.get(k) or {}) for k in CSV_MAPPINGS]
    )


def export_chunks(rows: Iterator[dict], fmt: str, chunk_records: int = 500) -> Iterator[bytes]:
    """The export body, a few hundred records per chunk (one write per chunk, bounded memory)."""
    if fmt == "csv":
        buf = io.StringIO()
        writer = csv.writer(buf, lineterminator="\n")
        writer.writerow(CSV_COLUMNS)
        n = 0
        for record in rows:
            writer.writerow(csv_row(record))
            n += 1
            if n % chunk_records == 0:
                yield buf.getvalue().encode()
                buf.seek(0)
                buf.truncate()
        yield buf.getvalue().encode()
        return
    lines: list[bytes] = []
    for record in rows:
        lines.append(json_bytes({k: record.get(k) for k in RECORD_FIELDS}))
        if len(lines) >= chunk_records:
            yield b"\n".join(lines) + b"\n"
            lines = []
    if lines:
        yield b"\n".join(lines) + b"\n"
