"""GET /vehicles (the fleet the black box holds) and GET /vehicles/{id}/latest (a vehicle's
latest record)."""

from typing import Annotated

from fastapi import APIRouter, Depends, HTTPException
from fastapi.responses import Response
from starlette.concurrency import run_in_threadpool

from ares.core.messages import VehicleRecord
from blackbox.api.credentials import Claims
from blackbox.api.dependencies import ROLES_LIVE, Services, allow, vehicle_id_path
from blackbox.api.models import VehicleList, error_responses, json_response


def build_router(services: Services) -> APIRouter:
    """The vehicle routes, with the stack's own vehicle as the example id."""
    VehicleId = vehicle_id_path(services.vehicle_id)
    Live = Annotated[Claims, Depends(allow(services.tokens, *ROLES_LIVE))]
    repo = services.repository
    router = APIRouter(tags=["vehicles"])

    @router.get("/vehicles", response_model=VehicleList, responses=error_responses(401, 503))
    def vehicles(_: Live) -> Response:
        return json_response({"vehicles": repo.vehicle_summaries()})

    @router.get(
        "/vehicles/{vehicle_id}/latest", response_model=VehicleRecord, responses=error_responses(401, 404, 422, 503)
    )
    async def latest(vehicle_id: VehicleId, _: Live) -> Response:
        # the hot path of every dashboard: a cache hit stays on the event loop, no thread hop
        hit = repo.cached_latest(vehicle_id) or await run_in_threadpool(repo.latest, vehicle_id)
        if hit is None:
            raise HTTPException(404, f"unknown vehicle {vehicle_id!r}: no record of it in the black box")
        return Response(hit[0], media_type="application/json")

    return router
