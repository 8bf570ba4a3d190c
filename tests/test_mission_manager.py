"""The mission manager as a node (managers/mission_node.py) on the in-memory bus with a manual clock, in a
closed loop with the simulated body (simulator/body.py) and a shuttle that drives at the mission's
limit along the built-in tour: goals, each POI's actions in order, passengers holding the doors,
pause / resume / cancel, pre-emption, and a restart that goes on where the last process was."""

from __future__ import annotations

import itertools
import math
import time

import pytest

from ares.core import config
from ares.core.messages import BodyRequest, MissionGoal, MissionRequest
from ares.core.recording import INCARNATION_ENV
from ares.core.signed_command import load_command_key, sign
from managers.mission import Body, MissionState, body_request_refusal
from simulator.scenario import ScenarioPassengers
from tests.helpers.commands import call_signed, with_command_key
from tests.helpers.mission import Tour

DT = 0.1
CRUISE = 3.0


@pytest.fixture
def tour_cfg(run_config, tmp_path) -> dict:
    return config.deep_merge(with_command_key(run_config, tmp_path), {"mission_manager": {"autostart": "tour"}})


def test_the_tour_serves_each_poi_in_order_and_passengers_hold_the_doors(tour_cfg):
    people = [
        ScenarioPassengers(poi="Depot", boarding=2, late=1),
        ScenarioPassengers(poi="Library", boarding=1, alighting=1, on_ramp=1),
    ]
    tour = Tour(tour_cfg, passengers=people)
    tour.until(lambda: tour.status.latest is not None and tour.status.latest.poi == "Library", 120, "the Depot served")
    tour.until(lambda: tour.status.latest.poi == "Lakeside", 400, "the Library served")
    st = tour.status.latest
    assert st.kind == "tour" and st.state == "DRIVING" and st.goal_id == 1
    assert [(p.name, p.done) for p in st.pois[:2]] == [
        ("Depot", ["STOP", "FULL_STOP", "OPENING_DOORS", "CLOSING_DOORS", "NEXT_POI"]),
        ("Library", ["STOP", "OPENING_DOORS", "TAKEOFF_RAMP", "PICKUP_RAMP", "CLOSING_DOORS", "NEXT_POI"]),
    ]
    assert tour.violations == []
    assert tour.body.passengers == 2 + 2 + 1 + 1 - 1  # the late one got on too
    actions = [(e.data["poi"], e.data["action"]) for e in tour.kinds("poi_action")]
    assert actions[:5] == [("Depot", a) for a in st.pois[0].done]
    # the stop points: stood within reach of each
    assert st.distance_m is not None and 0 < st.distance_m < 370 and st.eta_s > tour.t


def test_the_late_passenger_opens_the_closing_doors_again(tour_cfg):
    tour = Tour(tour_cfg, passengers=[ScenarioPassengers(poi="Depot", boarding=0, late=1)])
    seen = []
    tour.until(
        lambda: seen.append(tour.body.door_state) or tour.status.latest.poi == "Library", 120, "the Depot served"
    )
    compact = [d for i, d in enumerate(seen) if i == 0 or seen[i - 1] != d]
    # closing on the late one: open again (the doors had barely moved: maybe never seen "opening")
    assert compact[:4] == ["closed", "opening", "open", "closing"]
    assert compact[4:6] in (["open", "closing"], ["opening", "open"])
    assert compact[-2:] == ["closing", "closed"] and compact.count("closing") == 2 and tour.violations == []


def test_pause_holds_resume_goes_on_and_the_limit_falls_gently(tour_cfg):
    tour = Tour(tour_cfg, s0=40.0)  # past the Depot: the Library next
    tour.run(8.0)
    assert tour.v == pytest.approx(CRUISE)
    reply = call_signed(tour.bus, tour.cfg, "mission/pause", MissionRequest(operator="ana"))
    assert reply.accepted and reply.state == "PAUSED"
    limits = []
    for _ in range(30):
        tour.run(DT)
        limits.append(tour.status.latest.limit_mps)
    assert all(a - b <= 3.0 * DT + 1e-6 for a, b in zip(limits, limits[1:]))  # <= pause_decel_mps2
    assert tour.v == 0.0 and limits[-1] == 0.0
    assert [(e.data["operator"], e.data["accepted"]) for e in tour.kinds("mission_command")] == [("ana", True)]
    refused = call_signed(tour.bus, tour.cfg, "mission/pause", MissionRequest(operator="ana"))
    assert not refused.accepted and "nothing to pause" in refused.reason
    assert call_signed(tour.bus, tour.cfg, "mission/resume", MissionRequest(operator="ana")).accepted
    tour.run(5.0)
    assert tour.v > 2.0


def test_goals_are_checked_pre_empt_and_end_with_a_result(tour_cfg):
    tour = Tour(config.deep_merge(tour_cfg, {"mission_manager": {"autostart": "none"}}))
    tour.run(1.0)
    assert tour.status.latest.state == "IDLE" and tour.status.latest.limit_mps == 0.0  # no mission, no motion
    refused = call_signed(tour.bus, tour.cfg, "mission/goal", MissionGoal(operator="ana", pois=["Atlantis"]))
    assert not refused.accepted and "unknown POIs ['Atlantis']" in refused.reason
    first = call_signed(tour.bus, tour.cfg, "mission/goal", MissionGoal(operator="ana", pois=["Lakeside", "Library"]))
    assert first.accepted and first.goal_id == 1
    tour.run(2.0)
    second = call_signed(tour.bus, tour.cfg, "mission/goal", MissionGoal(operator="ben", pois=["Depot"]))
    assert second.accepted and second.goal_id == 2
    results = tour.kinds("mission_result")
    assert len(results) == 1 and "pre-empted by goal 2" in results[0].message
    tour.until(lambda: tour.status.latest.state == "SUCCEEDED", 120, "the Depot served")
    assert tour.kinds("mission_result")[-1].data["state"] == "SUCCEEDED"
    assert tour.status.latest.limit_mps == 0.0
    drive = call_signed(tour.bus, tour.cfg, "mission/goal", MissionGoal(operator="ana", drive=True))
    assert drive.accepted
    tour.run(3.0)
    assert tour.status.latest.kind == "drive" and tour.status.latest.limit_mps is None and tour.v > 2.0
    assert call_signed(tour.bus, tour.cfg, "mission/cancel", MissionRequest(operator="ana")).accepted
    tour.run(3.0)
    assert tour.v == 0.0 and tour.status.latest.state == "CANCELED"


def test_a_restarted_mission_manager_goes_on_where_the_last_one_was(tour_cfg, tmp_path, monkeypatch):
    monkeypatch.setenv(config.RUN_CONFIG_ENV, str(tmp_path / "config.json"))
    tour = Tour(tour_cfg, s0=40.0)
    tour.until(
        lambda: (
            tour.status.latest is not None
            and tour.status.latest.state == "AT_POI"
            and tour.status.latest.action == "TAKEOFF_RAMP"
        ),
        200,
        "the ramp going out at the Library",
    )
    before = tour.status.latest
    monkeypatch.setenv(INCARNATION_ENV, "1")  # the supervisor's restart
    tour.node.teardown()
    tour.node = tour.start_node()
    tour.run(0.5)
    after = tour.status.latest
    assert (after.goal_id, after.state, after.poi, after.action) == (1, "AT_POI", "Library", "TAKEOFF_RAMP")
    assert [p.done for p in after.pois] == [p.done for p in before.pois]
    tour.until(lambda: tour.status.latest.poi == "Lakeside", 200, "the Library served after the restart")
    assert tour.violations == []


def test_a_first_start_ignores_what_an_earlier_run_left(tour_cfg, tmp_path, monkeypatch):
    monkeypatch.setenv(config.RUN_CONFIG_ENV, str(tmp_path / "config.json"))
    (tmp_path / "mission_manager.json").write_text("{not json")
    tour = Tour(tour_cfg)
    tour.run(1.0)
    assert tour.status.latest.goal_id == 1 and tour.status.latest.poi == "Depot"
    monkeypatch.setenv(INCARNATION_ENV, "2")
    (tmp_path / "mission_manager.json").write_text("{not json")
    tour.node = tour.start_node()  # a restart that finds a corrupt file says so
    assert any("could not read the mission" in e.message for e in tour.kinds("mission"))
    tour.run(0.5)
    assert tour.status.latest.state == "IDLE" and math.isclose(tour.status.latest.limit_mps, 0.0)


def test_a_restart_before_the_first_goal_sets_the_autostart_goal(tour_cfg, tmp_path, monkeypatch):
    monkeypatch.setenv(config.RUN_CONFIG_ENV, str(tmp_path / "config.json"))
    monkeypatch.setenv(INCARNATION_ENV, "1")  # the first process died before it set its goal: nothing kept
    tour = Tour(tour_cfg)
    tour.run(1.0)
    assert tour.status.latest.goal_id == 1 and tour.status.latest.poi == "Depot"
    assert any(e.message.startswith("autostart (tour)") for e in tour.kinds("mission"))


def test_the_tour_goes_round_again_after_its_last_poi(tour_cfg):
    tour = Tour(tour_cfg, s0=1400.0)  # before the Main gate, the last POI of the lap
    tour.until(lambda: tour.status.latest.poi == "Main gate", 10, "the goal")
    assert [p.name for p in tour.status.latest.pois] == ["Main gate", "Depot", "Library", "Lakeside", "Observatory"]
    tour.until(
        lambda: tour.status.latest.poi == "Depot" and tour.status.latest.state == "DRIVING", 200, "the Main gate served"
    )
    tour.until(lambda: tour.status.latest.poi == "Library", 300, "the Depot served, on the next lap")
    st = tour.status.latest
    assert st.goal_id == 1 and st.kind == "tour" and st.state == "DRIVING"
    assert 1587 + 20 < tour.progress < 1587 + 330 and tour.violations == []
    assert not tour.kinds("mission_result")  # a repeating tour does not end


def test_a_restarted_path_managers_lap_count_does_not_move_the_pois(tour_cfg):
    tour = Tour(tour_cfg, s0=1560.0)  # before the start line: the Depot (20 m) is on the next lap
    tour.until(lambda: tour.status.latest.poi == "Library", 120, "the Depot served, across the start line")
    tour.lap_offset = 1  # the path manager restarted: lap 0 again
    tour.until(lambda: tour.status.latest.poi == "Lakeside", 300, "the Library served all the same")
    assert [p.done[-1] for p in tour.status.latest.pois[:2]] == ["NEXT_POI", "NEXT_POI"]


# ---- the operator's doors and ramp (service mission/body) -----------------------------------------

DOORS = ("closed", "opening", "open", "closing")
RAMPS = ("stowed", "deploying", "deployed", "stowing")


@pytest.mark.parametrize("state", list(MissionState))
@pytest.mark.parametrize("standing", (True, False))
@pytest.mark.parametrize("doors_ask", (None, "open", "close"))
@pytest.mark.parametrize("ramp_ask", (None, "deploy", "stow"))
def test_every_doors_and_ramp_request_in_every_state(state, standing, doors_ask, ramp_ask):
    for doors, ramp, clear in itertools.product(DOORS, RAMPS, (True, False)):
        body = Body(doors=doors, ramp=ramp, entrance_clear=clear)
        refusal = body_request_refusal(state, standing, body, doors_ask, ramp_ask)
        allowed = (
            (doors_ask is not None or ramp_ask is not None)
            and standing
            and state not in (MissionState.DRIVING, MissionState.AT_POI)
            and not (ramp_ask == "deploy" and (doors != "open" or doors_ask == "close"))
            and not (ramp_ask == "stow" and not clear)
            and not (doors_ask == "close" and (ramp != "stowed" or ramp_ask == "deploy" or not clear))
        )
        assert (refusal is None) == allowed, (state, standing, body, doors_ask, ramp_ask, refusal)
        if refusal is not None:
            assert refusal.startswith("refused: ")


def test_an_operator_opens_and_closes_the_doors_while_paused_and_is_refused_on_the_move(tour_cfg):
    tour = Tour(tour_cfg, s0=40.0)
    tour.run(5.0)
    moving = call_signed(tour.bus, tour.cfg, "mission/body", BodyRequest(operator="ana", doors="open"))
    assert not moving.accepted and "moving" in moving.reason
    assert call_signed(tour.bus, tour.cfg, "mission/pause", MissionRequest(operator="ana")).accepted
    tour.until(lambda: tour.v == 0.0, 10, "stopped")
    tour.run(0.5)
    reply = call_signed(tour.bus, tour.cfg, "mission/body", BodyRequest(operator="ana", doors="open"))
    assert reply.accepted and reply.state == "PAUSED"
    tour.until(lambda: tour.body.door_state == "open", 5, "the doors open")
    tour.run(0.2)  # the manager hears the body
    ramp = call_signed(tour.bus, tour.cfg, "mission/body", BodyRequest(operator="ana", ramp="deploy"))
    assert ramp.accepted
    tour.until(lambda: tour.body.ramp_state == "deployed", 8, "the ramp deployed")
    tour.run(0.2)  # the manager hears the body
    assert not call_signed(
        tour.bus, tour.cfg, "mission/body", BodyRequest(operator="ana", doors="close")
    ).accepted  # over the ramp
    assert "close the doors" in call_signed(tour.bus, tour.cfg, "mission/resume", MissionRequest(operator="ana")).reason
    tour.run(3.0)
    assert tour.v == 0.0
    assert call_signed(tour.bus, tour.cfg, "mission/body", BodyRequest(operator="ana", ramp="stow")).accepted
    tour.until(lambda: tour.body.ramp_state == "stowed", 8, "the ramp stowed")
    tour.run(0.2)  # the manager hears the body
    assert call_signed(tour.bus, tour.cfg, "mission/body", BodyRequest(operator="ana", doors="close")).accepted
    tour.until(lambda: tour.body.door_state == "closed", 5, "the doors closed")
    tour.run(0.2)  # the manager hears the body
    assert call_signed(tour.bus, tour.cfg, "mission/resume", MissionRequest(operator="ana")).accepted
    tour.until(lambda: tour.v > 1.0, 15, "driving on")
    commands = [e for e in tour.kinds("mission_command") if e.data["operator"] == "ana"]
    assert [e.data["accepted"] for e in commands] == [False, True, True, True, False, False, True, True, True]
    assert tour.violations == []


# ---- who commands: the signed name, only from a holder of the vehicle's command key --------------


def test_only_a_command_signed_with_the_vehicles_key_is_obeyed_under_its_signed_name(tour_cfg):
    tour = Tour(config.deep_merge(tour_cfg, {"mission_manager": {"autostart": "none"}}), s0=40.0)
    tour.run(0.5)
    key = load_command_key(config.core(tour.cfg).commands)
    goal = MissionGoal(operator="ana", pois=["Library"])
    drive = sign(key, "mission/goal", MissionGoal(operator="ana", drive=True), "ana")
    refused = {
        # what any process holding the bus's password (the fleet's, say) could send
        "unsigned": goal,
        "another key": sign(b"f" * 64, "mission/goal", goal, "ana"),
        "a drive's signature on a tour": drive.model_copy(update={"drive": False, "pois": ["Library"]}),
        "another name on the signature": drive.model_copy(
            update={"signature": drive.signature.model_copy(update={"operator": "boss"})}
        ),
        "a pause's signature": sign(key, "mission/pause", goal, "ana"),
        "a minute old": sign(key, "mission/goal", goal, "ana", wall=lambda: time.time() - 60.0),
    }
    reasons = {why: tour.bus.call("mission/goal", request) for why, request in refused.items()}
    assert not any(reply.accepted for reply in reasons.values())
    assert "an unsigned command" in reasons["unsigned"].reason
    for why in ("another key", "a drive's signature on a tour", "another name on the signature", "a pause's signature"):
        assert "signature does not match" in reasons[why].reason, why
    assert "a stale command" in reasons["a minute old"].reason
    tour.run(1.0)
    assert tour.status.latest.state == "IDLE" and tour.status.latest.goal_id == 0 and tour.v == 0.0

    # signed for ana, whatever name the payload gives: the black box keeps the signed one
    obeyed = sign(key, "mission/goal", MissionGoal(operator="mallory", pois=["Library"]), "ana")
    assert tour.bus.call("mission/goal", obeyed).accepted
    replayed = tour.bus.call("mission/goal", obeyed)
    assert not replayed.accepted and "a replayed command" in replayed.reason
    events = [e for _, e in tour.events.drain()]
    commands = [(e.data["operator"], e.data["accepted"]) for e in events if e.kind == "mission_command"]
    assert commands == [("ana", True)]
    refusals = [e for e in events if e.kind == "command_refused"]
    assert len(refusals) == len(refused) + 1 and {e.data["service"] for e in refusals} == {"mission/goal"}
    assert {e.data["claimed"] for e in refusals} == {"ana", "mallory"}
    tour.run(3.0)
    assert tour.status.latest.goal_id == 1 and tour.v > 0.0
