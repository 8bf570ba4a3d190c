"""GET /vehicles/{id}/records (a page of records, optionally a selection of their fields) and
GET /vehicles/{id}/export (every record of a window as a streamed CSV or JSON Lines file)."""

from typing import Annotated, Literal

from fastapi import APIRouter, Depends, Query
from fastapi.responses import Response, StreamingResponse

from blackbox.api.credentials import Claims
from blackbox.api.dependencies import (
    ROLES_EXPORT,
    ROLES_RECORDS,
    End,
    Services,
    Start,
    allow,
    page_query,
    page_size_query,
    vehicle_id_path,
)
from blackbox.api.models import CLIPPED_DOC, WINDOW_DOC, RecordsPage, error_responses, iso_utc
from blackbox.api.repository import RECORD_FIELDS, parse_fields

EXPORT_RESPONSE = {
    "description": "Records of the window, oldest first: JSON Lines (one VehicleRecord per line) or CSV "
    "(position flattened; scores, sensors and processes as JSON cells). Streamed: a store "
    "failure mid-way cuts it short. The window served is in the headers.",
    "content": {"application/x-ndjson": {"schema": {"type": "string"}}, "text/csv": {"schema": {"type": "string"}}},
    "headers": {
        "X-Window-Start": {
            "description": WINDOW_DOC,
            "required": True,
            "schema": {"type": "string", "format": "date-time"},
        },
        "X-Window-End": {
            "description": "end of the window served (exclusive)",
            "required": True,
            "schema": {"type": "string", "format": "date-time"},
        },
        "X-Window-Clipped": {"description": CLIPPED_DOC, "required": True, "schema": {"type": "boolean"}},
    },
}

# `fields` as the schema says it: an array of record field names, sent comma-separated
# (style form, not exploded). FastAPI reads the string (not shown in the schema: this is), and
# parse_fields checks it against this.
FIELDS_PARAMETER = {
    "name": "fields",
    "in": "query",
    "required": False,
    "style": "form",
    "explode": False,
    "description": "the record fields to return, comma-separated, each once (the time is always included; "
    "left out: every field; present, it names at least one)",
    "schema": {
        "type": "array",
        "items": {"type": "string", "enum": list(RECORD_FIELDS)},
        "uniqueItems": True,
        "minItems": 1,
        "maxItems": len(RECORD_FIELDS),
    },
}


def build_router(services: Services) -> APIRouter:
    """The record routes, with the page bounds and default page size of the limits."""
    limits = services.settings.limits
    repo = services.repository
    Reader = Annotated[Claims, Depends(allow(services.tokens, *ROLES_RECORDS))]
    Exporter = Annotated[Claims, Depends(allow(services.tokens, *ROLES_EXPORT))]
    VehicleId = vehicle_id_path(services.vehicle_id)
    Page = page_query(limits)
    PageSize = page_size_query(limits)
    router = APIRouter(tags=["records"])

    @router.get(
        "/vehicles/{vehicle_id}/records",
        response_model=RecordsPage,
        responses=error_responses(401, 404, 422, 503),
        openapi_extra={"parameters": [FIELDS_PARAMETER]},
    )
    def records(
        vehicle_id: VehicleId,
        _: Reader,
        start: Start = None,
        end: End = None,
        fields: Annotated[str | None, Query(max_length=512, include_in_schema=False)] = None,
        page: Page = 1,
        page_size: PageSize = limits.default_page_size,
    ) -> Response:
        chosen = parse_fields(fields)
        window = repo.window(start, end)
        repo.require_vehicle(vehicle_id)
        return Response(repo.records_page(vehicle_id, window, page, page_size, chosen), media_type="application/json")

    @router.get(
        "/vehicles/{vehicle_id}/export",
        response_class=StreamingResponse,
        responses={200: EXPORT_RESPONSE, **error_responses(401, 404, 422, 503)},
    )
    def export(
        vehicle_id: VehicleId,
        _: Exporter,
        start: Start = None,
        end: End = None,
        format: Annotated[Literal["jsonl", "csv"], Query(description="jsonl or csv")] = "jsonl",
    ) -> StreamingResponse:
        window = repo.window(start, end)
        repo.require_vehicle(vehicle_id)  # also: the store answers, before the 200 is committed
        stamp = f"{window.start:%Y%m%dT%H%M%SZ}_{window.end:%Y%m%dT%H%M%SZ}"
        safe_id = "".join(c if c.isalnum() or c in "-_." else "_" for c in vehicle_id)
        media = "text/csv" if format == "csv" else "application/x-ndjson"
        return StreamingResponse(
            repo.export(vehicle_id, window, format),
            media_type=media,
            headers={
                "Content-Disposition": f'attachment; filename="{safe_id}_{stamp}.{format}"',
                "X-Window-Start": iso_utc(window.start),
                "X-Window-End": iso_utc(window.end),
                "X-Window-Clipped": "true" if window.clipped else "false",
            },
        )

    return router
