"""The black box's REST API (ARES §3.8-3.10): read-only queries over the record store.

`create_app(store, settings)` builds the FastAPI application; `serve(settings, store_uri)` runs
it under uvicorn, over HTTPS unless plain HTTP is asked for explicitly. Route handlers are thin:
they check the caller's role and the parameters, then ask `Repository` (this module's only
owner of store calls and caches) and return what it gives.

Nothing here writes a record, changes an event or publishes on the bus: the API cannot move
the vehicle or alter what the black box holds. The only writes are users (admin role) and the
API's own security events (an IP blacklisted).

Endpoints, all under /api/v1 (roles: ROLES_* below):

    GET  /health                                   no auth: status and store reachability
    POST /auth/token                               OAuth2 password form -> bearer token (15 min)
    POST /auth/renew                               valid token -> fresh token
    GET  /vehicles                                 fleet, auditor, operator
    GET  /vehicles/{id}/latest                     fleet, auditor, operator
    GET  /vehicles/{id}/records?start&end&fields&page&page_size     auditor, operator
    GET  /vehicles/{id}/export?start&end&format=jsonl|csv          auditor (streamed)
    GET  /vehicles/{id}/events?start&end&kind&page&page_size       auditor, operator, fleet
    GET  /vehicles/{id}/reliability?start&end&t_hours              auditor, operator, fleet
    GET  /users, POST /users                       admin
"""
import csv
import io
import logging
import os
import time
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Annotated, Any, Iterator, Literal

import orjson
from fastapi import Depends, FastAPI, Form, HTTPException, Path as PathParam, Query, Request, Security
from fastapi.exceptions import RequestValidationError
from fastapi.middleware.cors import CORSMiddleware
from fastapi.responses import JSONResponse, Response, StreamingResponse
from fastapi.security import OAuth2PasswordBearer
from pydantic import AwareDatetime, BaseModel, ConfigDict, Field, create_model
from starlette.concurrency import run_in_threadpool

from ares.messages import DriveMode, EventLevel, StoredEvent, VehicleRecord
from blackbox import reliability as rel
from blackbox.auth import ROLES, AuthError, AuthSettings, Claims, Passwords, Tokens, UserError, add_user, load_secret
from blackbox.security import (BlacklistSettings, Guard, HeaderSettings, RateLimitSettings, SecurityMiddleware,
                               blacklist_event, security_headers)
from blackbox.store import RETENTION, RecordStore, StoreUnavailable, open_store
from blackbox.tls import TlsSettings

log = logging.getLogger("blackbox.api")

PREFIX = "/api/v1"
TOKEN_PATH = f"{PREFIX}/auth/token"

# who may call what (the roles of ARES §3.9's three GUIs, plus user administration)
ROLES_LIVE = ("fleet", "auditor", "operator")           # vehicles and their latest state
ROLES_RECORDS = ("auditor", "operator")                 # browse records
ROLES_EXPORT = ("auditor",)                             # export records (the black box interface)
ROLES_EVENTS = ("auditor", "operator", "fleet")         # events and reliability summaries
ROLES_ADMIN = ("admin",)

VEHICLE_ID_PATTERN = r"^[^/*$?#\s]{1,64}$"              # one key segment of ares/<vehicle_id>/... (ares.cli)
RECORD_FIELDS = tuple(VehicleRecord.model_fields)
ALWAYS_SELECTED = ("time",)                             # a selection without the time would be a bag of values
_JSON_OPTS = orjson.OPT_NAIVE_UTC | orjson.OPT_UTC_Z


# ---- settings -----------------------------------------------------------------------------------

class LimitSettings(BaseModel):
    model_config = ConfigDict(extra="forbid")

    default_window_s: float = Field(3600.0, gt=0)      # start/end omitted: the last hour
    start_grace_s: float = Field(300.0, ge=0)         # a start computed as "now - 7 days" by a client is not refused
    default_page_size: int = Field(100, ge=1)
    max_page_size: int = Field(1000, ge=1, le=10000)
    max_page: int = Field(100_000, ge=1)
    export_batch: int = Field(2000, ge=1)            # records per store query while streaming an export
    reliability_batch: int = Field(5000, ge=1)
    max_t_hours: float = Field(100_000.0, gt=0)
    max_body_bytes: int = Field(8192, ge=256)         # forms and JSON bodies (login, new user) are small
    latest_cache_s: float = Field(1.0, ge=0.0, le=1.0)  # a record is written each second: never staler than that
    vehicles_cache_s: float = Field(5.0, ge=0.0)


class ApiSettings(BaseModel):
    """The `api:` section of the stack configuration (ares/config/stack.yaml)."""
    model_config = ConfigDict(extra="forbid")

    vehicle_id: str = "shuttle01"       # the stack's vehicle_id: whose events the API's own events are
    host: str = "127.0.0.1"
    port: int = Field(8443, ge=0, le=65535)
    state_dir: str | None = None        # token key and self-signed certificate; None: next to the store file
    docs: bool = False                  # interactive /docs and /redoc (their scripts need a looser CSP)
    access_log: bool = False
    log_level: str = "info"
    keep_alive_s: int = Field(5, ge=1, le=300)
    limit_concurrency: int | None = Field(1000, ge=1)
    cors_origins: list[str] = Field(default_factory=list)   # empty: no CORS (browsers refuse cross-origin)
    limits: LimitSettings = LimitSettings()
    auth: AuthSettings = AuthSettings()
    tls: TlsSettings = TlsSettings()
    rate_limit: RateLimitSettings = RateLimitSettings()
    blacklist: BlacklistSettings = BlacklistSettings()
    headers: HeaderSettings = HeaderSettings()

    @classmethod
    def from_config(cls, cfg: dict) -> "ApiSettings":
        data = dict(cfg.get("api") or {})
        data.setdefault("vehicle_id", cfg.get("vehicle_id", "shuttle01"))
        return cls.model_validate(data)


def state_dir(settings: ApiSettings, store: Any) -> Path:
    """Where the API keeps its token key and certificate: configured, else beside the embedded
    store's file, else the user's state directory (a MongoDB store has no file)."""
    if settings.state_dir:
        return Path(settings.state_dir).expanduser()
    path = getattr(store, "path", None)
    if path:
        return Path(path).expanduser().resolve().parent
    base = os.environ.get("XDG_STATE_HOME") or os.path.expanduser("~/.local/state")
    return Path(base) / "ares"


# ---- response models (records and events are ares.messages' own) --------------------------------

class FieldProblem(BaseModel):
    loc: list[str | int]
    msg: str
    type: str


class ApiError(BaseModel):
    """Every error: a sentence for humans, and for 422 the offending parameters."""
    detail: str
    errors: list[FieldProblem] | None = None


class Health(BaseModel):
    status: Literal["ok", "degraded"]
    store: Literal["ok", "unavailable"]
    detail: str | None = None


class Token(BaseModel):
    access_token: str
    token_type: Literal["bearer"] = "bearer"
    expires_in: int = Field(description="seconds the token stays valid; renew it before")
    role: str


class VehicleSummary(BaseModel):
    vehicle_id: str
    last_seen: datetime | None = Field(None, description="time of its latest record (null: events only)")
    mode: DriveMode | None = None


class VehicleList(BaseModel):
    vehicles: list[VehicleSummary]


# VehicleRecord with every field optional: what a page with a field selection holds. Derived
# from VehicleRecord, so the record schema is still defined once (ares.messages).
VehicleRecordFields = create_model(
    "VehicleRecordFields", __config__=ConfigDict(extra="forbid"),
    **{name: (f.annotation | None, Field(None, description=f.description)) for name, f in VehicleRecord.model_fields.items()})


class RecordsPage(BaseModel):
    vehicle_id: str
    start: datetime
    end: datetime
    page: int
    page_size: int
    total: int = Field(description="records in the window")
    fields: list[str] | None = Field(None, description="the selected fields (null: all)")
    records: list[VehicleRecordFields]      # type: ignore[valid-type]


class EventsPage(BaseModel):
    vehicle_id: str
    start: datetime
    end: datetime
    page: int
    page_size: int
    has_more: bool
    events: list[StoredEvent]


class ReliabilityReport(BaseModel):
    vehicle_id: str
    start: datetime
    end: datetime
    records: int = Field(description="records read in the window (one per second of vehicle time)")
    operating_hours: float = Field(description="hours up: mode AUTOMATIC with every process running")
    failures: int = Field(description="FAULT events that took the vehicle out of operation (one per outage)")
    open_failures: int = Field(description="failures not repaired by the end of the window (counted up to it)")
    repair_hours: float
    mtbf_hours: float | None = Field(description="operating hours / failures; null: no failure")
    failure_rate_per_hour: float | None = Field(description="1 / MTBF; null: infinite (no operating time)")
    t_hours: float
    reliability: float | None = Field(description="R(t) = exp(-failure rate * t)")
    mttr_hours: float | None = Field(description="repair hours / failures; null: no failure")
    availability: float | None = Field(description="MTBF / (MTBF + MTTR), a fraction; null: undefined")
    definitions: str = rel.__doc__.split("Edge cases")[0].strip() if rel.__doc__ else ""


class UserInfo(BaseModel):
    name: str
    role: str
    created: datetime


class NewUser(BaseModel):
    model_config = ConfigDict(extra="forbid")

    name: str = Field(pattern=r"^[a-z][a-z0-9_.-]{1,31}$")
    role: Literal["auditor", "operator", "fleet", "admin"]
    password: str = Field(min_length=1, max_length=256)


_DESCRIPTIONS = {
    400: "Malformed body: not parseable, too many form fields, or a form field over 1 kB",
    401: "Not authenticated: no token, or an expired, malformed or forged one (send Authorization: Bearer <token>)",
    403: "Forbidden: the token's role may not do this, or the client address is blacklisted "
         "after an abnormal flow of requests",
    404: "Unknown vehicle",
    409: "Already exists",
    413: "Request body too large",
    422: "Invalid parameters (bad time range, unknown field, out-of-range page, ...)",
    429: "Rate limited: retry after the Retry-After header's seconds",
    503: "The black box store is unavailable: retry later",
}


def _errors(*codes: int) -> dict:
    # 403 (blacklist) and 429 (rate limit) can answer any request
    return {code: {"model": ApiError, "description": _DESCRIPTIONS[code]}
            for code in sorted({*codes, 403, 429})}


def _json(data: Any, status: int = 200) -> Response:
    return Response(orjson.dumps(data, option=_JSON_OPTS), status_code=status, media_type="application/json")


def _utc(dt: datetime) -> datetime:
    return dt.astimezone(timezone.utc)


# ---- repository: every store call and cache ------------------------------------------------------

class Repository:
    def __init__(self, store: RecordStore, limits: LimitSettings):
        self.store = store
        self.limits = limits
        self._latest: dict[str, tuple[float, bytes, dict]] = {}    # vehicle -> (expires, JSON, record)
        self._vehicles: tuple[float, list[str]] = (0.0, [])

    def vehicles(self, fresh: bool = False) -> list[str]:
        expires, ids = self._vehicles
        now = time.monotonic()
        if fresh or now >= expires:
            ids = self.store.vehicles()
            self._vehicles = (now + self.limits.vehicles_cache_s, ids)
        return ids

    def require_vehicle(self, vehicle_id: str) -> None:
        # a vehicle recorded since the cache was filled must not look unknown: re-read once
        if vehicle_id not in self.vehicles() and vehicle_id not in self.vehicles(fresh=True):
            raise HTTPException(404, f"unknown vehicle {vehicle_id!r}: the black box holds nothing for it "
                                     "(GET /api/v1/vehicles lists the known ones)")

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

    def window(self, start: datetime | None, end: datetime | None) -> tuple[datetime, datetime]:
        """The queried window, checked: start < end, within the retention (the last 7 days)."""
        now = _utc(self.store.now())
        oldest = now - RETENTION - timedelta(seconds=self.limits.start_grace_s)
        newest = now + RETENTION        # vehicle clocks may run ahead; beyond this it is a mistake
        # bounds first: arithmetic on an arbitrary user datetime (year 1 or 9999) could overflow
        for name, value in (("start", start), ("end", end)):
            if value is not None and not oldest <= value <= newest:
                raise HTTPException(422, f"{name} {value.isoformat()} is outside the black box's retention: "
                                         f"records are kept {RETENTION.days} days, from {oldest.isoformat()}")
        end = _utc(end) if end is not None else now
        start = _utc(start) if start is not None else max(oldest, end - timedelta(seconds=self.limits.default_window_s))
        if start >= end:
            raise HTTPException(422, f"start ({start.isoformat()}) must be before end ({end.isoformat()})")
        if end - start > RETENTION + timedelta(seconds=self.limits.start_grace_s):
            raise HTTPException(422, f"window longer than the {RETENTION.days}-day retention")
        return start, end

    def records_page(self, vehicle_id: str, start: datetime, end: datetime, page: int, page_size: int,
                     fields: list[str] | None) -> bytes:
        """The page as JSON. Every field (no selection): the stored documents are spliced in as
        they are, which is ~5x faster than decoding them into dicts and encoding them again."""
        total = self.store.count_records(vehicle_id, start, end)
        head = {"vehicle_id": vehicle_id, "start": start, "end": end, "page": page, "page_size": page_size,
                "total": total, "fields": fields}
        skip = (page - 1) * page_size
        if fields is None:
            records = self.store.records_json(vehicle_id, start, end, skip=skip, limit=page_size)
            return orjson.dumps(head, option=_JSON_OPTS)[:-1] + b',"records":' + records + b"}"
        rows = self.store.records(vehicle_id, start, end, skip=skip, limit=page_size)
        return orjson.dumps({**head, "records": [{k: r.get(k) for k in fields} for r in rows]}, option=_JSON_OPTS)

    def iter_records(self, vehicle_id: str, start: datetime, end: datetime, batch: int) -> Iterator[dict]:
        """Every record of the window, oldest first, fetched by time cursor (no growing OFFSET)."""
        cursor = start
        while True:
            rows = self.store.records(vehicle_id, cursor, end, limit=batch)
            yield from rows
            if len(rows) < batch:
                return
            last = rows[-1]["time"]
            cursor = (last if last.tzinfo else last.replace(tzinfo=timezone.utc)) + timedelta(microseconds=1)

    def events_page(self, vehicle_id: str, start: datetime, end: datetime, kinds: list[str] | None,
                    page: int, page_size: int) -> dict:
        rows = self.store.events(vehicle_id, start, end, kinds=kinds, skip=(page - 1) * page_size,
                                 limit=page_size + 1)
        fields = StoredEvent.model_fields
        return {"vehicle_id": vehicle_id, "start": start, "end": end, "page": page, "page_size": page_size,
                "has_more": len(rows) > page_size,
                "events": [{k: e.get(k) for k in fields} for e in rows[:page_size]]}

    def fault_times(self, vehicle_id: str, start: datetime, end: datetime) -> list[datetime]:
        out, skip, batch = [], 0, self.limits.reliability_batch
        while True:
            rows = self.store.events(vehicle_id, start, end, skip=skip, limit=batch)
            out += [_utc(e["time"]) for e in rows if getattr(e.get("level"), "value", e.get("level")) == EventLevel.FAULT.value]
            if len(rows) < batch:
                return out
            skip += batch

    def reliability(self, vehicle_id: str, start: datetime, end: datetime, t_hours: float) -> dict:
        faults = self.fault_times(vehicle_id, start, end)
        count = 0

        def counted():
            nonlocal count
            for r in self.iter_records(vehicle_id, start, end, self.limits.reliability_batch):
                count += 1
                yield r
        until = min(end, _utc(self.store.now()))
        tally = rel.tally_window(counted(), faults, until=max(until, start))
        return {"vehicle_id": vehicle_id, "start": start, "end": end, "records": count,
                "open_failures": tally.open_failures, **tally.figures(t_hours).as_dict()}


# ---- export formats ------------------------------------------------------------------------------

CSV_SCALARS = ("vehicle_id", "time", "t", "speed_mps", "steering_wheel_deg", "mode", "controller",
               "awareness_level", "mission_state", "events")
CSV_POSITION = tuple(f"position.{k}" for k in ("x", "y", "z", "easting", "northing", "zone", "hemisphere",
                                                "lat", "lon"))
CSV_MAPPINGS = ("scores", "sensors", "processes")     # keys vary per record: one JSON cell each
CSV_COLUMNS = (*CSV_SCALARS, *CSV_POSITION, *CSV_MAPPINGS)


def _cell(value: Any) -> Any:
    if value is None:
        return ""
    if isinstance(value, datetime):
        return value.astimezone(timezone.utc).isoformat().replace("+00:00", "Z")
    if isinstance(value, (dict, list)):
        return orjson.dumps(value, option=_JSON_OPTS).decode()
    return getattr(value, "value", value)


def csv_row(record: dict) -> list:
    position = record.get("position") or {}
    return ([_cell(record.get(k)) for k in CSV_SCALARS]
            + [_cell(position.get(k.split(".", 1)[1])) for k in CSV_POSITION]
            + [_cell(record.get(k) or {}) for k in CSV_MAPPINGS])


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
        lines.append(orjson.dumps({k: record.get(k) for k in RECORD_FIELDS}, option=_JSON_OPTS))
        if len(lines) >= chunk_records:
            yield b"\n".join(lines) + b"\n"
            lines = []
    if lines:
        yield b"\n".join(lines) + b"\n"


# ---- the application -----------------------------------------------------------------------------

def _parse_fields(text: str | None) -> list[str] | None:
    if not text:
        return None
    names = [n.strip() for n in text.split(",") if n.strip()]
    unknown = [n for n in names if n not in RECORD_FIELDS]
    if unknown:
        raise HTTPException(422, f"unknown field(s) {', '.join(repr(n) for n in unknown)}; "
                                 f"fields of a record: {', '.join(RECORD_FIELDS)}")
    chosen = [*ALWAYS_SELECTED, *(n for n in names if n not in ALWAYS_SELECTED)]
    return list(dict.fromkeys(chosen))


def _parse_kinds(text: str | None) -> list[str] | None:
    if not text:
        return None
    return list(dict.fromkeys(k.strip() for k in text.split(",") if k.strip())) or None


def create_app(store: RecordStore, settings: ApiSettings) -> FastAPI:
    """The API over `store`. Holds no global state: tests build as many as they like."""
    from ares.clock import Clock

    sdir = state_dir(settings, store)
    repo = Repository(store, settings.limits)
    passwords = Passwords(settings.auth.argon2)
    tokens = Tokens(settings.auth, load_secret(settings.auth, sdir))
    guard = Guard(settings.rate_limit, settings.blacklist)
    clock = Clock.from_env()        # stack time for the events the API writes (t of StoredEvent)
    limits = settings.limits

    app = FastAPI(
        title="ARES black box API",
        version="1",
        description="Read-only access to the shuttle's black box: records of the last 7 days, events, "
                    "reliability figures. Authenticate at /api/v1/auth/token (OAuth2 password form) and "
                    "send the token as `Authorization: Bearer <token>`; renew it before it expires.",
        docs_url="/docs" if settings.docs else None,
        redoc_url="/redoc" if settings.docs else None,
        telemetry={"tracing": False, "metrics": False, "logs": False, "operation_spans": False},
        max_body_size=limits.max_body_bytes,
        form_limits={"max_fields": 8, "max_files": 0, "max_part_size": 1024},
    )
    app.state.repository = repo
    app.state.tokens = tokens
    app.state.passwords = passwords
    app.state.guard = guard
    app.state.settings = settings
    app.state.state_dir = sdir

    # ---- security: blacklist events, middleware ----

    def record_blacklist(ip: str, reason: str, duration_s: float) -> None:
        log.warning("REST API: %s blacklisted for %g s (%s)", ip, duration_s, reason)
        try:
            store.insert_events([blacklist_event(settings.vehicle_id, ip, reason, duration_s,
                                                 _utc(store.now()), clock.now())])
        except StoreUnavailable as exc:
            log.error("could not record the blacklisting of %s: %s", ip, exc)

    async def on_blacklist(ip: str, reason: str, duration_s: float) -> None:
        await run_in_threadpool(record_blacklist, ip, reason, duration_s)

    if settings.cors_origins:
        app.add_middleware(CORSMiddleware, allow_origins=settings.cors_origins, allow_methods=["GET", "POST"],
                           allow_headers=["Authorization", "Content-Type"], allow_credentials=False, max_age=600)
    # added last: outermost, so refusals and CORS answers carry the security headers too
    app.add_middleware(SecurityMiddleware, guard=guard, headers=security_headers(settings.headers),
                       token_path=TOKEN_PATH, on_blacklist=on_blacklist)

    # ---- errors: one shape for all ----

    @app.exception_handler(StoreUnavailable)
    async def store_down(_request: Request, exc: StoreUnavailable) -> JSONResponse:
        log.warning("store unavailable: %s", exc)
        return JSONResponse({"detail": "the black box store is unavailable; retry later"}, status_code=503,
                            headers={"Retry-After": "5"})

    @app.exception_handler(RequestValidationError)
    async def invalid(_request: Request, exc: RequestValidationError) -> JSONResponse:
        problems = [{"loc": [str(p) if not isinstance(p, int) else p for p in e.get("loc", ())],
                     "msg": str(e.get("msg", "")), "type": str(e.get("type", ""))} for e in exc.errors()]
        first = problems[0] if problems else None
        where = ".".join(str(p) for p in first["loc"][1:]) if first else ""
        detail = f"invalid {where or 'request'}: {first['msg']}" if first else "invalid request"
        return JSONResponse({"detail": detail, "errors": problems}, status_code=422)

    # ---- auth dependency ----

    bearer = OAuth2PasswordBearer(tokenUrl=TOKEN_PATH, auto_error=False)

    def allow(*roles: str):
        async def check(token: Annotated[str | None, Security(bearer)]) -> Claims:
            if not token:
                raise HTTPException(401, "not authenticated: send Authorization: Bearer <token> "
                                         "(get one at /api/v1/auth/token)", headers={"WWW-Authenticate": "Bearer"})
            try:
                claims = tokens.verify(token)
            except AuthError as exc:
                raise HTTPException(401, str(exc), headers={"WWW-Authenticate": "Bearer"}) from None
            if claims.role not in roles:
                raise HTTPException(403, f"role {claims.role!r} may not do this (needs {' or '.join(roles)})")
            return claims
        return check

    VehicleId = Annotated[str, PathParam(pattern=VEHICLE_ID_PATTERN, examples=[settings.vehicle_id],
                                         description="vehicle id (as in ares/<vehicle_id>/...)")]
    Start = Annotated[AwareDatetime | None, Query(description="window start, inclusive, with a UTC offset "
                                                  "(default: end - 1 h); at most 7 days ago")]
    End = Annotated[AwareDatetime | None, Query(description="window end, exclusive (default: now)")]
    Page = Annotated[int, Query(ge=1, le=limits.max_page, description="page number, from 1")]
    PageSize = Annotated[int, Query(ge=1, le=limits.max_page_size, description="items per page")]

    # ---- routes ----

    @app.get(f"{PREFIX}/health", response_model=Health, tags=["service"],
             responses={503: {"model": Health, "description": "The store is unreachable"}, **_errors()})
    def health() -> Response:
        try:
            store.ping()
        except StoreUnavailable as exc:
            return _json({"status": "degraded", "store": "unavailable", "detail": str(exc)}, 503)
        return _json({"status": "ok", "store": "ok", "detail": None})

    @app.post(f"{PREFIX}/auth/token", response_model=Token, tags=["auth"], responses=_errors(400, 401, 413, 422, 503))
    def token(request: Request,
              username: Annotated[str, Form(min_length=1, max_length=64)],
              password: Annotated[str, Form(min_length=1, max_length=256)],
              grant_type: Annotated[Literal["password"] | None, Form()] = None) -> Token:
        user = passwords.authenticate(store, username, password)
        if user is None:
            ip = request.client.host if request.client else "unknown"
            verdict = guard.login_failed(ip)
            if verdict is not None:
                record_blacklist(ip, verdict.newly_blacklisted or "", guard.cfg.duration_s)
            raise HTTPException(401, "wrong user name or password", headers={"WWW-Authenticate": "Bearer"})
        access, ttl = tokens.issue(user.name, user.role)
        return Token(access_token=access, expires_in=ttl, role=user.role)

    @app.post(f"{PREFIX}/auth/renew", response_model=Token, tags=["auth"], responses=_errors(401))
    async def renew(claims: Annotated[Claims, Depends(allow(*ROLES))]) -> Token:
        access, ttl = tokens.issue(claims.name, claims.role)
        return Token(access_token=access, expires_in=ttl, role=claims.role)

    @app.get(f"{PREFIX}/vehicles", response_model=VehicleList, tags=["vehicles"], responses=_errors(401, 503))
    def vehicles(_: Annotated[Claims, Depends(allow(*ROLES_LIVE))]) -> Response:
        out = []
        for vid in repo.vehicles(fresh=True):
            hit = repo.latest(vid)
            doc = hit[1] if hit else {}
            out.append({"vehicle_id": vid, "last_seen": doc.get("time"), "mode": doc.get("mode")})
        return _json({"vehicles": out})

    @app.get(f"{PREFIX}/vehicles/{{vehicle_id}}/latest", response_model=VehicleRecord, tags=["vehicles"],
             responses=_errors(401, 404, 422, 503))
    async def latest(vehicle_id: VehicleId, _: Annotated[Claims, Depends(allow(*ROLES_LIVE))]) -> Response:
        # the hot path of every dashboard: a cache hit stays on the event loop, no thread hop
        hit = repo.cached_latest(vehicle_id) or await run_in_threadpool(repo.latest, vehicle_id)
        if hit is None:
            raise HTTPException(404, f"unknown vehicle {vehicle_id!r}: no record of it in the black box")
        return Response(hit[0], media_type="application/json")

    @app.get(f"{PREFIX}/vehicles/{{vehicle_id}}/records", response_model=RecordsPage, tags=["records"],
             responses=_errors(401, 404, 422, 503))
    def records(vehicle_id: VehicleId, _: Annotated[Claims, Depends(allow(*ROLES_RECORDS))],
                start: Start = None, end: End = None,
                fields: Annotated[str | None, Query(max_length=512, description="comma-separated top-level "
                                                    f"fields to return (time is always included): {', '.join(RECORD_FIELDS)}")] = None,
                page: Page = 1, page_size: PageSize = limits.default_page_size) -> Response:
        chosen = _parse_fields(fields)
        start, end = repo.window(start, end)
        repo.require_vehicle(vehicle_id)
        return Response(repo.records_page(vehicle_id, start, end, page, page_size, chosen), media_type="application/json")

    @app.get(f"{PREFIX}/vehicles/{{vehicle_id}}/export", tags=["records"],
             response_class=StreamingResponse,
             responses={200: {"description": "Records of the window, oldest first: JSON Lines (one VehicleRecord "
                                             "per line) or CSV (position flattened; scores, sensors and processes "
                                             "as JSON cells). Streamed: a store failure mid-way cuts it short.",
                              "content": {"application/x-ndjson": {"schema": {"type": "string"}},
                                          "text/csv": {"schema": {"type": "string"}}}},
                        **_errors(401, 404, 422, 503)})
    def export(vehicle_id: VehicleId, _: Annotated[Claims, Depends(allow(*ROLES_EXPORT))],
               start: Start = None, end: End = None,
               format: Annotated[Literal["jsonl", "csv"], Query(description="jsonl or csv")] = "jsonl") -> StreamingResponse:
        start, end = repo.window(start, end)
        repo.require_vehicle(vehicle_id)     # also: the store answers, before the 200 is committed
        rows = repo.iter_records(vehicle_id, start, end, limits.export_batch)
        stamp = f"{start:%Y%m%dT%H%M%SZ}_{end:%Y%m%dT%H%M%SZ}"
        safe_id = "".join(c if c.isalnum() or c in "-_." else "_" for c in vehicle_id)
        media = "text/csv" if format == "csv" else "application/x-ndjson"
        return StreamingResponse(export_chunks(rows, format), media_type=media, headers={
            "Content-Disposition": f'attachment; filename="{safe_id}_{stamp}.{format}"'})

    @app.get(f"{PREFIX}/vehicles/{{vehicle_id}}/events", response_model=EventsPage, tags=["events"],
             responses=_errors(401, 404, 422, 503))
    def events(vehicle_id: VehicleId, _: Annotated[Claims, Depends(allow(*ROLES_EVENTS))],
               start: Start = None, end: End = None,
               kind: Annotated[str | None, Query(max_length=512, pattern=r"^[A-Za-z0-9_.,-]*$",
                                                 description="comma-separated event kinds (default: all)")] = None,
               page: Page = 1, page_size: PageSize = limits.default_page_size) -> Response:
        start, end = repo.window(start, end)
        repo.require_vehicle(vehicle_id)
        return _json(repo.events_page(vehicle_id, start, end, _parse_kinds(kind), page, page_size))

    @app.get(f"{PREFIX}/vehicles/{{vehicle_id}}/reliability", response_model=ReliabilityReport, tags=["events"],
             responses=_errors(401, 404, 422, 503))
    def reliability(vehicle_id: VehicleId, _: Annotated[Claims, Depends(allow(*ROLES_EVENTS))],
                    start: Start = None, end: End = None,
                    t_hours: Annotated[float, Query(gt=0, le=limits.max_t_hours,
                                                    description="mission time t of R(t), hours")] = 1.0) -> Response:
        start, end = repo.window(start, end)
        repo.require_vehicle(vehicle_id)
        report = repo.reliability(vehicle_id, start, end, t_hours)
        return _json({**report, "definitions": ReliabilityReport.model_fields["definitions"].default})

    @app.get(f"{PREFIX}/users", response_model=list[UserInfo], tags=["users"], responses=_errors(401, 503))
    def list_users(_: Annotated[Claims, Depends(allow(*ROLES_ADMIN))]) -> list[UserInfo]:
        return [UserInfo(name=u.name, role=u.role, created=u.created) for u in store.list_users()]

    @app.post(f"{PREFIX}/users", response_model=UserInfo, status_code=201, tags=["users"],
              responses=_errors(400, 401, 409, 413, 422, 503))
    def create_user(new: NewUser, _: Annotated[Claims, Depends(allow(*ROLES_ADMIN))]) -> UserInfo:
        if store.get_user(new.name) is not None:
            raise HTTPException(409, f"user {new.name!r} already exists")
        try:
            user = add_user(store, passwords, new.name, new.role, new.password, settings.auth.min_password_length)
        except UserError as exc:
            raise HTTPException(422, str(exc)) from None
        return UserInfo(name=user.name, role=user.role, created=user.created)

    return app


# ---- running it ----------------------------------------------------------------------------------

def uvicorn_config(app: FastAPI, settings: ApiSettings, *, insecure_http: bool = False, host: str | None = None,
                   port: int | None = None):
    """uvicorn's configuration for `app`: TLS with the configured or self-signed certificate,
    unless `insecure_http` (explicit: tokens and records would cross the network in clear)."""
    import uvicorn
    tls_args: dict = {}
    if not insecure_http:
        from blackbox.tls import certificate
        cert, key = certificate(settings.tls, app.state.state_dir)
        tls_args = {"ssl_certfile": str(cert), "ssl_keyfile": str(key)}
    return uvicorn.Config(
        app, host=host or settings.host, port=settings.port if port is None else port,
        loop="uvloop", http="httptools", lifespan="off", access_log=settings.access_log,
        log_level=settings.log_level, proxy_headers=False, server_header=False,
        timeout_keep_alive=settings.keep_alive_s, limit_concurrency=settings.limit_concurrency, **tls_args)


def serve(settings: ApiSettings, store_uri: str | None = None, *, insecure_http: bool = False,
          host: str | None = None, port: int | None = None) -> None:
    """Run the API in the foreground until interrupted (uvicorn handles SIGINT/SIGTERM)."""
    import uvicorn
    store = open_store(store_uri)
    try:
        app = create_app(store, settings)
        config = uvicorn_config(app, settings, insecure_http=insecure_http, host=host, port=port)
        if insecure_http:
            log.warning("REST API over plain HTTP (--insecure-http): tokens and records travel in clear")
        scheme = "http" if insecure_http else "https"
        print(f"ARES black box API on {scheme}://{config.host}:{config.port}{PREFIX} "
              f"(state in {app.state.state_dir})", flush=True)
        uvicorn.Server(config).run()
    finally:
        store.close()
