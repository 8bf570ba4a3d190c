"""The passenger's view (blackbox/console/passenger_view.py) and its stream (GET /live/passenger):
every reason the page gives for a standing shuttle, the next stop and the time to it, the doors
and the media; a passenger's token reads that stream and nothing else of the vehicle. In a real
browser during a run: tests/test_pages_stack.py."""

from __future__ import annotations

import pytest

from ares.core.messages import BodyState, Event, MovementStatus
from blackbox.console.passenger_view import MESSAGES, passenger_frame, stop_reason
from tests.helpers.api import VEHICLE_ID, auth, token_for
from tests.test_live import car, live_api, mission, read_events  # noqa: F401  (live_api: a fixture)


def movement(limited_by="", limit=3.0, latched=False) -> MovementStatus:
    return MovementStatus(
        t=1.0, level=0, latched=latched, stopping=False, limit_mps=limit, limited_by=limited_by, v=0.0, kappa=0.0,
        reason="",
    )  # fmt: skip


def body(doors="closed", ramp="stowed", media=False) -> BodyState:
    return BodyState(t=1.0, doors=doors, ramp=ramp, entrance_clear=True, media=media)


@pytest.mark.parametrize(
    "speed, state, gate, full_stop_at, reason",
    [
        (0.0, "DRIVING", movement(latched=True, limited_by="emergency", limit=0.0), None, "emergency"),
        (2.0, "DRIVING", movement(latched=True, limited_by="emergency", limit=0.0), None, "emergency"),  # braking
        (0.0, "PAUSED", movement(limited_by="mission", limit=0.0), None, "paused"),
        (0.0, "AT_POI", movement(limited_by="mission", limit=0.0), None, "at_stop"),
        (0.0, "DRIVING", movement(limited_by="obstacle", limit=0.0), None, "obstacle"),
        (1.5, "DRIVING", movement(limited_by="obstacle", limit=0.5), None, "obstacle"),  # slowing for it: said now
        (0.0, "DRIVING", movement(limited_by="mission", limit=0.0), 502.0, "intersection"),
        (0.0, "DRIVING", movement(limited_by="speed", limit=0.0), None, "waiting"),
        (3.0, "DRIVING", movement(limited_by="speed", limit=3.5), None, "none"),
        (0.0, "SUCCEEDED", movement(limited_by="mission", limit=0.0), None, "none"),
        (None, None, None, None, "none"),  # nothing heard yet
    ],
)
def test_the_reason_a_passenger_is_given(speed, state, gate, full_stop_at, reason):
    status = None if state is None else mission(1.0, state=state)
    assert stop_reason(speed, status, gate, full_stop_at) == reason
    assert reason in MESSAGES and (MESSAGES[reason] != "") == (reason != "none")


def test_the_frame_holds_the_next_stop_the_time_to_it_the_doors_and_the_media_and_nothing_else():
    f = passenger_frame(
        VEHICLE_ID, "default", ["Depot", "Library"], 2.0, mission(10.0, eta=100.0), movement(), body(media=True), None,
        5.0,
    )  # fmt: skip
    assert (f["next_stop"], f["eta_s"], f["distance_m"], f["doors"], f["media"]) == ("Library", 90, 50, "closed", True)
    assert f["reason"] == "none" and f["moving"] and f["stops"] == ["Depot", "Library"]
    assert not {"pose", "processes", "events", "speed_mps", "x", "y"} & set(f)  # nothing of where it is or how it works
    drive = passenger_frame(VEHICLE_ID, "default", [], 2.0, mission(1.0, kind="drive"), None, None, None, 0.0)
    assert drive["next_stop"] is None  # a drive stops nowhere


def test_a_passenger_streams_the_passenger_view_and_reads_nothing_else(live_api):  # noqa: F811
    client, tokens, hub = live_api
    hub.put(VEHICLE_ID, "mission/status", mission(1.0, eta=31.0))
    hub.put(VEHICLE_ID, "body/state", body())
    hub.put(VEHICLE_ID, "dbw/car_state", car(speed=0.0))
    hub.put(VEHICLE_ID, "movement/status", movement(limited_by="mission", limit=0.0))
    hub.put(
        VEHICLE_ID,
        "events",
        Event(t=1.0, source="mission_manager", kind="full_stop", message="", data={"line_s": 502.0}),
    )
    passenger = token_for(client, "passenger")
    (event, frame), *_ = read_events(client, "/api/v1/live/passenger?hz=2", passenger, count=1)
    assert event == "frame" and frame["next_stop"] == "Library" and frame["eta_s"] == 30
    assert frame["reason"] == "intersection" and frame["doors"] == "closed"
    # an operator may look at the kiosk's view; a passenger sees nothing of the rest
    assert read_events(client, "/api/v1/live/passenger?hz=2", tokens["operator"], count=1)[0][0] == "frame"
    for path in (
        f"/api/v1/live/vehicles/{VEHICLE_ID}",
        "/api/v1/live/fleet",
        "/api/v1/route",
        f"/api/v1/vehicles/{VEHICLE_ID}/records",
        f"/api/v1/vehicles/{VEHICLE_ID}/events",
        f"/api/v1/vehicles/{VEHICLE_ID}/snapshots",
        "/api/v1/vehicles",
    ):
        assert client.get(path, headers=auth(passenger)).status_code == 403, path
    assert client.post(f"/api/v1/vehicles/{VEHICLE_ID}/mission/pause", headers=auth(passenger)).status_code in (
        403,
        404,
    )
    assert client.get("/api/v1/live/passenger", headers=auth(tokens["fleet"])).status_code == 403


def test_the_passenger_page_is_served_without_a_library(live_api):  # noqa: F811
    client, _, _ = live_api
    r = client.get("/passenger")
    assert r.status_code == 200 and '<script src="/static/passenger.js"></script>' in r.text
    assert "{{" not in r.text and 'href=""' not in r.text and 'src=""' not in r.text
