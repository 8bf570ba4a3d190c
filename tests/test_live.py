"""The live gateway (blackbox/console/live_hub.py, blackbox/api/routes/live.py) and the pages' serving
(blackbox/api/routes/pages.py): what a frame holds, staleness, events, the fleet's legs and
lateness, the thinned grid; the streams' roles, limits and refusals; the pages' security headers."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from fastapi.testclient import TestClient

from ares.core.messages import (
    AwarenessState,
    BodyState,
    CarState,
    DriveMode,
    Event,
    EventLevel,
    MissionStatus,
    OccupancyGrid,
    OdometryScore,
    Pose,
)
from blackbox.api import create_app
from blackbox.api.routes.pages import MAP, PLOTS, WEB, vendor_missing
from blackbox.console.live_hub import LegTimer, LiveHub, LiveSettings
from tests.helpers.api import VEHICLE_ID, add_role_users, api_settings, auth, token_for

OTHER = "shuttle02"


class Wall:
    def __init__(self, t: float = 1000.0):
        self.t = t

    def __call__(self) -> float:
        return self.t


def pose(t=1.0, x=10.0, y=5.0, yaw=0.0) -> Pose:
    return Pose(
        t=t,
        x=x,
        y=y,
        z=0.0,
        yaw=yaw,
        v=2.0,
        yaw_rate=0.0,
        cov_xx=0.01,
        cov_xy=0.0,
        cov_yy=0.01,
        var_yaw=0.001,
        var_v=0.01,
        position_std_m=0.1,
        rtk=True,
        gnss_age_s=0.1,
    )


def car(t=1.0, speed=2.0) -> CarState:
    return CarState(
        t=t,
        mode=DriveMode.AUTOMATIC,
        engaged=True,
        watchdog_tripped=False,
        setpoint_age_s=0.02,
        v_command=speed,
        kappa_command=0.0,
        speed_mps=speed,
        steering_wheel_deg=12.0,
    )


def mission(t, state="DRIVING", poi="Library", eta=None, kind="tour") -> MissionStatus:
    return MissionStatus(
        t=t,
        goal_id=1,
        state=state,
        kind=kind,
        poi=poi,
        action="OPENING_DOORS" if state == "AT_POI" else None,
        distance_m=50.0,
        eta_s=eta,
        limit_mps=3.0,
        ready_to_move=True,
    )


def test_a_frame_holds_the_latest_of_each_topic_and_drops_what_went_stale():
    wall = Wall()
    hub = LiveHub(LiveSettings(stale_s=2.0), now=wall)
    hub.put(VEHICLE_ID, "localization/pose", pose())
    hub.put(VEHICLE_ID, "dbw/car_state", car())
    hub.put(VEHICLE_ID, "odometry/score", OdometryScore(t=1.0, score=0.93, covariance=0.01, pose_age_s=0.0))
    hub.put(VEHICLE_ID, "awareness/state", AwarenessState(t=1.0, level=2, causes=["road hidden"]))
    hub.put(VEHICLE_ID, "body/state", BodyState(t=1.0, doors="closed", ramp="stowed", entrance_clear=True))
    frame = hub.frame(VEHICLE_ID)
    assert frame["speed_mps"] == 2.0 and frame["mode"] == "AUTOMATIC" and frame["scores"]["odometry"] == 0.93
    assert frame["awareness"] == {"level": 2, "causes": ["road hidden"]} and frame["body"]["doors"] == "closed"
    assert frame["pose"]["x"] == 10.0 and frame["car_state_wall_ms"] == 1000.0 * 1e3
    assert frame["mission"] is None and frame["controller"] is None  # never heard: missing, not invented
    wall.t += 1.5
    hub.put(VEHICLE_ID, "dbw/car_state", car(t=2.5, speed=0.0))
    wall.t += 1.0  # pose 2.5 s old, car state 1 s
    frame = hub.frame(VEHICLE_ID)
    assert frame["pose"] is None and frame["speed_mps"] == 0.0
    assert hub.frame("nobody") is None


def test_the_operator_sees_the_fix_and_its_corrections():
    from ares.core.messages import CorrectionsStatus
    from tests.helpers.gnss import fix

    hub = LiveHub(LiveSettings(), now=Wall())
    assert hub.put(VEHICLE_ID, "dbw/car_state", car()) is None and hub.frame(VEHICLE_ID)["gnss"] is None
    hub.put(VEHICLE_ID, "gnss/fix", fix(1.0, rtk=False, var=0.1).model_copy(update={"quality": 5, "satellites": 11}))
    status = CorrectionsStatus(t=1.0, source="ntrip 127.0.0.1:2101/BASE", link="down", age_s=12.34, frames=7)
    hub.put(VEHICLE_ID, "gnss/corrections", status)
    cause = "no RTK: corrections link down, the newest 12 s old"
    hub.put(VEHICLE_ID, "odometry/score", OdometryScore(t=1.0, score=0.1, covariance=0.06, pose_age_s=0.0, cause=cause))
    assert hub.frame(VEHICLE_ID)["gnss"] == {
        "fix": "RTK float",
        "satellites": 11,
        "corrections_link": "down",
        "corrections_age_s": 12.3,
        "corrections_source": "ntrip 127.0.0.1:2101/BASE",
        "why_no_rtk": cause,
    }


def test_events_are_kept_in_order_per_vehicle_and_the_fleet_lists_vehicles_heard_lately():
    wall = Wall()
    hub = LiveHub(LiveSettings(vehicle_gone_s=30.0, events_kept=3), now=wall)
    for i in range(5):
        hub.put(
            VEHICLE_ID if i % 2 == 0 else OTHER,
            "events",
            Event(
                t=float(i),
                source="mission_manager",
                kind="mission_command",
                level=EventLevel.INFO,
                message=f"event {i}",
            ),
        )
    kept = hub.events_since(0)
    assert [e["message"] for e in kept] == ["event 2", "event 3", "event 4"]  # the last 3
    assert [e["message"] for e in hub.events_since(kept[0]["seq"], VEHICLE_ID)] == ["event 4"]
    hub.put(OTHER, "dbw/car_state", car())
    assert hub.vehicles() == sorted([VEHICLE_ID, OTHER])
    wall.t += 20
    hub.put(VEHICLE_ID, "dbw/car_state", car())
    wall.t += 15
    assert hub.vehicles() == [VEHICLE_ID]  # OTHER silent for 35 s
    assert [v["vehicle_id"] for v in hub.fleet_frame()] == [VEHICLE_ID]


def test_a_vehicle_silent_past_unreachable_after_s_is_listed_unreachable_until_heard_again():
    wall = Wall()
    hub = LiveHub(LiveSettings(unreachable_after_s=3.0, vehicle_gone_s=600.0), now=wall)
    hub.put(VEHICLE_ID, "dbw/car_state", car())
    assert [(v["reachable"], v["silent_s"]) for v in hub.fleet_frame()] == [(True, 0.0)]
    wall.t += 3.5  # a cut link: nothing arrives
    assert [(v["reachable"], v["silent_s"]) for v in hub.fleet_frame()] == [(False, 3.5)]
    wall.t += 60.0
    assert [v["reachable"] for v in hub.fleet_frame()] == [False]  # still listed, with its last state
    hub.put(VEHICLE_ID, "dbw/car_state", car())
    assert [v["reachable"] for v in hub.fleet_frame()] == [True]
    hub_of_the_fleet = LiveHub(LiveSettings(), now=wall, not_vehicles=frozenset({"fleet"}))
    hub_of_the_fleet.put("fleet", "events", Event(t=1.0, source="fleet_router", kind="acl_refused", message="x"))
    assert hub_of_the_fleet.vehicles() == [] and [e["kind"] for e in hub_of_the_fleet.events_since(0)] == [
        "acl_refused"
    ]


def test_the_grid_is_thinned_and_placed_in_the_local_frame():
    hub = LiveHub(LiveSettings(grid_cell_m=0.5, grid_max_cells=1000), now=Wall())
    cells = np.zeros((40, 40), dtype=np.uint8)
    cells[20, 30:34] = 100  # a wall ahead: x 5.0-7.0 m (0.5 m from the origin at -10), y 0.0
    grid = OccupancyGrid(t=1.0, frame="vehicle", resolution_m=0.25, origin_x=-2.5, origin_y=-5.0, cells=cells)
    hub.put(VEHICLE_ID, "localization/pose", pose(x=100.0, y=50.0, yaw=math.pi / 2))  # facing +y
    hub.put(VEHICLE_ID, "perception/grid", grid)
    frame = hub.frame(VEHICLE_ID)
    g = frame["grid"]
    assert g["cell_m"] == 0.5 and len(g["x"]) == 2  # four 0.25 m cells -> two of 0.5 m
    assert all(99.5 <= x <= 100.0 for x in g["x"])  # ahead (+x in the vehicle) is +y here
    assert all(55.0 <= y <= 56.0 for y in g["y"])
    assert hub.frame(VEHICLE_ID)["grid"] is g  # the same grid message: cached


def test_a_leg_is_timed_from_its_poi_and_late_against_past_runs_or_the_profile():
    legs = LegTimer()
    legs.update(mission(0.0, "AT_POI", poi="Depot"))
    legs.update(mission(10.0, "DRIVING", poi="Library", eta=110.0))  # leaves the Depot: 100 s expected
    assert (legs.from_poi, legs.to_poi, legs.started_t) == ("Depot", "Library", 10.0)
    assert legs.expected_s() == (100.0, "speed profile")
    legs.update(mission(130.0, "AT_POI", poi="Library"))  # took 120 s
    assert legs.history[("Depot", "Library")][-1] == 120.0
    hub = LiveHub(LiveSettings(late_factor=1.25, late_margin_s=30.0), now=Wall())
    for t, state, poi, eta in (
        (0.0, "AT_POI", "Depot", None),
        (10.0, "DRIVING", "Library", 110.0),
        (130.0, "AT_POI", "Library", None),
        (200.0, "AT_POI", "Depot", None),
        (210.0, "DRIVING", "Library", 310.0),
        (370.0, "DRIVING", "Library", 400.0),
    ):
        hub.put(VEHICLE_ID, "mission/status", mission(t, state, poi, eta))
    leg = hub.fleet_frame()[0]["leg"]
    assert leg["expected_s"] == 120.0 and leg["expected_from"] == "median of 1 past runs"
    assert leg["since_s"] == 160.0 and leg["late"] is False  # 160 < 120 × 1.25 + 30 = 180
    hub.put(VEHICLE_ID, "mission/status", mission(395.0, "PAUSED", "Library", None))
    assert hub.fleet_frame()[0]["leg"]["late"] is True  # 185 s: a pause counts too
    hub.put(VEHICLE_ID, "mission/status", mission(396.0, "IDLE", None, None, kind="none"))
    assert hub.fleet_frame()[0]["leg"]["late"] is False  # no goal: no leg


def test_streams_per_user_are_bounded():
    hub = LiveHub(LiveSettings(max_streams_per_user=2, max_streams=3), now=Wall())
    assert hub.open_stream("ann") is None and hub.open_stream("ann") is None
    assert "2 live streams" in hub.open_stream("ann")
    assert hub.open_stream("bob") is None
    assert "3 streams at most" in hub.open_stream("cy")
    hub.close_stream("ann")
    assert hub.open_stream("cy") is None


# ---- over HTTP ---------------------------------------------------------------------------------


@pytest.fixture
def live_api(store):
    hub = LiveHub(LiveSettings(rate_hz=20.0, max_streams_per_user=1))
    hub.put(VEHICLE_ID, "dbw/car_state", car())
    hub.put(VEHICLE_ID, "localization/pose", pose())
    hub.put(VEHICLE_ID, "events", Event(t=1.0, source="api", kind="note", message="hello"))
    route = {
        "name": "default",
        "closed": True,
        "length_m": 10.0,
        "x": [0.0, 10.0],
        "y": [0.0, 0.0],
        "pois": [],
        "zones": [],
    }
    app = create_app(store, api_settings(), VEHICLE_ID, live=hub, route=route)
    add_role_users(store, app)
    client = TestClient(app, base_url="https://testserver")
    tokens = {role: token_for(client, role) for role in ("operator", "auditor", "fleet", "admin")}
    return client, tokens, hub


def read_events(client, path, token, count=2):
    got = []
    with client.stream("GET", path, headers=auth(token)) as r:
        assert r.status_code == 200, r.read()
        assert r.headers["content-type"].startswith("text/event-stream")
        event = None
        for line in r.iter_lines():
            if line.startswith("event: "):
                event = line[7:]
            elif line.startswith("data: "):
                got.append((event, json.loads(line[6:])))
                if len(got) >= count:
                    break
    return got


def test_an_operator_streams_the_vehicle_and_its_recent_events(live_api):
    client, tokens, _ = live_api
    got = read_events(client, f"/api/v1/live/vehicles/{VEHICLE_ID}?hz=20", tokens["operator"])
    assert got[0][0] == "events" and got[0][1][0]["message"] == "hello"
    assert got[1][0] == "frame" and got[1][1]["speed_mps"] == 2.0 and got[1][1]["vehicle_id"] == VEHICLE_ID


def test_the_fleet_stream_lists_every_vehicle(live_api):
    client, tokens, hub = live_api
    hub.put(OTHER, "dbw/car_state", car(speed=1.0))
    got = read_events(client, "/api/v1/live/fleet?hz=20", tokens["fleet"])
    frame = next(data for event, data in got if event == "frame")
    assert {v["vehicle_id"]: v["speed_mps"] for v in frame["vehicles"]} == {VEHICLE_ID: 2.0, OTHER: 1.0}


@pytest.mark.parametrize(
    "role,path,status",
    [
        ("fleet", f"/api/v1/live/vehicles/{VEHICLE_ID}", 403),  # the fleet sees the fleet, not one cab
        ("admin", "/api/v1/live/fleet", 403),
        (None, "/api/v1/live/fleet", 401),
        ("operator", "/api/v1/live/vehicles/nobody", 404),
        ("operator", f"/api/v1/live/vehicles/{VEHICLE_ID}?hz=50", 422),  # above the gateway's rate
        ("admin", "/api/v1/route", 403),
    ],
)
def test_streams_are_refused_to_the_wrong_role_or_request(live_api, role, path, status):
    client, tokens, _ = live_api
    headers = auth(tokens[role]) if role else {}
    assert client.get(path, headers=headers).status_code == status


def test_one_stream_too_many_is_refused_and_the_slot_comes_back(live_api):
    client, tokens, hub = live_api
    hub.open_stream("operator")  # the operator's one stream, held elsewhere
    r = client.get(f"/api/v1/live/vehicles/{VEHICLE_ID}", headers=auth(tokens["operator"]))
    assert r.status_code == 429 and "live streams" in r.json()["detail"]
    hub.close_stream("operator")
    assert read_events(client, f"/api/v1/live/vehicles/{VEHICLE_ID}?hz=20", tokens["operator"], 1)
    assert hub.streams == {}  # closed with the connection


def test_without_a_bus_the_gateway_is_not_offered(store):
    app = create_app(store, api_settings(), VEHICLE_ID)
    add_role_users(store, app)
    client = TestClient(app, base_url="https://testserver")
    token = token_for(client, "operator")
    paths = client.get("/openapi.json").json()["paths"]
    assert not [p for p in paths if p.startswith(("/api/v1/live", "/api/v1/route"))]
    assert client.get("/api/v1/live/fleet", headers=auth(token)).status_code == 404
    assert client.get("/api/v1/route", headers=auth(token)).status_code == 404


def test_a_stack_without_the_route_offers_the_streams_only(store):
    hub = LiveHub(LiveSettings())
    app = create_app(store, api_settings(), VEHICLE_ID, live=hub)
    paths = TestClient(app).get("/openapi.json").json()["paths"]
    assert "/api/v1/live/fleet" in paths and "/api/v1/route" not in paths


def test_pages_are_served_with_a_strict_policy_and_the_api_keeps_its_own(live_api):
    client, tokens, _ = live_api
    for page in ("/operator", "/blackbox", "/fleet"):
        r = client.get(page)
        assert r.status_code == 200 and r.headers["content-type"].startswith("text/html")
        csp = r.headers["content-security-policy"]
        assert "script-src 'self'" in csp and "connect-src 'self'" in csp and "unsafe" not in csp
        assert "<script>" not in r.text and "style=" not in r.text  # nothing inline
        assert "http://" not in r.text and "https://" not in r.text  # nothing from elsewhere
    js = client.get("/static/common.js")
    assert js.status_code == 200 and "javascript" in js.headers["content-type"]
    index = client.get("/", follow_redirects=False)
    assert index.status_code == 307 and index.headers["location"] == "/operator"
    assert (
        client.get("/api/v1/health").headers["content-security-policy"] == "default-src 'none'; frame-ancestors 'none'"
    )


def test_the_static_folder_serves_nothing_outside_it(live_api):
    """`..` sent as the client wrote it: httpx would resolve a literal `/static/../x` to `/x` before
    sending, so the dots go percent-encoded, which it keeps; the server decodes them, as uvicorn
    does, and the app sees `..` in the path (checked). Each target exists one or two folders up."""
    client, _, _ = live_api
    seen: list[str] = []

    async def recording(scope, receive, send):
        if scope["type"] == "http":
            seen.append(scope["path"])
        await client.app(scope, receive, send)

    raw = TestClient(recording, base_url="https://testserver")
    frame = (WEB / "pages" / "frame.html").read_text()
    for path, target in (
        ("/static/%2e%2e/pages/frame.html", "/static/../pages/frame.html"),
        ("/static/..%2fpages/frame.html", "/static/../pages/frame.html"),
        ("/static/%2E%2E/%2E%2E/api/routes/pages.py", "/static/../../api/routes/pages.py"),
    ):
        r = raw.get(path)
        assert seen[-1] == target  # the server saw the dots
        assert r.status_code == 404, (path, r.status_code)
        assert frame[:200] not in r.text and "def mount" not in r.text
    assert raw.get("/static/common.js").status_code == 200  # the same client reaches what is inside


def test_the_page_libraries_are_installed_and_served(live_api):
    """The map and plot libraries every page loads: scripts/setup.sh installs them (npm ci in
    blackbox/web); without them the pages have no map and no plots, so this fails."""
    client, _, _ = live_api
    assert vendor_missing() == [], "page libraries missing: run scripts/setup.sh (npm ci in blackbox/web)"
    for path in (*MAP, *PLOTS):
        r = client.get(path)
        assert r.status_code == 200, path
        kind = "javascript" if path.endswith(".js") else "text/css"
        assert kind in r.headers["content-type"] and len(r.content) > 1000, path
        assert "script-src 'self'" in r.headers["content-security-policy"]


def test_the_operator_sees_the_black_boxs_writer():
    from ares.core.messages import BlackboxStatus

    hub = LiveHub(LiveSettings(), now=Wall())
    hub.put(VEHICLE_ID, "dbw/car_state", car())
    assert hub.frame(VEHICLE_ID)["blackbox"] is None  # never heard: missing, not invented
    status = BlackboxStatus(
        t=1.0,
        store_up=False,
        written=120,
        events_written=4,
        dropped=2,
        events_dropped=1,
        lost=0,
        store_faults=37,
        spooled=0,
        in_memory=18,
        last_error="database or disk is full",
    )
    hub.put(VEHICLE_ID, "blackbox/status", status)
    assert hub.frame(VEHICLE_ID)["blackbox"] == {
        "store": "down",
        "written": 120,
        "waiting": 18,
        "lost": 3,
        "store_faults": 37,
        "last_error": "database or disk is full",
    }
