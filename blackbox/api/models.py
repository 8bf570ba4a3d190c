"""What the REST API sends and accepts: response and request models, the documented error
responses, and the one JSON encoding of its responses.

Records and events are ares.core.messages' own models: the record schema is defined once, there.
"""

from datetime import datetime
from typing import Any, Literal

import orjson
from fastapi.responses import Response
from pydantic import BaseModel, ConfigDict, Field, create_model

from ares.core.messages import DriveMode, StoredEvent, VehicleRecord
from blackbox.api.credentials import MAX_PASSWORD_CHARS, ROLES, USERNAME_RE
from blackbox.register import reliability as rel

JSON_OPTIONS = orjson.OPT_NAIVE_UTC | orjson.OPT_UTC_Z


def json_bytes(data: Any) -> bytes:
    return orjson.dumps(data, option=JSON_OPTIONS)


def iso_utc(dt: datetime) -> str:
    """A UTC date-time as the JSON bodies write it (RFC 3339, Z)."""
    return json_bytes(dt)[1:-1].decode()


def json_response(data: Any, status: int = 200, headers: dict[str, str] | None = None) -> Response:
    return Response(json_bytes(data), status_code=status, media_type="application/json", headers=headers)


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


class LoginForm(BaseModel):
    """The OAuth2 password form of POST /auth/token (application/x-www-form-urlencoded)."""

    model_config = ConfigDict(
        extra="forbid", json_schema_extra={"examples": [{"username": "alice", "password": "a long passphrase"}]}
    )

    username: str = Field(min_length=1, max_length=64)
    password: str = Field(min_length=1, max_length=MAX_PASSWORD_CHARS)
    grant_type: Literal["password"] = Field("password", description="OAuth2's; may be left out")


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
# from VehicleRecord, so the record schema is still defined once (ares.core.messages).
VehicleRecordFields = create_model(
    "VehicleRecordFields",
    __config__=ConfigDict(extra="forbid"),
    **{
        name: (f.annotation | None, Field(None, description=f.description))
        for name, f in VehicleRecord.model_fields.items()
    },
)


WINDOW_DOC = (
    "the window served, [start, end), in UTC: a start before the retention (the last 7 days) is moved "
    "up to it, and an empty or reversed window serves nothing (end = start)"
)
CLIPPED_DOC = "true when the window served is not the one asked for (see start, end)"


class RecordsPage(BaseModel):
    vehicle_id: str
    start: datetime = Field(description=WINDOW_DOC)
    end: datetime
    clipped: bool = Field(description=CLIPPED_DOC)
    page: int
    page_size: int
    total: int = Field(description="records in the window")
    fields: list[str] | None = Field(None, description="the selected fields (null: all)")
    records: list[VehicleRecordFields]  # type: ignore[valid-type]


class EventPageHead(BaseModel):
    """What a page of a vehicle's events says besides its items: the window served and the page."""

    vehicle_id: str
    start: datetime = Field(description=WINDOW_DOC)
    end: datetime
    clipped: bool = Field(description=CLIPPED_DOC)
    page: int
    page_size: int
    has_more: bool


class EventsPage(EventPageHead):
    events: list[StoredEvent]


class SnapshotEntry(StoredEvent):
    """A `snapshot` event (data: file, cause, cause_t, from_t, to_t, messages, bytes) and its file."""

    available: bool = Field(description="the file is still kept (retention: as the records')")
    download: str = Field(description="the file's path under the API (GET, auditor; operator: this vehicle's)")


class SnapshotsPage(EventPageHead):
    snapshots: list[SnapshotEntry]


class ReliabilityReport(BaseModel):
    vehicle_id: str
    start: datetime = Field(description=WINDOW_DOC)
    end: datetime
    clipped: bool = Field(description=CLIPPED_DOC)
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
    disabled: bool = Field(description="refused at login and on every request (POST /users/{name}/enable undoes it)")


class RoleChange(BaseModel):
    """A user's new role; every token the user holds is refused from then on."""

    model_config = ConfigDict(extra="forbid", json_schema_extra={"examples": [{"role": "auditor"}]})

    role: Literal[ROLES]  # type: ignore[valid-type]


class PasswordChange(BaseModel):
    """A user's new password; every token the user holds is refused from then on.
    password_change_model gives it the configured minimum length."""

    model_config = ConfigDict(extra="forbid")

    password: str = Field(min_length=1, max_length=MAX_PASSWORD_CHARS)


def password_change_model(min_password_length: int) -> type[PasswordChange]:
    example = {"password": "another passphrase".ljust(min_password_length, ".")}
    return create_model(
        "PasswordChange",
        __base__=PasswordChange,
        __doc__=PasswordChange.__doc__,
        __config__=ConfigDict(extra="forbid", json_schema_extra={"examples": [example]}),
        password=(str, Field(min_length=min_password_length, max_length=MAX_PASSWORD_CHARS)),
    )


class NewUser(BaseModel):
    """A user to create; new_user_model gives the password its configured minimum length."""

    model_config = ConfigDict(extra="forbid")

    name: str = Field(pattern=USERNAME_RE.pattern)
    role: Literal[ROLES]  # type: ignore[valid-type]
    password: str = Field(min_length=1, max_length=MAX_PASSWORD_CHARS)


def new_user_model(min_password_length: int) -> type[NewUser]:
    """NewUser whose schema says the configured shortest password (auth.min_password_length)."""
    example = {"name": "carol", "role": "auditor", "password": "a long passphrase".ljust(min_password_length, ".")}
    return create_model(
        "NewUser",
        __base__=NewUser,
        __doc__=NewUser.__doc__,
        __config__=ConfigDict(extra="forbid", json_schema_extra={"examples": [example]}),
        password=(str, Field(min_length=min_password_length, max_length=MAX_PASSWORD_CHARS)),
    )


# Every error answer of the API, documented on the operations that can give it. A method a path
# does not have is answered 405 with an Allow header (app.answer_other_methods); an unknown path 404.
ERROR_DESCRIPTIONS = {
    400: "Malformed body: not parseable (not JSON where JSON is expected), too many form fields, or a form "
    "field over 4 kB",
    401: "Not authenticated: no token, or an expired, malformed, forged or revoked one, one of another vehicle, or "
    "one whose account was disabled, removed or changed since (send Authorization: Bearer <token>)",
    403: "Forbidden: the token's role may not do this, or the client address is blacklisted "
    "after an abnormal flow of requests (then with Retry-After)",
    404: "Unknown vehicle, or (the users' routes) unknown user",
    409: "Conflict: the user already exists, an admin would disable, delete or demote their own account, or the "
    "vehicle refused the command in its present state",
    413: "Request body too large (any request's: over api.limits.max_body_bytes)",
    422: "Invalid parameters or body: a value outside its documented type, format, range, pattern or "
    "enumeration (the offending ones in `errors`)",
    429: "Rate limited: retry after the Retry-After header's seconds",
    503: "The black box store is unavailable, or (a command) the vehicle's manager did not answer: retry after "
    "the Retry-After header's seconds",
}

STORE_RETRY_AFTER_S = 5  # a store that is down: try again in this long

RETRY_AFTER = {"description": "seconds to wait before trying again", "schema": {"type": "integer", "minimum": 0}}
ERROR_HEADERS = {
    401: {
        "WWW-Authenticate": {
            "description": "the scheme to authenticate with",
            "required": True,
            "schema": {"type": "string", "const": "Bearer"},
        }
    },
    403: {"Retry-After": RETRY_AFTER},
    429: {"Retry-After": {**RETRY_AFTER, "required": True}},
    503: {"Retry-After": {**RETRY_AFTER, "required": True}},
}


def error_responses(*codes: int) -> dict:
    """The `responses` of a route that may answer `codes` (as ApiError)."""
    # any request can be answered 403 (blacklist), 413 (a body too large) and 429 (rate limit)
    return {
        code: {
            "model": ApiError,
            "description": ERROR_DESCRIPTIONS[code],
            **({"headers": ERROR_HEADERS[code]} if code in ERROR_HEADERS else {}),
        }
        for code in sorted({*codes, 403, 413, 429})
    }
