"""The REST API's command route (blackbox/api/routes/commands.py): an operator, and only an
operator, re-arms the shuttle through the movement manager's service, which decides; the black
box's event names the operator. The movement manager is the real node, on the in-memory bus."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient

from ares.core import config
from ares.core.clock import ManualClock
from ares.core.membus import MemoryNetwork
from ares.core.messages import AwarenessState, CarState, DriveMode, Setpoint, SpeedLimits
from ares.core.signed_command import load_command_key
from blackbox.api import create_app
from managers.movement_node import MovementManager
from tests.helpers.api import VEHICLE_ID, add_role_users, api_settings, auth, open_test_store, token_for
from tests.helpers.commands import with_command_key


@pytest.fixture
def vehicle(run_config, tmp_path):
    """(client, tokens, step(level, seconds), events): the API of a stack whose movement manager runs
    on the in-memory bus."""
    cfg = config.deep_merge(with_command_key(run_config, tmp_path), {"lidars": False})
    clock, network = ManualClock(), MemoryNetwork()
    node = MovementManager(cfg, clock=clock, bus=network.bus("movement_manager", clock))
    node.setup()
    feed = network.bus("test", clock)
    events = feed.subscribe("events", queue=100)
    api_bus = network.bus("api", clock)
    store = open_test_store(tmp_path / "bb.sqlite")
    key = load_command_key(config.core(cfg).commands)
    app = create_app(store, api_settings(), VEHICLE_ID, call=api_bus.call, command_key=key)
    add_role_users(store, app)
    client = TestClient(app)
    tokens = {role: token_for(client, role) for role in ("operator", "auditor", "fleet")}

    def step(level: int, seconds: float = 0.5, causes=("lidar roof: blind",)):
        for _ in range(round(seconds / 0.02)):
            t = round(clock.now() + 0.02, 9)
            clock.set(t)
            feed.publish("control/setpoint", Setpoint(t=t, v=2.0, kappa=0.0, source="mpc"))
            feed.publish(
                "speed/limits",
                SpeedLimits(
                    t=t,
                    s=0.0,
                    section=0,
                    kind="cruise",
                    limit_mps=3.0,
                    next_section=None,
                    next_limit_mps=None,
                    distance_to_next_m=None,
                ),
            )
            feed.publish(
                "dbw/car_state",
                CarState(
                    t=t,
                    mode=DriveMode.AUTOMATIC,
                    engaged=True,
                    watchdog_tripped=False,
                    setpoint_age_s=0.02,
                    v_command=2.0,
                    kappa_command=0.0,
                    speed_mps=2.0,
                    steering_wheel_deg=0.0,
                ),
            )
            feed.publish("awareness/state", AwarenessState(t=t, level=level, causes=list(causes) if level else []))
            node.step_once(t)
        return node.gate

    yield client, tokens, step, events
    store.close()


URL = f"/api/v1/vehicles/{VEHICLE_ID}/rearm"


def test_an_operator_rearms_through_the_movement_manager_which_decides(vehicle):
    client, tokens, step, events = vehicle
    step(0)
    r = client.post(URL, headers=auth(tokens["operator"]))
    assert r.status_code == 409 and r.json()["reason"].startswith("nothing to re-arm")
    assert step(1).latched
    r = client.post(URL, headers=auth(tokens["operator"]))
    assert r.status_code == 409 and "level 1 persists (lidar roof: blind)" in r.json()["reason"]
    assert step(0).latched  # cleared, still latched
    r = client.post(URL, headers=auth(tokens["operator"]))
    assert r.status_code == 200 and r.json() == {
        "accepted": True,
        "reason": "re-armed after: lidar roof: blind",
        "operator": "operator",
    }
    assert not step(0).latched
    rearms = [e.data for _, e in events.drain() if e.kind == "rearm"]
    assert [(d["operator"], d["accepted"]) for d in rearms] == [("operator", False)] * 2 + [("operator", True)]


def test_only_an_operator_of_this_vehicle_may(vehicle):
    client, tokens, step, _ = vehicle
    step(1)
    assert client.post(URL).status_code == 401
    for role in ("auditor", "fleet"):
        r = client.post(URL, headers=auth(tokens[role]))
        assert r.status_code == 403 and "needs operator" in r.json()["detail"]
    r = client.post("/api/v1/vehicles/shuttle99/rearm", headers=auth(tokens["operator"]))
    assert r.status_code == 404
    assert step(0).latched  # none of them re-armed it


def test_on_a_bus_the_writes_are_logging_in_users_and_the_commands(vehicle):
    """The managers decide each command and none alters a record (each adds the event that says who asked)."""
    client = vehicle[0]
    schema = client.get("/openapi.json").json()
    writes = {(p, m) for p, ops in schema["paths"].items() for m in ops if m in ("put", "delete", "patch", "post")}
    assert writes == {
        ("/api/v1/auth/token", "post"),
        ("/api/v1/auth/renew", "post"),
        ("/api/v1/auth/revoke", "post"),
        ("/api/v1/users", "post"),
        ("/api/v1/users/{name}", "delete"),
        ("/api/v1/users/{name}/role", "put"),
        ("/api/v1/users/{name}/password", "put"),
        ("/api/v1/users/{name}/disable", "post"),
        ("/api/v1/users/{name}/enable", "post"),
        ("/api/v1/vehicles/{vehicle_id}/rearm", "post"),
        ("/api/v1/vehicles/{vehicle_id}/mission", "post"),
        ("/api/v1/vehicles/{vehicle_id}/mission/{action}", "post"),
        ("/api/v1/vehicles/{vehicle_id}/body", "post"),
        ("/api/v1/vehicles/{vehicle_id}/snapshots", "post"),
    }


def test_an_operator_asks_this_vehicles_recorder_for_a_snapshot(run_config, tmp_path):
    """POST /vehicles/{id}/snapshots publishes the operator's request on recording/snapshot_request
    (the recorder's `snapshot` event then lists the file: tests/test_pages_stack.py); 409 where the
    vehicle keeps no snapshots."""
    clock, network = ManualClock(), MemoryNetwork()
    api_bus, feed = network.bus("api", clock), network.bus("test", clock)
    asked = feed.subscribe("recording/snapshot_request", queue=10)
    store = open_test_store(tmp_path / "bb.sqlite")
    key = load_command_key(config.core(with_command_key(run_config, tmp_path)).commands)

    def publish(request) -> None:
        api_bus.publish("recording/snapshot_request", request)

    app = create_app(
        store, api_settings(), VEHICLE_ID, clock, call=api_bus.call, command_key=key, request_snapshot=publish
    )
    add_role_users(store, app)
    client = TestClient(app)
    tokens = {role: token_for(client, role) for role in ("operator", "auditor", "fleet")}
    url = f"/api/v1/vehicles/{VEHICLE_ID}/snapshots"
    clock.set(42.5)
    r = client.post(url, json={"reason": "a kerb too close"}, headers=auth(tokens["operator"]))
    assert r.status_code == 202 and r.json()["accepted"] and r.json()["operator"] == "operator", r.text
    [(_, request)] = asked.drain()
    assert (request.requested_by, request.reason, request.request_id, request.t) == (
        "operator",
        "a kerb too close",
        r.json()["request_id"],
        42.5,
    )
    for role in ("auditor", "fleet"):
        assert client.post(url, json={}, headers=auth(tokens[role])).status_code == 403
    assert client.post(url, json={}).status_code == 401
    foreign = client.post("/api/v1/vehicles/shuttle99/snapshots", json={}, headers=auth(tokens["operator"]))
    assert foreign.status_code == 404
    too_long = client.post(url, json={"reason": "x" * 201}, headers=auth(tokens["operator"]))
    assert too_long.status_code == 422
    assert client.post(url, json={"why": "?"}, headers=auth(tokens["operator"])).status_code == 422
    assert asked.drain() == []  # none of them asked
    off = create_app(store, api_settings(), VEHICLE_ID, clock, call=api_bus.call, command_key=key)
    refused = TestClient(off).post(url, json={}, headers=auth(tokens["operator"]))
    assert refused.status_code == 409 and "keeps no incident snapshots" in refused.json()["reason"]
    store.close()


def test_without_a_bus_the_commands_are_not_offered(tmp_path):
    store = open_test_store(tmp_path / "bb.sqlite")
    app = create_app(store, api_settings(), VEHICLE_ID)
    add_role_users(store, app)
    client = TestClient(app)
    assert not [p for p in client.get("/openapi.json").json()["paths"] if "/rearm" in p or "/mission" in p]
    assert client.post(URL, headers=auth(token_for(client, "operator"))).status_code == 404
    store.close()


def test_an_operator_sets_pauses_and_cancels_the_mission_through_the_mission_manager(run_config, tmp_path):
    from tests.helpers.mission import Tour

    cfg = config.deep_merge(with_command_key(run_config, tmp_path), {"mission_manager": {"autostart": "none"}})
    tour = Tour(cfg, s0=40.0)
    tour.run(0.5)
    store = open_test_store(tmp_path / "bb.sqlite")
    key = load_command_key(config.core(cfg).commands)
    app = create_app(store, api_settings(), VEHICLE_ID, call=tour.network.bus("api", tour.clock).call, command_key=key)
    add_role_users(store, app)
    client = TestClient(app)
    tokens = {role: token_for(client, role) for role in ("operator", "auditor", "fleet")}
    base = f"/api/v1/vehicles/{VEHICLE_ID}/mission"
    try:
        assert client.post(base, json={"pois": ["Library"]}).status_code == 401
        assert client.post(base, json={"pois": ["Library"]}, headers=auth(tokens["auditor"])).status_code == 403
        assert client.post(f"{base}/pause", headers=auth(tokens["fleet"])).status_code == 403
        refused = client.post(base, json={"pois": ["Atlantis"]}, headers=auth(tokens["operator"]))
        assert refused.status_code == 409 and "unknown POIs ['Atlantis']" in refused.json()["reason"]
        assert (
            client.post(base, json={"pois": ["Library"], "drive": True}, headers=auth(tokens["operator"])).status_code
            == 422
        )
        started = client.post(base, json={"pois": ["Library", "Lakeside"]}, headers=auth(tokens["operator"]))
        assert started.status_code == 200 and started.json() == {
            "accepted": True,
            "reason": "accepted: 2 POIs, first Library",
            "operator": "operator",
            "goal_id": 1,
            "state": "DRIVING",
        }
        tour.run(5.0)
        assert tour.v > 2.0
        assert client.post(f"{base}/pause", headers=auth(tokens["operator"])).json()["state"] == "PAUSED"
        tour.run(3.0)
        assert tour.v == 0.0
        again = client.post(f"{base}/pause", headers=auth(tokens["operator"]))
        assert again.status_code == 409 and "nothing to pause" in again.json()["reason"]
        assert client.post(f"{base}/fly", headers=auth(tokens["operator"])).status_code == 422
        assert client.post(f"{base}/cancel", headers=auth(tokens["operator"])).json()["state"] == "CANCELED"
        commands = [(e.data["operator"], e.data["accepted"]) for e in tour.kinds("mission_command")]
        assert commands == [
            ("operator", False),
            ("operator", True),
            ("operator", True),
            ("operator", False),
            ("operator", True),
        ]
    finally:
        store.close()
