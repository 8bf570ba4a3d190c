"""Speed manager: the profile from curvature and grade (ARES eqs. 16–17), its single-speed
sections (Figure 17), the node, and `ares route profile`."""

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings

from ares import cli
from ares.core import config
from ares.core.clock import ManualClock
from ares.core.membus import MemoryNetwork
from ares.core.messages import PathMatch
from ares.core.route import Route
from managers.speed import (
    KINDS,
    MIN_RAMP_MPS2,
    G,
    SpeedProfileParams,
    SpeedTable,
    sections,
    speed_limits,
    speed_profile,
    speed_sections,
)
from managers.speed_node import SpeedManager
from tests.helpers.random_routes import routes

PARAMS = SpeedProfileParams()
VEHICLE = config.load_vehicle("ares_shuttle")


def circle(radius: float, spacing: float = 0.25) -> Route:
    a = np.linspace(0.0, 2 * math.pi, int(2 * math.pi * radius / spacing), endpoint=False)
    x, y = radius * np.cos(a), radius * np.sin(a)
    return Route("circle", x, y, np.zeros_like(x), True, np.full(len(x), 4.0))


def straight_into_a_turn(grade: float = 0.0, straight: float = 100.0, radius: float = 10.0) -> Route:
    """An open route: `straight` metres along x falling (grade < 0) or rising at `grade`, then a
    quarter turn of `radius` to the left on the level."""
    xs = np.arange(0.0, straight, 0.25)
    a = np.linspace(0.0, math.pi / 2, int(math.pi / 2 * radius / 0.25) + 1)
    x = np.concatenate([xs, straight + radius * np.sin(a)])
    y = np.concatenate([np.zeros_like(xs), radius * (1 - np.cos(a))])
    z = np.concatenate([grade * (xs - straight), np.zeros_like(a)])
    return Route("turn", x, y, z, False, np.full(len(x), 4.0))


# ---- the profile --------------------------------------------------------------------------------


def test_the_speed_in_a_turn_is_sqrt_of_lateral_acceleration_times_radius():
    # R = 20 m, a_lat = 0.35 m/s²: v = sqrt(7) = 2.6458 m/s, below the 3.5 m/s cruise
    v = speed_profile(circle(20.0), cruise=3.5, lateral_accel=0.35, decel=0.5, accel=0.5)
    assert v == pytest.approx(math.sqrt(0.35 * 20.0), rel=0.01)
    # a wide circle is a straight: the cruise speed
    assert speed_profile(circle(200.0), 3.5, 0.35, 0.5, 0.5) == pytest.approx(3.5)


def test_braking_before_a_turn_stays_within_the_deceleration():
    route = straight_into_a_turn()
    v = speed_profile(route, cruise=3.5, lateral_accel=0.35, decel=0.5, accel=0.5)
    ds = np.diff(route.s)
    # v² falls by at most 2·d·ds from one sample to the next ...
    assert np.all(v[:-1] ** 2 - v[1:] ** 2 <= 2 * 0.5 * ds + 1e-9)
    # ... and the vehicle is at the turn's speed when it gets there, having slowed from cruise
    turn = np.flatnonzero(route.s >= 100.0)[0]
    assert v[turn] == pytest.approx(math.sqrt(0.35 * 10.0), rel=0.02)
    assert v[0] == pytest.approx(3.5)
    braking = np.flatnonzero(v < 3.5 - 1e-9)[0]
    # from 3.5 to sqrt(3.5) m/s at 0.5 m/s²: (12.25 − 3.5) / 1 = 8.75 m, plus the look at the turn's
    # tightest part a few metres ahead (the 4 m window)
    assert 100.0 - route.s[braking] == pytest.approx(8.75 + 4.0, abs=1.0)


def test_a_descent_brakes_earlier_and_a_climb_later():
    flat = straight_into_a_turn(0.0)
    down = straight_into_a_turn(-0.03)  # downhill towards the turn
    up = straight_into_a_turn(+0.03)
    v_flat = speed_limits(flat, PARAMS, VEHICLE, grade=True)
    v_down = speed_limits(down, PARAMS, VEHICLE, grade=True)
    v_up = speed_limits(up, PARAMS, VEHICLE, grade=True)
    # without grade the path manager's profile is the same whatever the elevation
    assert np.array_equal(speed_limits(down, PARAMS, VEHICLE), v_flat)
    assert np.all(v_down <= v_flat + 1e-9) and np.any(v_down < v_flat - 0.1)
    assert np.all(v_up >= v_flat - 1e-9) and np.any(v_up > v_flat + 0.1)
    # on the descent the achieved deceleration is d − g·3 %: 0.5 − 0.294 = 0.206 m/s²
    straight = down.s < 95.0
    ds = np.diff(down.s)[straight[:-1]]
    drop = (v_down[:-1] ** 2 - v_down[1:] ** 2)[straight[:-1]]
    assert np.all(drop <= 2 * (PARAMS.decel_mps2 - G * 0.03) * ds + 1e-6)
    assert drop.max() == pytest.approx(2 * (PARAMS.decel_mps2 - G * 0.03) * ds.max(), rel=0.05)


def test_a_steep_descent_still_lets_the_profile_slow_down():
    steep = straight_into_a_turn(-0.2, straight=200.0)  # g·20 % is four times the braking budget
    v = speed_limits(steep, PARAMS, VEHICLE, grade=True)
    on_the_descent = steep.s[:-1] < 195.0
    drop = (v[:-1] ** 2 - v[1:] ** 2)[on_the_descent]
    assert np.all(drop <= 2 * MIN_RAMP_MPS2 * np.diff(steep.s)[on_the_descent] + 1e-6) and drop.max() > 0
    assert v[np.flatnonzero(steep.s >= 200.0)[0]] == pytest.approx(math.sqrt(0.35 * 10.0), rel=0.02)


# ---- the sections -------------------------------------------------------------------------------


def check_sections(route: Route, profile: np.ndarray, found) -> None:
    end = route.length if route.closed else route.s[-1]
    assert [sec.index for sec in found] == list(range(len(found)))
    assert found[0].s_start == 0.0 and found[-1].s_end == pytest.approx(end)
    for a, b in zip(found, found[1:]):
        assert a.s_end == b.s_start  # contiguous, in order
    for sec in found:
        assert sec.s_end >= sec.s_start and sec.kind in KINDS
        inside = (route.s >= sec.s_start) & (route.s <= sec.s_end)
        assert np.all(sec.speed <= profile[inside] + 1e-9)  # never above the profile


def test_the_default_tour_is_a_few_dozen_sections_of_every_kind():
    route = Route.from_tour("default")
    profile = speed_limits(route, PARAMS, VEHICLE, grade=True)
    found = speed_sections(route, PARAMS, VEHICLE, profile)
    check_sections(route, profile, found)
    assert 10 <= len(found) <= 100
    assert {sec.kind for sec in found} == set(KINDS)
    assert max(sec.speed for sec in found) == pytest.approx(3.5)
    for sec in found:
        if sec.kind == "cruise":
            assert sec.speed == pytest.approx(3.5)
    # an acceleration ramp is cut in steps of section_step_mps: each in a higher step than the last
    step = PARAMS.section_step_mps
    for a, b in zip(found, found[1:]):
        if a.kind == b.kind == "acceleration":
            assert math.floor(b.speed / step) > math.floor(a.speed / step)
        if a.kind == b.kind == "deceleration":
            assert math.floor(b.speed / step) < math.floor(a.speed / step)


def test_an_open_route_ends_in_a_stop():
    route = straight_into_a_turn()
    profile = speed_limits(route, PARAMS, VEHICLE, grade=True)
    found = speed_sections(route, PARAMS, VEHICLE, profile)
    check_sections(route, profile, found)
    assert found[-1].speed == 0.0 and found[-1].kind == "deceleration"


@settings(max_examples=40, deadline=None)
@given(routes)
def test_sections_cover_any_route_contiguously_below_its_profile(route):
    profile = speed_profile(route, 3.5, 0.35, 0.5, 0.5, grade=True)
    check_sections(route, profile, sections(route, profile, 3.5, 0.35, None, 0.5))


# ---- the node -----------------------------------------------------------------------------------


def match_at(s: float, t: float) -> PathMatch:
    return PathMatch(
        t=t,
        index=0,
        s=s,
        lap=0,
        xte=0.0,
        heading_error=0.0,
        zones=[],
        force_odometry=False,
        distance_to_end_m=None,
        ahead_x=[],
        ahead_y=[],
        ahead_yaw=[],
        ahead_curvature=[],
        ahead_speed=[],
        ahead_s=[],
    )


def test_the_node_publishes_the_sections_and_the_limits_where_the_vehicle_is(run_config):
    clock = ManualClock()
    network = MemoryNetwork()
    node = SpeedManager(run_config, clock=clock, bus=network.bus("speed_manager", clock))
    node.setup()
    bus = network.bus("test", clock)
    limits = bus.subscribe("speed/limits", queue=1000)
    listed = bus.subscribe("speed/sections", queue=100)
    table = SpeedTable(Route.from_tour("default"), PARAMS, VEHICLE)

    def step(t, s=None):
        clock.set(t)
        if s is not None:
            bus.publish("path/match", match_at(s, t))
        node.step_once(t)

    step(0.0)  # no match yet: the sections, no limits
    assert [m for _, m in limits.drain()] == []
    sent = [m for _, m in listed.drain()]
    assert len(sent) == 1 and len(sent[0].sections) == len(table.sections) and sent[0].closed
    assert sent[0].sections[-1].s_end == pytest.approx(sent[0].length_m)

    cruise = next(sec for sec in table.sections if sec.kind == "cruise" and sec.s_end - sec.s_start > 50.0)
    s = cruise.s_start + 10.0
    for k in range(1, 21):  # 1 s at 20 Hz
        step(round(k * 0.05, 9), s)
    got = [m for _, m in limits.drain()]
    assert len(got) == 20
    last = got[-1]
    assert last.section == cruise.index and last.kind == "cruise" and last.limit_mps == pytest.approx(3.5)
    coming = table.sections[(cruise.index + 1) % len(table.sections)]
    assert last.next_section == coming.index and last.next_limit_mps == pytest.approx(coming.speed)
    assert last.distance_to_next_m == pytest.approx(cruise.s_end - s)
    # the sections come again after 1 / sections_rate_hz = 2 s, not at every step
    assert len([m for _, m in listed.drain()]) == 0
    step(2.0, s)
    assert len([m for _, m in listed.drain()]) == 1

    # the last section of the loop: the next one is the first
    step(2.05, table.route.length - 0.1)
    last = [m for _, m in limits.drain()][-1]
    assert last.section == len(table.sections) - 1 and last.next_section == 0

    # the match goes stale: speed/limits goes quiet
    limits.drain()
    step(2.05 + 1.5)
    assert [m for _, m in limits.drain()] == []


def test_an_open_route_has_no_section_after_its_last():
    table = SpeedTable(straight_into_a_turn(), PARAMS, VEHICLE)
    end = table.limits(0.0, table.route.length + 3.0)
    assert end.section == len(table.sections) - 1 and end.next_section is None
    assert end.next_limit_mps is None and end.distance_to_next_m is None
    start = table.limits(0.0, -2.0)
    assert start.section == 0 and start.next_section == 1


# ---- `ares route profile` -----------------------------------------------------------------------


@pytest.mark.parametrize("suffix", [".png", ".svg"])
def test_route_profile_draws_the_picture_and_prints_a_summary(tmp_path, capsys, suffix):
    out = tmp_path / f"profile{suffix}"
    assert cli.main(["route", "profile", "default", "--out", str(out)]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert out.stat().st_size > 10_000
    assert summary["picture"] == str(out) and summary["route"] == "default"
    assert summary["sections"] > 10 and summary["max_speed_mps"] == pytest.approx(3.5)
    assert 0 < summary["min_speed_mps"] < summary["max_speed_mps"]


def test_route_profile_reads_a_route_file_and_refuses_a_bad_picture_name(tmp_path, capsys):
    route = tmp_path / "line.csv"
    route.write_text("x,y\n0,0\n60,0\n")
    out = tmp_path / "line.png"
    assert cli.main(["route", "profile", str(route), "--vehicle", "ares_shuttle", "--out", str(out)]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert out.exists() and summary["min_speed_mps"] == 0.0  # an open route stops at its end
    assert cli.main(["route", "profile", str(route), "--out", str(tmp_path / "line.jpg")]) != 0
    assert cli.main(["route", "profile", "no_such_tour", "--out", str(out)]) != 0
