"""GET /health: is the API up, and does its store answer (no authentication: for probes).

Its callers are anyone who reaches the port, so it says the status and nothing more: the store's
own error (for MongoDB, the servers it tried and their state) goes to the API's log, where the
operator reads it, never into the answer."""

import logging

from fastapi import APIRouter
from fastapi.responses import Response

from blackbox.api.dependencies import Services
from blackbox.api.models import ERROR_HEADERS, STORE_RETRY_AFTER_S, Health, error_responses, json_response
from blackbox.register.store.record_store import StoreUnavailable

log = logging.getLogger("blackbox.api.health")


def build_router(services: Services) -> APIRouter:
    repo = services.repository
    router = APIRouter(tags=["service"])

    @router.get(
        "/health",
        response_model=Health,
        responses={
            **error_responses(),
            503: {"model": Health, "description": "The store is unreachable", "headers": ERROR_HEADERS[503]},
        },
    )
    def health() -> Response:
        try:
            repo.ping()
        except StoreUnavailable as exc:
            log.warning("health: the black box store is unavailable: %s", exc)
            return json_response(
                {"status": "degraded", "store": "unavailable", "detail": None},
                503,
                {"Retry-After": str(STORE_RETRY_AFTER_S)},
            )
        return json_response({"status": "ok", "store": "ok", "detail": None})

    return router
