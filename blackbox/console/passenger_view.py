"""What a passenger sees of the shuttle (the passenger page, /passenger), from the live gateway's
latest messages: the tour's stops, the next one and the time to it, the doors and the ramp, the
media, and why the shuttle stands when it stands for a reason. Nothing else of the vehicle: no
position, no processes, no events (a kiosk's token reads only this).

The reason is a key the page says in the passenger's language (`MESSAGES` holds the English):

| key          | when                                                              |
|--------------|-------------------------------------------------------------------|
| emergency    | the movement gate holds a latched emergency stop                  |
| obstacle     | the obstacle manager's limit is the one that holds the shuttle    |
| intersection | the mission stands the shuttle at a marked intersection           |
| paused       | the operator paused the mission                                   |
| at_stop      | at a stop: the doors, the ramp (the stop's name is beside it)      |
| waiting      | standing for anything else (the road, a restart, a slow start)    |
| none         | moving, or no mission                                             |
"""

from __future__ import annotations

from ares.core.messages import BodyState, MissionStatus, MovementStatus

MESSAGES = {
    "emergency": "Emergency stop. Please stay seated: the staff have been told.",
    "obstacle": "Something is on the road ahead: we wait until it is clear.",
    "intersection": "Stopping at the crossing before we go on.",
    "paused": "The shuttle is paused by the operator.",
    "at_stop": "We are at the stop.",
    "waiting": "Waiting for the road: we go on shortly.",
    "none": "",
}
STANDING_MPS = 0.1


def stop_reason(
    speed_mps: float | None,
    mission: MissionStatus | None,
    movement: MovementStatus | None,
    full_stop_at: float | None,
) -> str:
    """The key of why the shuttle stands (or "none"); `full_stop_at`: the line of the mission's
    intersection stop now under way, if any."""
    if movement is not None and movement.latched:
        return "emergency"
    if mission is not None and mission.state == "PAUSED":
        return "paused"
    if mission is not None and mission.state == "AT_POI":
        return "at_stop"
    standing = speed_mps is not None and abs(speed_mps) < STANDING_MPS
    if movement is not None and movement.limited_by == "obstacle" and (movement.limit_mps or 0.0) < 1.0:
        return "obstacle"  # the obstacle manager slows or holds it: said before it stands
    if not standing or mission is None or mission.state != "DRIVING":
        return "none"
    if full_stop_at is not None:
        return "intersection"
    return "waiting"


def passenger_frame(
    vehicle_id: str,
    tour: str,
    stops: list[str],
    speed_mps: float | None,
    mission: MissionStatus | None,
    movement: MovementStatus | None,
    body: BodyState | None,
    full_stop_at: float | None,
    wall_ms: float,
) -> dict:
    """The passenger's view: the tour, its stops, the next stop, the doors, the media, the reason."""
    eta = None
    if mission is not None and mission.eta_s is not None:
        eta = max(mission.eta_s - mission.t, 0.0)
    reason = stop_reason(speed_mps, mission, movement, full_stop_at)
    return {
        "vehicle_id": vehicle_id,
        "tour": tour,
        "stops": stops,
        "next_stop": None if mission is None or mission.kind != "tour" else mission.poi,
        "at_stop": mission is not None and mission.state == "AT_POI",
        "eta_s": None if eta is None else round(eta),
        "distance_m": None if mission is None or mission.distance_m is None else round(mission.distance_m),
        "doors": None if body is None else body.doors,
        "ramp": None if body is None else body.ramp,
        "media": bool(body is not None and body.media),
        "moving": speed_mps is not None and abs(speed_mps) >= STANDING_MPS,
        "reason": reason,
        "message": MESSAGES[reason],
        "wall_ms": wall_ms,
    }
