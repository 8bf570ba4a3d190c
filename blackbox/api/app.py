"""create_app: the FastAPI application over a record store, its services, middleware, error
handlers and routers."""

import logging
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.middleware.cors import CORSMiddleware
from fastapi.responses import JSONResponse
from fastapi.routing import APIRoute
from starlette.concurrency import run_in_threadpool

from ares.core.clock import Clock
from blackbox.api.credentials import Accounts, Passwords, Tokens, load_secret
from blackbox.api.dependencies import Services
from blackbox.api.models import STORE_RETRY_AFTER_S
from blackbox.api.repository import Repository
from blackbox.api.routes import auth, commands, events, health, pages, records, snapshots, users, vehicles
from blackbox.api.routes import live as live_routes
from blackbox.api.security import BAN_FILE, Guard, SecurityMiddleware, security_headers
from blackbox.api.settings import PREFIX, TOKEN_PATH, ApiSettings, state_dir
from blackbox.console.live_hub import LiveHub
from blackbox.register.store.record_store import RecordStore, StoreUnavailable

log = logging.getLogger(__name__)


def create_app(
    store: RecordStore,
    settings: ApiSettings,
    vehicle_id: str,
    clock: Clock | None = None,
    call: Callable[[str, Any], Any] | None = None,
    live: LiveHub | None = None,
    route: dict | None = None,
    command_key: bytes | None = None,
    snapshots_dir: Path | None = None,
    request_snapshot: Callable[[Any], None] | None = None,
) -> FastAPI:
    """The API over `store`, serving the black box of `vehicle_id` (whose events the API's own events
    are; stack time from `clock`); `call`: the stack's services on its bus (blocking; the command
    routes run it in a thread); `live`: the bus state for the pages; `route`: the vehicle's route
    for their maps; `command_key`: the vehicle's, with which the command routes sign each command
    (needed with `call`); `request_snapshot`: publishes an operator's SnapshotRequest to the
    vehicle's recorder (None: the vehicle keeps no snapshots). Holds no global state: tests build
    as many as they like."""
    sdir = state_dir(settings, store)
    services = Services(
        repository=Repository(store, settings.limits, vehicle_id, (clock or Clock.from_env()).now),
        tokens=Tokens(
            settings.auth, load_secret(settings.auth, sdir), vehicle_id, Accounts(store, settings.auth.account_cache_s)
        ),
        passwords=Passwords(settings.auth.argon2),
        guard=Guard(settings.rate_limit, settings.blacklist, ban_file=sdir / BAN_FILE),
        settings=settings,
        vehicle_id=vehicle_id,
        call=call,
        command_key=command_key,
        live=live,
        route=route,
        snapshots=snapshots_dir,
        request_snapshot=request_snapshot,
    )

    app = FastAPI(
        title="ARES black box API",
        version="1",
        description="The shuttle's black box: records of the last 7 days, events, reliability figures "
        "(never altered through the API), the vehicle's live state, and the operator's commands (operator "
        "role: a mission goal, pause, resume, cancel, doors and ramp to the mission manager, a re-arm to the "
        "movement manager, each forwarded to that manager's service on the vehicle's bus, which may refuse "
        "it: 409). Authenticate at /api/v1/auth/token (OAuth2 password form) and "
        "send the token as `Authorization: Bearer <token>`; renew it before it expires. A method "
        "a path does not have is answered 405 with an `Allow` header listing those it has.",
        docs_url="/docs" if settings.docs else None,
        redoc_url="/redoc" if settings.docs else None,
        telemetry={"tracing": False, "metrics": False, "logs": False, "operation_spans": False},
        max_body_size=settings.limits.max_body_bytes,
        # the login form: a few fields, none over what its schema allows (256 characters of up to 4 bytes,
        # percent-encoded: 3 kB)
        form_limits={"max_fields": 8, "max_files": 0, "max_part_size": 4096},
    )
    app.state.services = services
    app.state.state_dir = sdir  # the TLS certificate's home (blackbox.api.uvicorn_server)

    add_middleware(app, settings, services)
    app.add_exception_handler(StoreUnavailable, store_down)
    app.add_exception_handler(RequestValidationError, invalid)

    include_routes(app, services, commands_offered=call is not None, live_offered=live is not None)
    pages.mount(app)
    return app


def add_middleware(app: FastAPI, settings: ApiSettings, services: Services) -> None:
    """CORS where origins are configured, then the security middleware (rate limits, the blacklist,
    the headers)."""
    if settings.cors_origins:
        app.add_middleware(
            CORSMiddleware,
            allow_origins=settings.cors_origins,
            allow_methods=["GET", "POST"],
            allow_headers=["Authorization", "Content-Type"],
            allow_credentials=False,
            max_age=600,
        )
    # added last: outermost, so refusals and CORS answers carry the security headers too;
    # the blacklisting is stored off the event loop
    app.add_middleware(
        SecurityMiddleware,
        guard=services.guard,
        headers=security_headers(settings.headers),
        page_headers=security_headers(settings.headers, page=True),
        page_paths=pages.PAGE_PATHS,
        page_prefixes=pages.PAGE_PREFIXES,
        token_path=TOKEN_PATH,
        on_blacklist=partial(run_in_threadpool, services.repository.record_blacklisting),
    )


def include_routes(app: FastAPI, services: Services, *, commands_offered: bool, live_offered: bool) -> None:
    """Every resource's router under PREFIX, and a 405 with `Allow` for the methods a path lacks."""
    methods: dict[str, set[str]] = {}  # path -> its methods
    # what this API can serve where it runs: the commands need the vehicle's bus, the live routes
    # its live hub; an API over a store alone offers neither (not a 503: they are not in its schema)
    offered = [health, auth, vehicles, records, events, snapshots, users]
    if commands_offered:
        offered.append(commands)
    if live_offered:
        offered.append(live_routes)
    for routes in offered:
        router = routes.build_router(services)
        app.include_router(router, prefix=PREFIX)
        for route in router.routes:
            if isinstance(route, APIRoute):
                methods.setdefault(PREFIX + route.path, set()).update(route.methods)
    answer_other_methods(app, methods)


def answer_other_methods(app: FastAPI, methods: dict[str, set[str]]) -> None:
    """A method that a path of the API does not have gets 405 with an `Allow` header that lists
    exactly the methods the path has (those of the schema). Left to itself, Starlette answers
    with the methods of the path's first route only (GET for /users, which has POST too)."""
    for path, allowed in methods.items():
        # after the path's own routes, for any method (an ASGI endpoint: Starlette gives it no
        # method list): reached only when none of the path's routes took the request
        app.router.add_route(path, MethodNotAllowed(", ".join(sorted(allowed))), include_in_schema=False)


class MethodNotAllowed:
    """ASGI endpoint: 405 with the path's Allow header."""

    def __init__(self, allow: str):
        self.allow = allow

    async def __call__(self, scope, receive, send) -> None:
        response = JSONResponse(
            {"detail": f"method {scope['method']} not allowed here (allowed: {self.allow})"},
            status_code=405,
            headers={"Allow": self.allow},
        )
        await response(scope, receive, send)


# ---- errors: one shape for all -------------------------------------------------------------------


async def store_down(_request: Request, exc: StoreUnavailable) -> JSONResponse:
    log.warning("store unavailable: %s", exc)
    return JSONResponse(
        {"detail": "the black box store is unavailable; retry later"},
        status_code=503,
        headers={"Retry-After": str(STORE_RETRY_AFTER_S)},
    )


async def invalid(_request: Request, exc: RequestValidationError) -> JSONResponse:
    problems = [
        {
            "loc": [str(p) if not isinstance(p, int) else p for p in e.get("loc", ())],
            "msg": str(e.get("msg", "")),
            "type": str(e.get("type", "")),
        }
        for e in exc.errors()
    ]
    first = problems[0] if problems else None
    where = ".".join(str(p) for p in first["loc"][1:]) if first else ""
    detail = f"invalid {where or 'request'}: {first['msg']}" if first else "invalid request"
    return JSONResponse({"detail": detail, "errors": problems}, status_code=422)
