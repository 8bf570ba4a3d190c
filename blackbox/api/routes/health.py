"""GET /health: is the API up, and does its store answer (no authentication: for probes)."""

from fastapi import APIRouter
from fastapi.responses import Response

from blackbox.api.dependencies import Services
from blackbox.api.models import ERROR_HEADERS, STORE_RETRY_AFTER_S, Health, error_responses, json_response
from blackbox.register.store.record_store import StoreUnavailable


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
            return json_response(
                {"status": "degraded", "store": "unavailable", "detail": str(exc)},
                503,
                {"Retry-After": str(STORE_RETRY_AFTER_S)},
            )
        return json_response({"status": "ok", "store": "ok", "detail": None})

    return router
