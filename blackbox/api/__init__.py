"""The black box's REST API (ARES §3.8-3.10): read-only queries over the record store.

`create_app(store, settings)` builds the FastAPI application; `serve(settings, store_uri)` runs
it under uvicorn, over HTTPS unless plain HTTP is asked for explicitly. Route handlers are thin:
they check the caller's role and the parameters, then ask the `Repository` (the only owner of
store calls and caches) and return what it gives.

    settings.py      ApiSettings, LimitSettings, where the API keeps its state, PREFIX
    models.py        response and request models, documented errors, the JSON encoding
    repository.py    Repository: every store call and cache; pages, reports, export files
    dependencies.py  the services routes work with, roles (`allow`), shared parameters
    routes/          one router per resource: health, auth, vehicles, records, events, users
    app.py           create_app: services, middleware, error handlers, routers
    server.py        uvicorn_config, serve

Nothing here writes a record, changes an event or publishes on the bus: the API cannot move
the vehicle or alter what the black box holds. The only writes are users (admin role) and the
API's own security events (an IP blacklisted).

Endpoints, all under /api/v1 (roles: ROLES_* in dependencies.py):

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
