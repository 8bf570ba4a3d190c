"""The black box's REST API (ARES §3.8-3.10): queries over the record store, the live state
for the pages, and the operator's commands, forwarded to the managers' services on the bus.

`create_app(store, settings, vehicle_id, ...)` builds the FastAPI application; `serve(settings,
store_uri)` runs it under uvicorn, over HTTPS unless plain HTTP is asked for explicitly. Route
handlers are thin: they check the caller's role and the parameters, then ask the `Repository`
(the only owner of store calls and caches), the live gateway or the bus, and return what it gives.

    settings.py        ApiSettings, LimitSettings, where the API keeps its state, PREFIX
    models.py          response and request models, documented errors, the JSON encoding
    repository.py      Repository: every store call and cache; pages, reports, export files
    dependencies.py    the services routes work with, roles (ROLES_*, `allow`), shared parameters
    credentials.py     passwords (argon2) and tokens (JWT); first_logins.py: one user per page
    security.py        rate limits, the blacklist and account locks (kept across restarts), report
                       slots per role, security headers
    live_hub.py        the live gateway: the bus state the pages show, kept in memory
    routes/            one router per resource: health, auth, vehicles, records, events, snapshots,
                       users, commands, live, pages
    app.py             create_app: services, middleware, error handlers, routers
    uvicorn_server.py  uvicorn_config, serve; tls.py: the self-signed certificate
    connections.py     what a caller's connections may hold: a cap per address, TLS handshake,
                       header and read timeouts (uvicorn's protocols, wrapped)
    api_node.py        the `api` process of the stack (serves this on the vehicle's bus)

What the API writes to the store: users (admin role; `ares run` makes the first ones on an empty
store, first_logins.py) and its own security events (an IP blacklisted), added to the others.
It never alters or deletes a record or an event. What it sends to the vehicle: an operator's
commands (operator role only, routes/commands.py), each forwarded with the operator's name to a
manager's service, which decides (a refusal is answered 409 with its reason) and records the
event: a re-arm to the movement manager (`movement/rearm`); a mission goal, pause, resume,
cancel, and the doors and ramp to the mission manager (`mission/goal`,
`mission/pause|resume|cancel`, `mission/body`). Besides those service calls, the `api` process
publishes only what every process does (its heartbeat, its own events): no command reaches the
drive-by-wire bridge but through the managers. Outside a stack (`ares api`, no bus) the command
and live routes answer 503.

Endpoints, all under /api/v1 (roles: ROLES_* in dependencies.py):

    GET  /health                                   no auth: status and store reachability
    POST /auth/token                               OAuth2 password form -> bearer token (15 min)
    POST /auth/renew                               valid token of an account that allows it -> fresh token
    POST /auth/revoke                              the token refused from then on (a logout)
    GET  /vehicles                                 fleet, auditor, operator
    GET  /vehicles/{id}/latest                     fleet, auditor, operator
    GET  /vehicles/{id}/records?start&end&fields&page&page_size     auditor, operator
    GET  /vehicles/{id}/export?start&end&format=jsonl|csv          auditor (streamed)
    GET  /vehicles/{id}/events?start&end&kind&page&page_size       auditor, operator, fleet
    GET  /vehicles/{id}/reliability?start&end&t_hours              auditor, operator, fleet
    GET  /vehicles/{id}/snapshots?start&end&page&page_size          auditor, operator (its own vehicle's)
    GET  /vehicles/{id}/snapshots/{name}           auditor, operator (its own vehicle's): the MCAP file, streamed
    POST /vehicles/{id}/rearm                      operator
    POST /vehicles/{id}/mission                    operator (a goal: POIs, or a drive)
    POST /vehicles/{id}/mission/{pause|resume|cancel}              operator
    POST /vehicles/{id}/body                       operator (doors, ramp)
    POST /vehicles/{id}/snapshots                  operator (an incident snapshot now, published to the recorder)
    GET  /live/vehicles/{id}                       operator, auditor (Server-Sent Events)
    GET  /live/fleet                               fleet, operator, auditor (Server-Sent Events)
    GET  /fleet                                    fleet, operator, auditor (the same, once)
    GET  /route                                    fleet, operator, auditor
    GET  /users, POST /users                       admin
    PUT  /users/{name}/role|password               admin (every token the user holds is refused)
    POST /users/{name}/disable|enable, DELETE /users/{name}     admin (not on their own account)

The pages (/operator, /blackbox, /fleet) and their files are served outside /api/v1 (routes/pages.py).
"""

from blackbox.api.app import create_app
from blackbox.api.repository import CSV_COLUMNS, RECORD_FIELDS
from blackbox.api.settings import PREFIX, TOKEN_PATH, ApiSettings, LimitSettings
from blackbox.api.uvicorn_server import serve, uvicorn_config

__all__ = [
    "create_app",
    "serve",
    "uvicorn_config",
    "ApiSettings",
    "LimitSettings",
    "PREFIX",
    "TOKEN_PATH",
    "CSV_COLUMNS",
    "RECORD_FIELDS",
]
