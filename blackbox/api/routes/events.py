"""GET /vehicles/{id}/events (a page of events, optionally of some kinds) and
GET /vehicles/{id}/reliability (MTBF, MTTR, R(t), availability over a window)."""

from typing import Annotated

from fastapi import APIRouter, Depends, HTTPException, Query
from fastapi.responses import Response

from blackbox.api.credentials import Claims
from blackbox.api.dependencies import (
    ROLES_EVENTS,
    End,
    Services,
    Start,
    allow,
    page_query,
    page_size_query,
    vehicle_id_path,
)
from blackbox.api.models import EventsPage, ReliabilityReport, error_responses, json_response
from blackbox.api.repository import parse_kinds

REPORT_RETRY_AFTER_S = 5  # a week's first report takes seconds; later ones come from the per-day cache


def build_router(services: Services) -> APIRouter:
    """The event routes, with the page bounds, default page size and t_hours bound of the limits."""
    limits = services.settings.limits
    repo = services.repository
    Reader = Annotated[Claims, Depends(allow(services.tokens, *ROLES_EVENTS))]
    VehicleId = vehicle_id_path(services.vehicle_id)
    Page = page_query(limits)
    PageSize = page_size_query(limits)
    router = APIRouter(tags=["events"])

    @router.get(
        "/vehicles/{vehicle_id}/events", response_model=EventsPage, responses=error_responses(401, 404, 422, 503)
    )
    def events(
        vehicle_id: VehicleId,
        _: Reader,
        start: Start = None,
        end: End = None,
        kind: Annotated[
            str | None,
            Query(
                max_length=512, pattern=r"^[A-Za-z0-9_.,-]*$", description="comma-separated event kinds (default: all)"
            ),
        ] = None,
        page: Page = 1,
        page_size: PageSize = limits.default_page_size,
    ) -> Response:
        window = repo.window(start, end)
        repo.require_vehicle(vehicle_id)
        return json_response(repo.events_page(vehicle_id, window, parse_kinds(kind), page, page_size))

    @router.get(
        "/vehicles/{vehicle_id}/reliability",
        response_model=ReliabilityReport,
        responses=error_responses(401, 404, 422, 503),
    )
    def reliability(
        vehicle_id: VehicleId,
        claims: Reader,
        start: Start = None,
        end: End = None,
        t_hours: Annotated[
            float, Query(gt=0, le=limits.max_t_hours, description="mission time t of R(t), hours")
        ] = 1.0,
    ) -> Response:
        window = repo.window(start, end)
        repo.require_vehicle(vehicle_id)
        with services.guard.report_slot(claims.role) as admitted:
            if not admitted:
                raise HTTPException(
                    429,
                    f"as many reliability reports as a {claims.role} may have are being computed: try again shortly",
                    headers={"Retry-After": str(REPORT_RETRY_AFTER_S)},
                )
            report = repo.reliability(vehicle_id, window, t_hours)
        return json_response({**report, "definitions": ReliabilityReport.model_fields["definitions"].default})

    return router
