"""The operator's commands, each signed with the operator's name from the validated token (the
vehicle's command key, ares/core/signed_command.py) and forwarded to a manager's service on the
vehicle's bus, which checks the signature, decides and records the event with that signed name:

| route                                      | service                        |
|--------------------------------------------|--------------------------------|
| POST /vehicles/{id}/rearm                  | movement/rearm                 |
| POST /vehicles/{id}/mission                | mission/goal (POIs, a drive)   |
| POST /vehicles/{id}/mission/{action}       | mission/pause, resume, cancel  |
| POST /vehicles/{id}/body                   | mission/body (doors, ramp)     |
| POST /vehicles/{id}/snapshots              | recording/snapshot_request (published) |

(a snapshot's request has no answer but the recorder's `snapshot` event that lists the file)

The only way a person outside the vehicle reaches its services, and only with an operator's
token (ARES §3.8: nothing outside may drive the vehicle: a goal, a pause, a re-arm are requests
the managers may refuse). A refusal is answered 409 with the manager's reason.
"""

import uuid
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Depends, HTTPException
from fastapi.responses import Response
from pydantic import BaseModel, ConfigDict, Field, model_validator
from starlette.concurrency import run_in_threadpool

from ares.core.bus import ServiceError
from ares.core.messages import BodyRequest, MissionGoal, MissionRequest, Msg, RearmRequest, SnapshotRequest
from ares.core.signed_command import sign
from blackbox.api.credentials import Claims
from blackbox.api.dependencies import ROLES_COMMAND, Services, allow, vehicle_id_path
from blackbox.api.models import error_responses, json_response


class CommandReply(BaseModel):
    accepted: bool
    reason: str
    operator: str
    goal_id: int | None = None  # mission commands: the goal concerned
    state: str | None = None  # ... and the mission's state after


class GoalBody(BaseModel):
    """A mission goal: the POIs in order, every POI of the route ahead (null), or a drive (no POIs)."""

    # the schema says what the check below says: a drive names no POIs
    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "not": {"required": ["drive", "pois"], "properties": {"drive": {"const": True}, "pois": {"type": "array"}}}
        },
    )

    pois: list[str] | None = None
    drive: bool = False
    repeat: bool = False

    @model_validator(mode="after")
    def _a_drive_names_no_pois(self) -> "GoalBody":
        if self.drive and self.pois is not None:
            raise ValueError("a drive goal has no POIs")
        return self


class BodyBody(BaseModel):
    """The doors and the ramp: open or close, deploy or stow (null or absent: leave as it is; one of
    them at least)."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "anyOf": [
                {"required": ["doors"], "properties": {"doors": {"type": "string"}}},
                {"required": ["ramp"], "properties": {"ramp": {"type": "string"}}},
            ]
        },
    )

    doors: Literal["open", "close"] | None = None
    ramp: Literal["deploy", "stow"] | None = None

    @model_validator(mode="after")
    def _something_asked(self) -> "BodyBody":
        if self.doors is None and self.ramp is None:
            raise ValueError("ask something of the doors or the ramp")
        return self


class SnapshotBody(BaseModel):
    """Why the operator asks for an incident snapshot (kept in the snapshot's event)."""

    model_config = ConfigDict(extra="forbid")

    reason: str = Field(default="", max_length=200)


class SnapshotAsked(CommandReply):
    request_id: str = Field(description="the `snapshot` event that lists the file carries it in its data")


def command_responses(*codes: int) -> dict:
    """A command's error answers, and its refusal: 409 with the manager's reason (a CommandReply)."""
    responses = error_responses(*codes)
    responses[409] = {"model": CommandReply, "description": "The manager refused the command: its reason"}
    return responses


COMMAND_RETRY_AFTER_S = 2  # a manager that did not answer is being restarted by the supervisor


def build_router(services: Services) -> APIRouter:
    VehicleId = vehicle_id_path(services.vehicle_id)
    Operator = Annotated[Claims, Depends(allow(services.tokens, *ROLES_COMMAND))]
    router = APIRouter(tags=["commands"])
    if services.call is None:
        raise ValueError("the command routes need the vehicle's bus (services.call)")
    call = services.call
    if services.command_key is None:
        raise ValueError("the command routes need the vehicle's command key (services.command_key)")
    key = services.command_key

    async def forward(vehicle_id: str, service: str, request: Msg, who: str, manager: str) -> Response:
        if vehicle_id != services.vehicle_id:
            raise HTTPException(
                404, f"vehicle {vehicle_id!r} is not this API's: commands go to {services.vehicle_id!r} only"
            )
        try:
            reply = await run_in_threadpool(call, service, sign(key, service, request, who))
        except ServiceError as exc:
            raise HTTPException(
                503, f"the {manager} did not answer: {exc}", headers={"Retry-After": str(COMMAND_RETRY_AFTER_S)}
            ) from None
        body = {"accepted": reply.accepted, "reason": reply.reason, "operator": who}
        if hasattr(reply, "goal_id"):
            body.update(goal_id=reply.goal_id, state=reply.state)
        return json_response(body, 200 if reply.accepted else 409)

    @router.post(
        "/vehicles/{vehicle_id}/rearm",
        response_model=CommandReply,
        responses=command_responses(401, 404, 409, 422, 503),
    )
    async def rearm(vehicle_id: VehicleId, claims: Operator) -> Response:
        return await forward(
            vehicle_id, "movement/rearm", RearmRequest(operator=claims.name), claims.name, "movement manager"
        )

    @router.post(
        "/vehicles/{vehicle_id}/mission",
        response_model=CommandReply,
        responses=command_responses(400, 401, 404, 409, 422, 503),
    )
    async def mission_goal(vehicle_id: VehicleId, goal: GoalBody, claims: Operator) -> Response:
        request = MissionGoal(operator=claims.name, pois=goal.pois, drive=goal.drive, repeat=goal.repeat)
        return await forward(vehicle_id, "mission/goal", request, claims.name, "mission manager")

    @router.post(
        "/vehicles/{vehicle_id}/mission/{action}",
        response_model=CommandReply,
        responses=command_responses(401, 404, 409, 422, 503),
    )
    async def mission_action(
        vehicle_id: VehicleId, action: Literal["pause", "resume", "cancel"], claims: Operator
    ) -> Response:
        return await forward(
            vehicle_id, f"mission/{action}", MissionRequest(operator=claims.name), claims.name, "mission manager"
        )

    @router.post(
        "/vehicles/{vehicle_id}/body",
        response_model=CommandReply,
        responses=command_responses(400, 401, 404, 409, 422, 503),
    )
    async def body(vehicle_id: VehicleId, asked: BodyBody, claims: Operator) -> Response:
        request = BodyRequest(operator=claims.name, doors=asked.doors, ramp=asked.ramp)
        return await forward(vehicle_id, "mission/body", request, claims.name, "mission manager")

    add_snapshot_request(router, services, VehicleId, Operator)
    return router


def add_snapshot_request(router: APIRouter, services: Services, VehicleId: Any, Operator: Any) -> None:
    """POST /vehicles/{id}/snapshots: an operator's request for an incident snapshot, published to
    the vehicle's recorder (no manager decides it: the recorder's `snapshot` event lists the file)."""

    @router.post(
        "/vehicles/{vehicle_id}/snapshots",
        response_model=SnapshotAsked,
        status_code=202,
        responses=command_responses(400, 401, 404, 409, 422),
    )
    async def snapshot(vehicle_id: VehicleId, asked: SnapshotBody, claims: Operator) -> Response:
        if vehicle_id != services.vehicle_id:
            raise HTTPException(
                404, f"vehicle {vehicle_id!r} is not this API's: requests go to {services.vehicle_id!r} only"
            )
        body = {"operator": claims.name, "request_id": uuid.uuid4().hex[:12]}
        if services.request_snapshot is None:
            reason = "this vehicle keeps no incident snapshots (recording.snapshots.enabled is false)"
            return json_response({**body, "accepted": False, "reason": reason}, 409)
        request = SnapshotRequest(
            t=services.repository.stack_time(),
            requested_by=claims.name,
            reason=asked.reason,
            request_id=body["request_id"],
        )
        await run_in_threadpool(services.request_snapshot, request)
        reason = "asked for: the black box lists the snapshot once its seconds after are saved"
        return json_response({**body, "accepted": True, "reason": reason}, 202)
