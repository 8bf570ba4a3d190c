"""The mission's state machine (managers/mission.py): every state × every event against
the rule written out plainly, a POI's actions run in order with the doors and ramp answering
after their travel, passengers holding the doors, and hypothesis properties (no motion with a
door open or the ramp out; the doors open only standing; the actions done in each POI's order)."""

from __future__ import annotations

import itertools

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from managers.mission import ACTIVE, Body, Mission, MissionParams, MissionState, PoiGoal, ready_to_move

LIBRARY = PoiGoal(
    "Library", 330.0, ("STOP", "OPENING_DOORS", "TAKEOFF_RAMP", "PICKUP_RAMP", "CLOSING_DOORS", "NEXT_POI")
)
LAKESIDE = PoiGoal(
    "Lakeside", 700.0, ("STOP", "FULL_STOP", "OPENING_DOORS", "CLOSING_DOORS", "START_MEDIA", "NEXT_POI")
)
READY, OPEN = Body(), Body(doors="open")


def mission_in(state: str) -> Mission:
    m = Mission()
    if state == "IDLE":
        return m
    m.goal([LIBRARY, LAKESIDE], READY)
    if state == "DRIVING":
        return m
    if state in ("AT_POI", "PAUSED_AT_POI"):
        m.step(0.0, 0.2, 0.0, READY)  # reached and standing: doors being opened
        assert m.state is MissionState.AT_POI and m.current_action() == "OPENING_DOORS"
        if state == "PAUSED_AT_POI":
            m.pause()
        return m
    if state == "PAUSED_DRIVING":
        m.pause()
        return m
    if state == "SUCCEEDED":
        m.state = MissionState.SUCCEEDED
        return m
    m.cancel(READY)
    return m


STATES = ("IDLE", "DRIVING", "AT_POI", "PAUSED_DRIVING", "PAUSED_AT_POI", "SUCCEEDED", "CANCELED")
EVENTS = ("goal", "drive_goal", "empty_goal", "cancel", "pause", "resume", "reach", "far")
BODIES = {"ready": READY, "doors_open": OPEN}


def expected(state: str, event: str, body: str) -> tuple[bool | None, str]:
    """(accepted, state after) as the module's docstring says it."""
    active = state in ("DRIVING", "AT_POI", "PAUSED_DRIVING", "PAUSED_AT_POI")
    ready = body == "ready"
    paused = {"PAUSED_DRIVING": "PAUSED", "PAUSED_AT_POI": "PAUSED"}.get(state, state)
    if event in ("goal", "drive_goal"):
        return (True, "DRIVING") if ready else (False, paused)
    if event == "empty_goal":
        return False, paused
    if event == "cancel":
        return (True, "CANCELED") if active and ready else (False, paused)
    if event == "pause":
        return (True, "PAUSED") if state in ("DRIVING", "AT_POI") else (False, paused)
    if event == "resume":
        # a paused drive goes on only ready to move (a POI's actions close what they opened)
        return {
            "PAUSED_DRIVING": (True, "DRIVING") if ready else (False, paused),
            "PAUSED_AT_POI": (True, "AT_POI"),
        }.get(state, (False, paused))
    if event == "reach":
        return None, "AT_POI" if state == "DRIVING" else paused
    return None, paused


@pytest.mark.parametrize("state,event,body", list(itertools.product(STATES, EVENTS, BODIES)))
def test_every_state_and_event(state, event, body):
    m = mission_in(state)
    b = BODIES[body]
    want_accepted, want_state = expected(state, event, body)
    if event == "goal":
        accepted, reason = m.goal([LAKESIDE], b)
    elif event == "drive_goal":
        accepted, reason = m.goal([], b, drive=True)
    elif event == "empty_goal":
        accepted, reason = m.goal([], b)
    elif event == "cancel":
        accepted, reason = m.cancel(b)
    elif event == "pause":
        accepted, reason = m.pause()
    elif event == "resume":
        accepted, reason = m.resume(b)
    else:
        # moving (no action can finish): only where the mission is changes
        m.step(1.0, 0.3 if event == "reach" else 50.0, 1.0, b)
        accepted, reason = None, ""
    assert accepted == want_accepted and m.state.value == want_state, (reason, m.result)
    if accepted is False:
        assert reason
    # the mission's limit: only DRIVING with the body ready lets the shuttle move
    limit = m.limit_mps(50.0, b)
    assert (limit > 0) == (m.state is MissionState.DRIVING and ready_to_move(b))


def test_a_goal_pre_empts_the_one_running_and_says_so():
    m = mission_in("DRIVING")
    accepted, _ = m.goal([LAKESIDE], READY)
    assert accepted and m.pois == [LAKESIDE] and m.result == "pre-empted by a new goal at Library"
    assert m.goal([PoiGoal("Nowhere", 1.0, ("FLY",))], READY)[1].startswith("refused: unknown actions ['FLY']")


class Doors:
    """The body as the tests play it: the doors and ramp reach their end positions after their
    travel time; a passenger may stand in the doorway."""

    def __init__(self, travel_s: float = 3.0):
        self.travel_s = travel_s
        self.doors, self.ramp = "closed", "stowed"
        self.doors_done = self.ramp_done = 0.0
        self.entrance_clear = True

    def body(self) -> Body:
        return Body(self.doors, self.ramp, self.entrance_clear)

    def obey(self, now: float, commands) -> None:
        if commands.doors == "open" and self.doors in ("closed", "closing"):
            self.doors, self.doors_done = "opening", now + self.travel_s
        if commands.doors == "close" and self.doors == "open":
            self.doors, self.doors_done = "closing", now + self.travel_s
        if commands.ramp == "deploy" and self.ramp in ("stowed", "stowing"):
            self.ramp, self.ramp_done = "deploying", now + self.travel_s
        if commands.ramp == "stow" and self.ramp == "deployed":
            self.ramp, self.ramp_done = "stowing", now + self.travel_s
        if self.doors in ("opening", "closing") and now >= self.doors_done:
            self.doors = "open" if self.doors == "opening" else "closed"
        if self.ramp in ("deploying", "stowing") and now >= self.ramp_done:
            self.ramp = "deployed" if self.ramp == "deploying" else "stowed"


def run_poi(m: Mission, body: Doors, seconds: float, boarding: tuple[float, float] = (0.0, 0.0)):
    """Standing at the POI, 10 Hz; a passenger in the entrance during `boarding` (start, end)."""
    media = []
    for k in range(int(seconds * 10)):
        now = k / 10
        body.entrance_clear = not boarding[0] <= now < boarding[1]
        commands = m.step(now, 0.0, 0.0, body.body())
        if commands.doors == "open" or commands.ramp == "deploy":
            assert m.state is MissionState.AT_POI  # only there, and standing (speed 0 here)
        media.append(commands.media)
        body.obey(now, commands)
        if m.state is not MissionState.AT_POI:
            return now, media
    return None, media


def test_a_poi_runs_its_actions_in_order_and_passengers_hold_the_doors():
    m = Mission()
    m.goal([LIBRARY, LAKESIDE], READY)
    body = Doors(travel_s=3.0)
    left_at, _ = run_poi(m, body, 60.0, boarding=(7.0, 15.0))
    assert m.done == [("Library", a) for a in LIBRARY.actions]
    assert m.state is MissionState.DRIVING and m.current_name() == "Lakeside"
    assert body.doors == "closed" and body.ramp == "stowed"
    # doors 3 s, ramp out 3 s; a passenger on the ramp until 15 s; ramp in 3 s, doors shut 3 s
    assert left_at == pytest.approx(15.0 + 3.0 + 3.0, abs=0.3)
    assert m.limit_mps(20.0, body.body()) > 0


def test_the_last_poi_succeeds_and_media_start_once():
    m = Mission()
    m.goal([LAKESIDE], READY)
    body = Doors(travel_s=1.0)
    left_at, media = run_poi(m, body, 30.0)
    assert m.state is MissionState.SUCCEEDED and m.result == "every POI done, last Lakeside"
    assert sum(media) == 1 and left_at >= MissionParams().full_stop_s
    assert [a for _, a in m.done] == list(LAKESIDE.actions)


def test_doors_closing_on_a_passenger_open_again():
    m = Mission()
    m.goal([PoiGoal("Stop", 10.0, ("STOP", "OPENING_DOORS", "CLOSING_DOORS", "NEXT_POI"))], READY)
    body = Doors(travel_s=2.0)
    run_poi(m, body, 3.0)  # doors open at 2 s, closing from 2.1 s
    assert body.doors == "closing"
    body.entrance_clear = False
    commands = m.step(3.0, 0.0, 0.0, body.body())
    assert commands.doors == "open"


def test_the_approach_limit_brings_the_shuttle_to_the_stop_point():
    m = Mission()
    m.goal([LIBRARY], READY)
    a = MissionParams().approach_decel_mps2
    assert m.limit_mps(16.25, READY) == pytest.approx((2 * a * 16.0) ** 0.5)
    assert m.limit_mps(0.25, READY) == 0.0 and m.limit_mps(None, READY) == 0.0


# ---- properties ------------------------------------------------------------------------------------

EVENT = st.one_of(
    st.tuples(
        st.just("step"),
        st.floats(0.0, 40.0),
        st.floats(0.0, 3.0),
        st.sampled_from(["closed", "open", "opening", "closing"]),
        st.sampled_from(["stowed", "deployed", "deploying", "stowing"]),
        st.booleans(),
    ),
    st.tuples(st.sampled_from(["goal", "cancel", "pause", "resume"])),
)


@settings(max_examples=300, deadline=None)
@given(st.lists(EVENT, min_size=1, max_size=60))
def test_properties_over_random_sequences(events):
    m = Mission()
    body = READY
    now = 0.0
    for event in events:
        if event[0] == "step":
            _, distance, speed, doors, ramp, clear = event
            body = Body(doors, ramp, clear)
            now += 0.1
            commands = m.step(now, distance, speed, body)
            # the doors open and the ramp goes out only standing at a POI
            if commands.doors == "open" or commands.ramp == "deploy":
                assert m.state is MissionState.AT_POI and speed <= MissionParams().stopped_mps
            # never a motion with a door open or the ramp out
            if not ready_to_move(body):
                assert m.limit_mps(distance, body) == 0.0
        elif event[0] == "goal":
            accepted, _ = m.goal([LIBRARY, LAKESIDE], body)
            assert accepted == ready_to_move(body)
        else:
            getattr(m, event[0])(*((body,) if event[0] in ("cancel", "resume") else ()))
        if m.state not in ACTIVE:
            assert m.limit_mps(10.0, body) == 0.0
    # whatever happened, each POI's actions were done in its own order
    for poi in (LIBRARY, LAKESIDE):
        done = [a for name, a in m.done if name == poi.name]
        assert done == list(poi.actions[: len(done)])


def test_a_drive_goes_round_without_stopping_and_a_door_still_stops_it():
    m = Mission()
    assert m.goal([LIBRARY], READY, drive=True) == (False, "refused: a drive goal has no POIs")
    assert m.goal([], READY, drive=True)[0]
    for t in range(5):
        assert m.step(float(t), None, 3.0, READY) == m.step(float(t), 0.1, 3.0, READY)  # nothing asked of the body
        assert m.state is MissionState.DRIVING and m.limit_mps(None, READY) == float("inf")
    assert m.limit_mps(None, OPEN) == 0.0
    assert m.pause()[0] and m.limit_mps(None, READY) == 0.0


@pytest.mark.parametrize("state", STATES)
def test_a_snapshot_restores_the_same_mission(state):
    m = mission_in(state)
    back = Mission.restore(m.snapshot(), m.params)
    assert back.snapshot() == m.snapshot()
    assert (back.state, back.current_name(), back.current_action()) == (m.state, m.current_name(), m.current_action())
    assert back.resume(READY) == m.resume(READY)
