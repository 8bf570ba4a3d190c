"""GET /vehicles/{id}/snapshots (the incident snapshots: their `snapshot` events, each with whether
its file is still kept) and GET /vehicles/{id}/snapshots/{name} (the MCAP file, streamed).

An auditor reads any vehicle's; an operator only the vehicle whose API this is (the one it
commands): another vehicle's snapshot is 403. A file is served only when the vehicle's black box
holds the `snapshot` event that names it (the name alone, or a vehicle's id in it, proves nothing).
A vehicle's files are in the snapshots folder; the fleet's copies of them in a folder per vehicle
within it (blackbox/fleet/snapshot_copy.py), looked in first."""

from collections.abc import Iterator
from pathlib import Path as FilePath
from typing import Annotated

from fastapi import APIRouter, Depends, HTTPException, Path
from fastapi.responses import Response, StreamingResponse

from blackbox.api.credentials import Claims
from blackbox.api.dependencies import (
    ROLES_SNAPSHOTS,
    End,
    Services,
    Start,
    allow,
    page_query,
    page_size_query,
    vehicle_id_path,
)
from blackbox.api.models import SnapshotsPage, error_responses, json_response
from blackbox.api.settings import PREFIX
from blackbox.register import snapshot_files

CHUNK_BYTES = 1 << 20
SNAPSHOT_RESPONSE = {
    "description": "The snapshot's MCAP file (the bus around the event: clouds on their sensor's grid, "
    "Foxglove's views), streamed",
    "content": {"application/octet-stream": {"schema": {"type": "string", "format": "binary"}}},
}


def build_router(services: Services) -> APIRouter:
    limits = services.settings.limits
    repo = services.repository
    Reader = Annotated[Claims, Depends(allow(services.tokens, *ROLES_SNAPSHOTS))]
    VehicleId = vehicle_id_path(services.vehicle_id)
    Page = page_query(limits)
    PageSize = page_size_query(limits)
    Name = Annotated[str, Path(pattern=snapshot_files.NAME.pattern, description="the snapshot's file name")]
    folder = services.snapshots
    router = APIRouter(tags=["snapshots"])

    def may_read(claims: Claims, vehicle_id: str) -> None:
        if claims.role == "operator" and vehicle_id != services.vehicle_id:
            raise HTTPException(
                403, f"an operator reads the snapshots of the vehicle it commands ({services.vehicle_id}) only"
            )

    @router.get(
        "/vehicles/{vehicle_id}/snapshots",
        response_model=SnapshotsPage,
        responses=error_responses(401, 404, 422, 503),
    )
    def snapshots(
        vehicle_id: VehicleId,
        claims: Reader,
        start: Start = None,
        end: End = None,
        page: Page = 1,
        page_size: PageSize = limits.default_page_size,
    ) -> Response:
        may_read(claims, vehicle_id)
        window = repo.window(start, end)
        repo.require_vehicle(vehicle_id)
        listed = repo.events_page(vehicle_id, window, ["snapshot"], page, page_size)
        entries = []
        for event in listed.pop("events"):
            name = str((event.get("data") or {}).get("file", ""))
            kept = _kept(folder, vehicle_id, name) is not None
            entries.append({**event, "available": kept, "download": _download(vehicle_id, name)})
        return json_response({**listed, "snapshots": entries})

    @router.get(
        "/vehicles/{vehicle_id}/snapshots/{name}",
        response_class=StreamingResponse,
        responses={200: SNAPSHOT_RESPONSE, **error_responses(401, 404, 422, 503)},
    )
    def snapshot(vehicle_id: VehicleId, name: Name, claims: Reader) -> StreamingResponse:
        may_read(claims, vehicle_id)
        repo.require_vehicle(vehicle_id)
        if repo.snapshot_event(vehicle_id, name) is None:
            raise HTTPException(404, f"vehicle {vehicle_id} has no snapshot {name!r} in its black box")
        path = _kept(folder, vehicle_id, name)
        if path is None:
            raise HTTPException(
                404, f"snapshot {name!r} is listed, but its file is not kept here (not yet copied, or gone)"
            )
        return StreamingResponse(
            _chunks(path),
            media_type="application/octet-stream",
            headers={
                "Content-Disposition": f'attachment; filename="{name}"',
                "Content-Length": str(path.stat().st_size),
            },
        )

    return router


def _kept(folder: FilePath | None, vehicle_id: str, name: str) -> FilePath | None:
    """The snapshot's file: the fleet's copy (in the vehicle's folder), else the vehicle's own; None if neither."""
    if folder is None:
        return None
    try:
        for path in (snapshot_files.path_of(folder / vehicle_id, name), snapshot_files.path_of(folder, name)):
            if path.is_file():
                return path
    except snapshot_files.SnapshotNameError:
        pass
    return None


def _download(vehicle_id: str, name: str) -> str:
    return f"{PREFIX}/vehicles/{vehicle_id}/snapshots/{name}"


def _chunks(path: FilePath) -> Iterator[bytes]:
    with open(path, "rb") as f:
        while chunk := f.read(CHUNK_BYTES):
            yield chunk
