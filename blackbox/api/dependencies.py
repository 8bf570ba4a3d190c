"""What route handlers depend on: the application's services, the caller's role (`allow`), and
the path and query parameters several routes share."""

import re
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path as FilePath
from typing import Annotated, Any

from fastapi import HTTPException, Path, Query, Security
from fastapi.security import OAuth2PasswordBearer
from pydantic import AwareDatetime, BeforeValidator
from starlette.concurrency import run_in_threadpool

from ares.core.config import VEHICLE_ID_PATTERN  # what a stack's vehicle id may be: the ids of its records
from blackbox.api.credentials import AuthError, Claims, Passwords, Tokens
from blackbox.api.repository import Repository
from blackbox.api.security import Guard
from blackbox.api.settings import TOKEN_PATH, ApiSettings, LimitSettings
from blackbox.console.live_hub import LiveHub

# who may call what (the roles of ARES §3.9's three GUIs, plus user administration)
ROLES_LIVE = ("fleet", "auditor", "operator")  # vehicles and their latest state
ROLES_RECORDS = ("auditor", "operator")  # browse records
ROLES_EXPORT = ("auditor",)  # export records (the black box interface)
ROLES_EVENTS = ("auditor", "operator", "fleet")  # events and reliability summaries
ROLES_SNAPSHOTS = ("auditor", "operator")  # incident snapshots (an operator: its own vehicle's only)
ROLES_ADMIN = ("admin",)
ROLES_PASSENGER = ("passenger", "operator")  # the passenger's view: the next stop, the doors, why it stands
ROLES_COMMAND = ("operator",)  # the vehicle's services: re-arm, the mission's goal and actions, doors and ramp


# ---- the application's services ------------------------------------------------------------------


@dataclass(frozen=True)
class Services:
    """What the routes work with, built once per application by create_app and handed to each
    route module's build_router: no per-request lookup on the hot paths, no global state (tests
    build as many applications as they like)."""

    repository: Repository
    tokens: Tokens
    passwords: Passwords
    guard: Guard
    settings: ApiSettings
    vehicle_id: str  # the stack's own, the example id of the schema
    # the stack's services on its bus: (name, request) -> reply; None outside a stack (tests of the
    # records alone, `ares api serve` over a store): the command routes then answer 503
    call: Callable[[str, Any], Any] | None = None
    # the vehicle's command key: the command routes sign each command with the operator's name
    # (ares/core/signed_command.py); None without `call`
    command_key: bytes | None = None
    live: LiveHub | None = None  # the live gateway (None outside a stack: its routes answer 503)
    route: dict | None = None  # the vehicle's route for the maps (None outside a stack)
    snapshots: FilePath | None = None  # where the incident snapshots' files are (None: none served)
    # an operator's request for an incident snapshot, onto the vehicle's bus (recording/snapshot_request);
    # None where the vehicle keeps no snapshots (recording.snapshots.enabled false) or outside a stack
    request_snapshot: Callable[[Any], None] | None = None


# ---- authentication ------------------------------------------------------------------------------

bearer = OAuth2PasswordBearer(tokenUrl=TOKEN_PATH, auto_error=False)


def allow(tokens: Tokens, *roles: str) -> Callable:
    """A dependency: the caller's claims when its bearer token is valid, its account still allows
    it (Tokens.verify) and its role is one of `roles`. The account's look-up in the store, when
    due, runs in the thread pool: it never holds up the event loop."""

    async def check(token: Annotated[str | None, Security(bearer)]) -> Claims:
        if not token:
            raise HTTPException(
                401,
                "not authenticated: send Authorization: Bearer <token> (get one at /api/v1/auth/token)",
                headers={"WWW-Authenticate": "Bearer"},
            )
        try:
            claims = tokens.signed_claims(token)
            accounts = tokens.accounts
            if accounts is not None and not accounts.recently_allowed(claims):
                await run_in_threadpool(accounts.check, claims)
        except AuthError as exc:
            raise HTTPException(401, str(exc), headers={"WWW-Authenticate": "Bearer"}) from None
        if claims.role not in roles:
            raise HTTPException(403, f"role {claims.role!r} may not do this (needs {' or '.join(roles)})")
        return claims

    return check


# ---- shared parameters ---------------------------------------------------------------------------

RFC3339 = re.compile(r"(\d{4})-\d\d-\d\d[Tt](\d\d):(\d\d):(\d\d)(?:\.\d+)?(?:[Zz]|([+-])(\d\d):(\d\d))")


def rfc3339(value: Any) -> Any:
    """A query date-time as the schema has it (format date-time: RFC 3339 §5.6, with its offset).
    pydantic alone would also take a number of seconds since 1970 ("0.5"), a date or a space for
    the T, and refuses two things RFC 3339 has: the year 0000 (earlier than anything kept: the
    earliest date-time there is) and a leap second (23:59:60 UTC: the end of its minute)."""
    if not isinstance(value, str):
        return value
    m = RFC3339.fullmatch(value)
    if m is None:
        raise ValueError("not an RFC 3339 date-time with a UTC offset, e.g. 2026-01-31T08:00:00Z")
    if m[1] == "0000":
        return datetime.min.replace(tzinfo=UTC)
    if m[4] == "60":
        offset = (int(m[6]) * 60 + int(m[7])) * (-1 if m[5] == "-" else 1) if m[5] else 0
        if (int(m[2]) * 60 + int(m[3]) - offset) % 1440 != 23 * 60 + 59:
            raise ValueError("a leap second (:60) is 23:59:60 UTC")
        return f"{value[: m.start(4)]}59.999999{value[m.end(0) - (6 if m[5] else 1) :]}"
    return value


Start = Annotated[
    AwareDatetime | None,
    BeforeValidator(rfc3339),
    Query(
        description="window start, inclusive, with a UTC offset (default: end - 1 h). Records are kept 7 days: an "
        "earlier start is served from the oldest kept, and the answer says `clipped`"
    ),
]
End = Annotated[
    AwareDatetime | None,
    BeforeValidator(rfc3339),
    Query(
        description="window end, exclusive (default: now); at or before the start: nothing is served, and the answer "
        "says `clipped`"
    ),
]


# the three below carry the settings into the schema (an example, bounds): route modules that
# use them build their router from the settings (build_router)


def vehicle_id_path(example: str):
    return Annotated[
        str,
        Path(pattern=VEHICLE_ID_PATTERN, examples=[example], description="vehicle id (as in ares/<vehicle_id>/...)"),
    ]


def page_query(limits: LimitSettings):
    return Annotated[int, Query(ge=1, le=limits.max_page, description="page number, from 1")]


def page_size_query(limits: LimitSettings):
    return Annotated[int, Query(ge=1, le=limits.max_page_size, description="items per page")]
