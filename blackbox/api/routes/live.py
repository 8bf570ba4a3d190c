"""The live gateway: the bus state the pages need, streamed as Server-Sent Events under the same
tokens and roles as the rest of the API.

| route                              | roles                      | what                                  |
|------------------------------------|----------------------------|---------------------------------------|
| GET /live/vehicles/{id}            | operator, auditor          | one vehicle, all the operator sees    |
| GET /live/passenger                | passenger, operator        | this vehicle, as a passenger sees it  |
| GET /live/fleet                    | fleet, operator, auditor   | every vehicle on the router, light    |
| GET /fleet                         | fleet, operator, auditor   | the same, once (JSON)                 |
| GET /route                         | fleet, operator, auditor   | this API's vehicle, its route, POIs   |

A stream sends `event: frame` (JSON) at `hz` (at most the gateway's rate_hz) and `event: events`
with the events that arrived since the last frame (the recent ones first). It ends when the
token expires: the page renews its token and opens a new stream. Each user has a few streams
at most (429 beyond); the frames are built from what the bus left in memory, so a slow browser
only slows its own stream. Outside a stack (`ares api` over a store) these routes are not offered.
"""

import asyncio
import time
from typing import Annotated

import orjson
from fastapi import APIRouter, Depends, HTTPException, Query, Request
from fastapi.responses import StreamingResponse

from blackbox.api.credentials import Claims
from blackbox.api.dependencies import ROLES_LIVE, ROLES_PASSENGER, ROLES_RECORDS, Services, allow, vehicle_id_path
from blackbox.api.models import error_responses, json_response
from blackbox.console.live_hub import LiveHub

SSE_HEADERS = {"X-Accel-Buffering": "no", "Cache-Control": "no-store"}


class SlotStream(StreamingResponse):
    """A stream that gives its slot back however it ends: finished, the client gone before the
    first frame (the generator then never runs, so its own `finally` would not), or cancelled."""

    def __init__(self, content, release, **kwargs):
        super().__init__(content, **kwargs)
        self._release = release

    async def __call__(self, scope, receive, send) -> None:
        try:
            await super().__call__(scope, receive, send)
        finally:
            self._release()


def build_router(services: Services) -> APIRouter:
    """The live routes; the app mounts them only on a bus (`services.live`), and /route only where
    the vehicle's route is known: an API over a store alone does not offer them."""
    VehicleId = vehicle_id_path(services.vehicle_id)
    Viewer = Annotated[Claims, Depends(allow(services.tokens, *ROLES_RECORDS))]
    Watcher = Annotated[Claims, Depends(allow(services.tokens, *ROLES_LIVE))]
    if services.live is None:
        raise ValueError("the live routes need the bus's live hub")
    gateway: LiveHub = services.live
    rate = gateway.s.rate_hz
    Hz = Annotated[float, Query(gt=0, le=rate, description=f"frames per second (at most {rate:g})")]
    router = APIRouter(tags=["live"])

    def stream(request: Request, claims: Claims, hz: float, build) -> StreamingResponse:
        refused = gateway.open_stream(claims.name)
        if refused is not None:
            raise HTTPException(429, f"too many live streams: {refused}", headers={"Retry-After": "5"})

        async def frames():
            seq = max(gateway.event_seq - 50, 0)  # a new page sees the recent events
            period = 1.0 / hz
            while time.time() < claims.expires and not await request.is_disconnected():
                started = time.monotonic()
                frame, events = build(seq)
                if events:
                    seq = events[-1]["seq"]
                    yield b"event: events\ndata: " + orjson.dumps(events) + b"\n\n"
                yield b"event: frame\ndata: " + orjson.dumps(frame) + b"\n\n"
                await asyncio.sleep(max(period - (time.monotonic() - started), 0.0))
            yield b"event: expired\ndata: {}\n\n"

        return SlotStream(
            frames(), lambda: gateway.close_stream(claims.name), media_type="text/event-stream", headers=SSE_HEADERS
        )

    @router.get(
        "/live/vehicles/{vehicle_id}",
        responses=error_responses(401, 403, 404, 422, 429),
        response_class=StreamingResponse,
    )
    async def vehicle_stream(request: Request, vehicle_id: VehicleId, claims: Viewer, hz: Hz = rate):
        if not gateway.knows(vehicle_id) and vehicle_id != services.vehicle_id:
            raise HTTPException(404, f"vehicle {vehicle_id!r} is not on this router")

        def build(seq):
            frame = gateway.frame(vehicle_id) or {"vehicle_id": vehicle_id, "wall_ms": time.time() * 1e3}
            return frame, gateway.events_since(seq, vehicle_id)

        return stream(request, claims, hz, build)

    _add_passenger_route(router, services, gateway, stream, Hz)

    @router.get("/live/fleet", responses=error_responses(401, 403, 422, 429), response_class=StreamingResponse)
    async def fleet_stream(request: Request, claims: Watcher, hz: Hz = min(rate, 2.0)):
        def build(seq):
            return {"vehicles": gateway.fleet_frame(), "wall_ms": time.time() * 1e3}, gateway.events_since(seq)

        return stream(request, claims, hz, build)

    @router.get("/fleet", responses=error_responses(401, 403))
    async def fleet(_claims: Watcher):
        """Every vehicle heard lately, once: as a frame of /live/fleet, for scripts and monitors."""
        return json_response({"vehicles": gateway.fleet_frame(), "wall_ms": time.time() * 1e3})

    if services.route is not None:
        known_route = services.route

        @router.get("/route", responses=error_responses(401, 403))
        async def route(_claims: Watcher):
            return json_response({"vehicle_id": services.vehicle_id, **known_route})

    return router


def _add_passenger_route(router: APIRouter, services: Services, gateway: LiveHub, stream, hz_type) -> None:
    """GET /live/passenger: this API's vehicle as a passenger sees it (the passenger page, a kiosk)."""
    Passenger = Annotated[Claims, Depends(allow(services.tokens, *ROLES_PASSENGER))]
    Hz = hz_type
    route_view = services.route or {}
    tour = str(route_view.get("name", ""))
    stops = [str(p["name"]) for p in route_view.get("pois", [])]

    @router.get("/live/passenger", responses=error_responses(401, 403, 422, 429), response_class=StreamingResponse)
    async def passenger_stream(request: Request, claims: Passenger, hz: Hz = min(gateway.s.rate_hz, 2.0)):
        """This API's vehicle as a passenger sees it: the tour, the next stop and the time to it, the
        doors and the ramp, the media, and why the shuttle stands (a key and its English words)."""
        vehicle_id = services.vehicle_id

        def build(_seq):
            frame = gateway.passenger(vehicle_id, tour, stops) or {
                "vehicle_id": vehicle_id,
                "tour": tour,
                "stops": stops,
            }
            return frame, []

        return stream(request, claims, hz, build)
