"""FULL_STOP at the intersections a tour marks (managers/intersection_stop.py): every state of a
stop line × every event, hypothesis properties of an approach (never across the line without
standing its time there, always across after), a closed route's next lap, the tour's check of the
marking, and the whole stack standing at the default tour's crossing."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from ares.core.config.tour import TourZone
from ares.core.route import Route, Zone
from managers.intersection_stop import IntersectionStops, LineState, StopLine
from tests.helpers.stack import REPO

FULL_STOP_S, REACH_M, DECEL = 2.0, 0.5, 0.5
LINE, END = 100.0, 120.0  # the intersection from its stop line to its end


def route(closed=False, length=300.0, full_stop=True) -> Route:
    """A straight road, or a circle of that length."""
    zones = [Zone("intersection", LINE, END, full_stop), Zone("rtk_loss", 10.0, 20.0)]
    if closed:
        a = np.arange(0.0, 2 * math.pi, 0.5 / (length / (2 * math.pi)))
        x, y = length / (2 * math.pi) * np.cos(a), length / (2 * math.pi) * np.sin(a)
    else:
        x = np.arange(0.0, length, 0.5)
        y = np.zeros_like(x)
    return Route("road", x, y, np.zeros_like(x), closed, np.full(len(x), 6.0), zones=zones)


def stops(**kw) -> IntersectionStops:
    return IntersectionStops(route(**kw), FULL_STOP_S, REACH_M, DECEL)


def approach_limit(s: float) -> float:
    return math.sqrt(2 * DECEL * max(LINE - s - REACH_M / 2, 0.0))


# every state × event: (s, standing, time since the state was entered) -> (state, limit)
EVENTS = {
    "s unknown": (None, True, 0.0),
    "far ahead": (60.0, False, 0.0),
    "just before the line, rolling": (LINE - 0.3, False, 0.0),
    "at the line, standing a moment": (LINE - 0.3, True, 0.5),
    "at the line, standing its time": (LINE - 0.3, True, FULL_STOP_S),
    "a little past the line, standing its time": (LINE + 0.8, True, FULL_STOP_S),
    "in the intersection, rolling": (LINE + 10.0, False, 0.0),
    "past the intersection": (END + 5.0, False, 0.0),
}
INF = math.inf
EXPECTED = {  # (state before, event) -> (state after, limit)
    ("ARMED", "s unknown"): ("ARMED", 0.0),
    ("ARMED", "far ahead"): ("ARMED", approach_limit(60.0)),
    ("ARMED", "just before the line, rolling"): ("ARMED", 0.0),
    ("ARMED", "at the line, standing a moment"): ("STANDING", 0.0),  # the count begins
    ("ARMED", "at the line, standing its time"): ("STANDING", 0.0),  # ... at this step: not yet stood
    ("ARMED", "a little past the line, standing its time"): ("STANDING", 0.0),
    ("ARMED", "in the intersection, rolling"): ("ARMED", 0.0),  # (started in it) stop, then stand
    ("ARMED", "past the intersection"): ("ARMED", INF),
    ("STANDING", "s unknown"): ("STANDING", 0.0),
    ("STANDING", "far ahead"): ("ARMED", approach_limit(60.0)),  # (a pose jump back) armed again
    ("STANDING", "just before the line, rolling"): ("STANDING", 0.0),  # rolling: the count starts again
    ("STANDING", "at the line, standing a moment"): ("STANDING", 0.0),
    ("STANDING", "at the line, standing its time"): ("CLEARED", INF),
    ("STANDING", "a little past the line, standing its time"): ("CLEARED", INF),
    ("STANDING", "in the intersection, rolling"): ("STANDING", 0.0),
    ("STANDING", "past the intersection"): ("ARMED", INF),
    ("CLEARED", "s unknown"): ("CLEARED", INF),
    ("CLEARED", "far ahead"): ("ARMED", INF),  # re-armed; its limit from the next step
    ("CLEARED", "just before the line, rolling"): ("CLEARED", INF),
    ("CLEARED", "at the line, standing a moment"): ("CLEARED", INF),
    ("CLEARED", "at the line, standing its time"): ("CLEARED", INF),
    ("CLEARED", "a little past the line, standing its time"): ("CLEARED", INF),
    ("CLEARED", "in the intersection, rolling"): ("CLEARED", INF),
    ("CLEARED", "past the intersection"): ("ARMED", INF),
}


@pytest.mark.parametrize("state, event", sorted(EXPECTED))
def test_every_state_of_a_line_by_every_event(state, event):
    stops_ = stops()
    (line,) = stops_.lines
    s, standing, held = EVENTS[event]
    now = 50.0
    line.state = LineState(state)
    line.standing_since = now - held if state == "STANDING" and standing else None
    if state == "ARMED" and event.endswith("standing its time"):
        line.standing_since = None  # armed: nothing counted yet
    limit, changes = stops_.step(now, s, standing)
    expected_state, expected_limit = EXPECTED[(state, event)]
    assert line.state.value == expected_state
    assert limit == pytest.approx(expected_limit)
    assert [c.state.value for c in changes] == ([] if expected_state == state else [expected_state])


def test_a_route_without_marked_lines_limits_nothing():
    unmarked = IntersectionStops(route(full_stop=False), FULL_STOP_S, REACH_M, DECEL)
    assert unmarked.lines == []
    assert unmarked.step(0.0, LINE, True) == (INF, []) and unmarked.step(0.0, None, False) == (INF, [])


def drive_through(stops_, s0: float, v0: float, dt: float = 0.05, seconds: float = 80.0):
    """A shuttle that obeys the limit (braking at most 2 m/s², speeding up at 1 m/s² towards 4 m/s):
    [(t, s, v, state)] of the drive."""
    s, v, out = s0, v0, []
    for k in range(int(seconds / dt)):
        t = k * dt
        limit, _ = stops_.step(t, s, abs(v) <= 0.05)
        target = min(4.0, limit)
        v = max(0.0, v - 2.0 * dt) if v > target else min(target, v + 1.0 * dt)
        s += v * dt
        out.append((t, s, v, stops_.lines[0].state))
    return out


@settings(max_examples=200, deadline=None)
@given(s0=st.floats(0.0, LINE - 15.0), v0=st.floats(0.0, 3.0))
def test_an_obedient_shuttle_stands_its_time_at_the_line_and_then_crosses(s0, v0):
    v0 = min(v0, approach_limit(s0))  # coming within the limit (a faster one is the gate's to slow)
    run = drive_through(stops(), s0, v0)
    standing_at_line = [t for t, s, v, _ in run if v <= 0.05 and LINE - REACH_M - 0.5 <= s <= LINE + REACH_M]
    crossed = [t for t, s, _, _ in run if s > LINE + 1.0]
    assert crossed, "it never crossed"
    assert standing_at_line and standing_at_line[0] + FULL_STOP_S <= crossed[0] + 1e-9
    assert all(s <= LINE + 1.0 for t, s, _, _ in run if t < standing_at_line[0])  # never across before standing
    assert max(s for _, s, _, _ in run) > END  # and through the intersection


def test_on_a_closed_route_the_next_lap_stops_again():
    loop = stops(closed=True, length=300.0)
    run = drive_through(loop, 50.0, 0.0, seconds=220.0)
    laps = np.array([s for _, s, _, _ in run])
    wrapped = laps % loop.length
    stood = [t for (t, _, v, state), w in zip(run, wrapped, strict=True) if state is LineState.STANDING and v <= 0.05]
    assert laps[-1] > 50.0 + 2 * loop.length  # two laps and more
    # one standing spell per pass of the line: the gaps between them are laps, not steps
    spells = [t for k, t in enumerate(stood) if k == 0 or t - stood[k - 1] > 1.0]
    assert len(spells) >= 2
    assert all(abs(w - LINE) < 1.0 for (t, _, _, _), w in zip(run, wrapped, strict=True) if t in set(spells))


def test_a_tour_marks_a_stop_line_only_at_an_intersection():
    assert TourZone(kind="intersection", s_start=1, s_end=2, full_stop=True).full_stop
    with pytest.raises(ValidationError, match="marks an intersection's stop line"):
        TourZone(kind="rtk_loss", s_start=1, s_end=2, full_stop=True)


def test_a_stop_line_is_a_line_object_of_the_route():
    (line,) = stops().lines
    assert line == StopLine(LINE, END) and line.state is LineState.ARMED


def test_in_the_whole_stack_the_shuttle_stands_at_a_marked_crossing_then_crosses(tmp_path):
    """The default tour with its crossing's first pass marked (`full_stop: true`), the in-process
    stack from 40 m before it: the mission's FULL_STOP stands the shuttle at the line through the
    movement gate, full_stop_s, then it crosses; the black box has both events and the seconds."""
    from tests.helpers.records import records, stored
    from tests.test_in_process_stack import drive

    default = (REPO / "ares" / "core" / "config" / "tours" / "default.yaml").read_text()
    crossing = "{kind: intersection, s_start: 502, s_end: 532}"
    assert crossing in default
    tour = tmp_path / "stop_sign.yaml"
    tour.write_text(default.replace(crossing, "{kind: intersection, s_start: 502, s_end: 532, full_stop: true}", 1))
    result = drive(tmp_path / "run", seconds=40, tour=str(tour), sim={"start_s_m": 462.0})
    assert result["ok"] and result["collisions"] == 0 and result["invariant_violations"] == 0
    _, events = stored(tmp_path / "run" / "blackbox.sqlite")
    stood = [e for e in events if e["kind"] == "full_stop"]
    crossed = [e for e in events if e["kind"] == "full_stop_cleared"]
    assert len(stood) == 1 and len(crossed) == 1 and stood[0]["data"]["line_s"] == 502.0
    assert crossed[0]["t"] - stood[0]["t"] == pytest.approx(2.0, abs=0.15)
    speed = {int(r["t"]): r["speed_mps"] for r in records(tmp_path / "run" / "blackbox.sqlite")}
    assert speed[math.ceil(stood[0]["t"])] < 0.05  # standing at the line
    assert speed[int(crossed[0]["t"]) + 8] > 1.0  # and across
    assert result["distance_m"] > 70  # through the crossing (502-532) from 462
