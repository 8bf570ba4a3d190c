"""POST /vehicles/{id}/rearm: an operator re-arms the shuttle after an emergency stop.

The only way a person outside the vehicle reaches its services, and only with an operator's
token (ARES §3.8: nothing outside may drive the vehicle). The route forwards the request, with
the operator's name, to the movement manager's `movement/rearm` service on the vehicle's bus. The
movement manager decides and records the event with that name. A re-arm it refuses (level 1
still holds, nothing latched) is answered 409 with its reason.
"""
from typing import Annotated

from fastapi import APIRouter, Depends, HTTPException
from fastapi.responses import Response
from pydantic import BaseModel
from starlette.concurrency import run_in_threadpool

from ares.bus import ServiceError
from ares.messages import RearmRequest
from blackbox.api.dependencies import ROLES_COMMAND, Services, allow, vehicle_id_path
from blackbox.api.models import error_responses, json_response
from blackbox.auth import Claims


class CommandReply(BaseModel):
    accepted: bool
    reason: str
    operator: str


def build_router(services: Services) -> APIRouter:
    VehicleId = vehicle_id_path(services.vehicle_id)
    Operator = Annotated[Claims, Depends(allow(services.tokens, *ROLES_COMMAND))]
    router = APIRouter(tags=["commands"])

    @router.post("/vehicles/{vehicle_id}/rearm", response_model=CommandReply,
                 responses=error_responses(401, 404, 409, 422, 503))
    async def rearm(vehicle_id: VehicleId, claims: Operator) -> Response:
        if vehicle_id != services.vehicle_id:
            raise HTTPException(404, f"vehicle {vehicle_id!r} is not this API's: commands go to "
                                     f"{services.vehicle_id!r} only")
        if services.call is None:
            raise HTTPException(503, "this API serves records only: it is not on a vehicle's bus")
        try:
            reply = await run_in_threadpool(services.call, "movement/rearm", RearmRequest(operator=claims.name))
        except ServiceError as exc:
            raise HTTPException(503, f"the movement manager did not answer: {exc}") from None
        body = {"accepted": reply.accepted, "reason": reply.reason, "operator": claims.name}
        return json_response(body, 200 if reply.accepted else 409)

    return router
