"""Path manager: reachable-nearest matching on the KD-tree, the path ahead, and the node."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ares.core import config
from ares.core.clock import ManualClock
from ares.core.config import ConfigError
from ares.core.membus import MemoryNetwork
from ares.core.messages import EventLevel, Pose
from ares.core.node import ContractError
from ares.core.route import Route
from managers import path as path_module
from managers.path import PathIndex, PathManagerParams, PathTracker, zone_kinds_at
from managers.path_node import PathManager
from managers.speed import SpeedProfileParams, speed_limits
from tests.helpers.path_match_reference import ReferencePathIndex
from tests.helpers.random_routes import pose_along, routes

PARAMS = PathManagerParams()
VEHICLE = config.load_vehicle("ares_shuttle")
CROSSING_PASSES = (517.0, 1320.0)  # the default tour's two passes over its crossing


@pytest.fixture(scope="module")
def tour():
    return Route.from_tour("default")


@pytest.fixture(scope="module")
def index(tour):
    return PathIndex(tour, PARAMS, speed_limits(tour, SpeedProfileParams(), VEHICLE))


def offset_pose(route, s, offset=0.0, dyaw=0.0):
    """A pose `offset` metres left of the route at s, heading along it (plus dyaw)."""
    x, y, _, yaw = route.point_at(s)
    return x - math.sin(yaw) * offset, y + math.cos(yaw) * offset, yaw + dyaw


def drive(index, route, s_from, s_to, step=0.2, offset=0.0, hint=None):
    """Matches along a drive from s_from to s_to (unwrapped), each hinted by the last."""
    hint = s_from - step if hint is None else hint
    out = []
    for s in np.arange(s_from, s_to, step):
        m = index.match(*offset_pose(route, float(s), offset), s_hint=hint)
        assert m is not None, f"no match at s={s:.1f}"
        out.append((float(s), m))
        hint = m.progress
    return out


def straight_route(tmp_path, length=100.0):
    path = tmp_path / "line.csv"
    path.write_text(f"x,y\n0,0\n{length},0\n")
    return Route.from_csv(path)


def hairpin_route(gap=5.0, leg=40.0):
    """Out along y=0, a half circle of diameter `gap` to the left, back along y=gap: an open route."""
    r = gap / 2
    out = np.column_stack([np.arange(0.0, leg, 0.25), np.zeros(int(leg / 0.25))])
    a = np.linspace(-math.pi / 2, math.pi / 2, int(math.pi * r / 0.25) + 1)[:-1]
    arc = np.column_stack([leg + r * np.cos(a), r + r * np.sin(a)])
    back = np.column_stack([np.arange(leg, 0.0, -0.25), np.full(int(leg / 0.25), gap)])
    xy = np.vstack([out, arc, back])
    return Route("hairpin", xy[:, 0], xy[:, 1], np.zeros(len(xy)), False, np.full(len(xy), 4.0))


# ---- the default tour's crossing and corners ---------------------------------------------------


def test_the_default_tour_crosses_itself(tour):
    (ax, ay, _, ayaw), (bx, by, _, byaw) = (tour.point_at(s) for s in CROSSING_PASSES)
    assert math.hypot(ax - bx, ay - by) < 0.5
    assert abs(math.remainder(ayaw - byaw, 2 * math.pi)) > 2.0


@pytest.mark.parametrize("own, other", [CROSSING_PASSES, CROSSING_PASSES[::-1]])
def test_at_the_crossing_the_hint_keeps_the_match_on_its_pass(index, tour, own, other):
    for offset in (-1.0, 0.0, 1.0):
        x, y, yaw = offset_pose(tour, own, offset)
        for lap in (0, 2):
            hint = lap * tour.length + own - 1.0
            m = index.match(x, y, yaw, s_hint=hint)
            assert m.search == "tracked" and m.lap == lap
            assert m.s == pytest.approx(own, abs=0.05) and m.xte == pytest.approx(offset, abs=1e-3)
    # the hint alone is enough: with no heading test at all, the window still picks the pass
    blind = PathIndex(tour, PARAMS.model_copy(update={"max_heading_error_rad": math.pi}))
    x, y, _ = offset_pose(tour, own, 0.3)
    other_yaw = tour.point_at(other)[3]
    m = blind.match(x, y, other_yaw, s_hint=own - 0.5)
    assert m.s == pytest.approx(own, abs=0.1)
    # and without any hint, the heading picks the pass the vehicle faces along
    x, y, yaw = offset_pose(tour, own, 0.0)
    assert index.match(x, y, yaw).s == pytest.approx(own, abs=0.05)
    assert index.match(x, y, other_yaw).s == pytest.approx(other, abs=0.6)


@pytest.mark.parametrize("own", CROSSING_PASSES)
def test_driving_through_the_crossing_never_leaves_its_pass(index, tour, own):
    for offset in (-1.5, 0.8):
        for s, m in drive(index, tour, own - 30, own + 30, offset=offset):
            assert m.s == pytest.approx(s, abs=0.02)
            assert m.xte == pytest.approx(offset, abs=0.02)
            assert m.search == "tracked"


def test_a_drive_round_the_tight_corners_is_continuous(index, tour):
    for start in (0.0, 220.0, 765.0, 1005.0):  # the 12-14 m radius corners
        for offset in (-1.5, 1.5):
            matches = [m for _, m in drive(index, tour, start - 10, start + 40, offset=offset)]
            steps = np.diff([m.progress for m in matches])
            # inside a polyline's vertex the nearest point may step back by ~offset x turn per
            # vertex (a few cm); anything more would be a jump
            assert steps.min() > -0.1 and steps.max() < 0.5
            assert all(m.search == "tracked" for m in matches)


# ---- a hairpin ----------------------------------------------------------------------------------


def test_on_a_hairpin_the_match_never_jumps_to_the_other_leg():
    route = hairpin_route(gap=5.0)
    index = PathIndex(route, PARAMS)
    leg_end = 40.0
    back_start = leg_end + math.pi * 2.5
    # 3.2 m inside the first leg is only 1.8 m from the second: still the first leg
    for hint in (None, 19.5):
        m = index.match(20.0, 3.2, 0.0, s_hint=hint)
        assert m.s == pytest.approx(20.0, abs=0.01) and m.xte == pytest.approx(3.2, abs=1e-6)
    # the same spot facing back: the second leg, 1.8 m to the left of it (it runs towards -x)
    m = index.match(20.0, 3.2, math.pi)
    assert m.s == pytest.approx(back_start + 20.0, abs=0.3) and m.xte == pytest.approx(1.8, abs=1e-6)
    # a whole drive round it, cutting 1.2 m inside: progress only ever moves forward a little
    matches = drive(index, route, 1.0, route.length - 1.0, offset=1.2)
    steps = np.diff([m.progress for _, m in matches])
    assert steps.min() > -0.1 and steps.max() < 0.5
    for s, m in matches:
        if s < leg_end - 3 or s > back_start + 3:  # on the legs: exactly the offset
            assert m.xte == pytest.approx(1.2, abs=1e-6)


# ---- the tree over {X, Y, Z, Ψ}: a ramp's levels, a road driven both ways ------------------------------

RAMP_RADIUS_M, RAMP_CLIMB_M = 15.0, 3.2  # a car park's spiral ramp: a storey per turn


def spiral_ramp(turns=3):
    """An open route climbing a helix: each turn exactly above the one before, in the same direction."""
    a = np.arange(0.0, 2 * math.pi * turns, 0.25 / RAMP_RADIUS_M)
    x, y = RAMP_RADIUS_M * np.cos(a), RAMP_RADIUS_M * np.sin(a)
    return Route("ramp", x, y, RAMP_CLIMB_M * a / (2 * math.pi), False, np.full(len(a), 4.0))


def there_and_back(leg=60.0):
    """Out along y = 0 and back along the very same line: every point passed in both directions."""
    out = np.arange(0.0, leg, 0.25)
    x = np.concatenate([out, leg - out])
    return Route("there-and-back", x, np.zeros_like(x), np.zeros_like(x), False, np.full(len(x), 4.0))


def test_on_a_spiral_ramp_the_match_is_on_the_vehicle_s_own_level():
    route = spiral_ramp()
    index = PathIndex(route, PARAMS)
    turn = route.length / 3
    wrong_level_without_height = 0
    for level in range(3):
        s = level * turn + 30.0
        x, y, z, yaw = route.point_at(s)
        for hint in (None, s - 0.2):
            m = index.match(x, y, yaw, hint, z=z)
            assert m.s == pytest.approx(s, abs=0.05) and abs(m.xte) < 1e-6, (level, hint)
        # without its height (the (x, y) tree of before) the ground alone cannot tell the levels apart
        wrong_level_without_height += abs(index.match(x, y, yaw, z=None).s - s) > turn / 2
    assert wrong_level_without_height >= 1
    # a pose jump from the ground floor to the top: the wide search lands on the top level
    x, y, z, yaw = route.point_at(2 * turn + 50.0)
    m = index.match(x, y, yaw, s_hint=30.0, z=z)
    assert m.search == "wide" and m.s == pytest.approx(2 * turn + 50.0, abs=0.05)
    # above the top level by more than max_height_error_m (a roof the route never reaches): no level at all
    assert index.match(x, y, yaw, z=z + PARAMS.max_height_error_m + 0.5) is None


def test_a_drive_up_the_ramp_stays_on_its_level_and_its_progress_moves_on():
    route = spiral_ramp()
    tracker = PathTracker(route, PARAMS)
    last = None
    for k, s in enumerate(np.arange(1.0, route.length - 1.0, 0.4)):
        x, y, z, yaw = route.point_at(float(s))
        m, _ = tracker.update(0.05 * k, x, y, yaw, 1e-4, z=z + 0.4, var_z=0.25)  # GNSS height 0.4 m high
        assert m is not None and m.s == pytest.approx(s, abs=0.05)
        assert last is None or 0.0 < m.progress - last < 0.5
        last = m.progress


def test_a_height_the_localization_is_not_sure_of_is_left_out():
    route = spiral_ramp()
    tracker = PathTracker(route, PARAMS)
    x, y, z, yaw = route.point_at(2 * route.length / 3 + 30.0)
    unsure, _ = tracker.update(0.0, x, y, yaw, 1e-4, z=z, var_z=PARAMS.max_height_sigma_m**2 * 4)
    assert unsure.s == pytest.approx(PathIndex(route, PARAMS).match(x, y, yaw, z=None).s)
    tracker.progress = None
    sure, _ = tracker.update(0.0, x, y, yaw, 1e-4, z=z, var_z=0.01)
    assert sure.s == pytest.approx(2 * route.length / 3 + 30.0, abs=0.05)


@pytest.mark.parametrize("offset", [0.0, 0.6, -0.6])
def test_on_a_road_driven_both_ways_the_heading_picks_the_pass(offset):
    route = there_and_back()
    index = PathIndex(route, PARAMS)
    for heading, expected in ((0.0, 20.0), (math.pi, 100.0)):  # out at s = 20, back past the same point at 100
        for hint in (None, expected - 0.2):
            m = index.match(20.0, offset, heading + 0.2, hint, z=0.0)
            assert m.s == pytest.approx(expected, abs=0.05), (heading, hint)
    # a drive back along the line, hinted all the way: never the outbound pass under it
    matches = drive(index, route, 62.0, route.length - 2.0, offset=offset)
    assert all(m.s == pytest.approx(s, abs=0.05) for s, m in matches)


# ---- laps, reverse heading, fallback --------------------------------------------------------------


def test_after_a_lap_the_lap_count_increments_and_s_wraps(index, tour):
    L = tour.length
    matches = drive(index, tour, L - 5.0, L + 5.0)
    assert matches[0][1].lap == 0 and matches[-1][1].lap == 1
    assert all(0.0 <= m.s < L for _, m in matches)
    assert matches[-1][1].s == pytest.approx(5.0 - 0.2, abs=0.05)
    assert matches[-1][1].progress == pytest.approx(L + 4.8, abs=0.05)
    # many laps later, far from the start line, the count holds
    matches = drive(index, tour, 7 * L + 600.0, 7 * L + 610.0)
    assert {m.lap for _, m in matches} == {7}
    assert matches[-1][1].s == pytest.approx(609.8, abs=0.05)


def test_a_vehicle_facing_against_the_route_is_not_matched(index, tour):
    x, y, yaw = offset_pose(tour, 400.0, 0.5)
    for hint in (None, 399.5):
        assert index.match(x, y, yaw + math.pi, s_hint=hint) is None
    assert index.match(x, y, yaw + 0.9, s_hint=399.5).search == "tracked"  # within the heading limit
    assert index.match(x, y, yaw + 1.1, s_hint=399.5) is None
    for own, other in (CROSSING_PASSES, CROSSING_PASSES[::-1]):
        x, y, yaw = offset_pose(tour, own, 0.5)
        # turned round at the crossing, the vehicle faces within 0.84 rad of the other pass: the
        # tracked search excludes both (its own pass by heading, the other by the hint's window);
        # the wide search then finds the other pass, and says so
        m = index.match(x, y, yaw + math.pi, s_hint=own - 0.5)
        assert m.search == "wide" and m.s == pytest.approx(other, abs=1.0)


def test_a_jump_or_a_start_off_the_path_falls_back_to_a_wide_search(index, tour):
    x, y, yaw = offset_pose(tour, 800.0, 0.0)
    m = index.match(x, y, yaw, s_hint=500.0)  # a pose jump of 300 m
    assert m.search == "wide" and m.s == pytest.approx(800.0, abs=0.05)
    assert m.progress == pytest.approx(800.0, abs=0.05)
    x, y, yaw = offset_pose(tour, 400.0, 12.0)  # placed 12 m beside the road
    m = index.match(x, y, yaw)
    assert m.search == "wide" and m.xte == pytest.approx(12.0, abs=0.01)
    x, y, yaw = offset_pose(tour, 400.0, 80.0)  # far off anything
    assert index.match(x, y, yaw) is None


# ---- open routes ----------------------------------------------------------------------------------


def test_open_route_end_and_distance_to_end(tmp_path):
    route = straight_route(tmp_path, 100.0)
    tracker = PathTracker(route, PARAMS, np.full(len(route), 2.0))
    for x, expected_s in ((10.0, 10.0), (99.7, 99.7), (101.0, 101.0)):
        m, msg = tracker.update(0.0, x, 0.4, 0.0)
        assert m.s == pytest.approx(expected_s, abs=1e-6)
        assert m.xte == pytest.approx(0.4, abs=1e-9)  # past the end, overshoot is no cross-track error
        assert msg.distance_to_end_m == pytest.approx(max(100.0 - expected_s, 0.0), abs=1e-6)
        assert msg.lap == 0
    assert msg.ahead_x == [100.0]  # past the end: only the end remains


def test_zones_forced_odometry_and_the_road_s_width(index, tour):
    tracker = PathTracker(tour, PARAMS, index.speed_limit)
    cases = [  # s, zones, forced odometry, the narrowest width over the 30 m sent ahead
        (40.0, [], False, 3.2),  # 20 m before the narrow lane: its width already
        (100.0, ["narrow"], False, 3.2),
        (230.0, [], False, 6.0),  # 30 m past it
        (400.0, [], False, 6.0),
        (517.0, ["intersection"], True, 6.0),
        (620.0, ["rtk_loss"], False, 6.0),
        (1320.0, ["intersection"], True, 6.0),
        (1575.0, ["road_opening"], True, 6.0),
    ]
    for s, zones, forced, width in cases:
        tracker.progress = s - 0.3
        _, msg = tracker.update(1.0, *offset_pose(tour, s, 0.2))
        assert msg.zones == zones and msg.force_odometry is forced, s
        assert msg.road_width_ahead_m == pytest.approx(width), s  # the control manager's creep keeps within it
        assert msg.distance_to_end_m is None
        assert zone_kinds_at(tour, s) == zones
        assert len(msg.ahead_x) == int(PARAMS.ahead_length_m / PARAMS.ahead_step_m) + 1
        assert msg.ahead_speed[0] == pytest.approx(np.interp(msg.s, tour.s, index.speed_limit), abs=0.05)


# ---- the path ahead -------------------------------------------------------------------------------


def test_ahead_wraps_on_a_closed_route(index, tour):
    L = tour.length
    i = tour.index_at(L - 10.0)
    a = index.ahead(i, 30.0, 0.5, s=L - 10.0)
    assert len(a.s) == 61
    assert a.s[0] == pytest.approx(L - 10.0) and a.s[-1] == pytest.approx(20.0)
    assert np.all((a.s >= 0) & (a.s < L))
    steps = np.hypot(np.diff(a.x), np.diff(a.y))
    assert steps == pytest.approx(np.full(60, 0.5), abs=0.01)  # no jump across the start line
    for s, x, y in zip(a.s, a.x, a.y):
        px, py, _, _ = tour.point_at(float(s))
        assert (x, y) == pytest.approx((px, py), abs=1e-6)
    default = index.ahead(i, 30.0, 0.5)  # from the pose's own s
    assert default.s[0] == pytest.approx(tour.s[i])


def test_ahead_stops_at_the_end_of_an_open_route(tmp_path):
    route = straight_route(tmp_path, 100.0)
    index = PathIndex(route, speed_limit=np.linspace(3.0, 0.0, len(route)))
    a = index.ahead(route.index_at(85.2), 30.0, 0.5, s=85.2)
    assert a.s[0] == pytest.approx(85.2) and a.s[-1] == pytest.approx(route.length)
    assert len(a.s) == 31 and np.all(np.diff(a.s) > 0)
    assert a.x[-1] == pytest.approx(100.0) and a.speed[-1] == pytest.approx(0.0)
    far = index.ahead(route.index_at(10.0), 30.0, 0.5, s=10.0)
    assert len(far.s) == 61 and far.s[-1] == pytest.approx(40.0)


# ---- agreement with Route.project -----------------------------------------------------------------


@settings(max_examples=300, deadline=None)
@given(s=st.floats(0.0, 1587.0), offset=st.floats(-2.0, 2.0), dyaw=st.floats(-0.5, 0.5), lag=st.floats(-1.0, 3.0))
def test_cross_track_error_equals_route_projection(tour, index, s, offset, dyaw, lag):
    x, y, yaw = offset_pose(tour, s, offset, dyaw)
    hint = s - lag
    m = index.match(x, y, yaw, s_hint=hint)
    ps, pxte, _ = tour.project(x, y, s_hint=hint)
    assert m is not None and m.search == "tracked"
    assert m.xte == pytest.approx(pxte, abs=1e-3)
    assert abs(tour.step_between(ps, m.s)) < 1e-3


# ---- the same results as before the tracked search scanned the hint's window directly ----------
#
# tests/path_match_reference.py is a frozen copy of match() from before that change (a KD ball
# query filtered by heading and window, then refined by its own copy of the projection): every
# query must give exactly what it gives, down to the last bit of every float and the search kind.

matcher_params = st.fixed_dictionaries(
    {
        "radius_m": st.one_of(st.sampled_from([1.0, 2.5, 5.0]), st.floats(0.3, 10.0)),
        "fallback_radius_m": st.floats(0.0, 60.0),
        "max_heading_error_rad": st.floats(0.05, 3.2),
        "window_behind_m": st.floats(0.0, 30.0),
        "window_ahead_m": st.floats(0.0, 60.0),
    }
)


def mostly(usual, unusual):
    return st.one_of(usual, usual, usual, unusual)  # three times in four


# a query: how far the vehicle moved along the route since the last one, its offset across it
# and its yaw error (mostly small, as when tracking), and what the matcher is told: the heading
# or not, which hint, which radius
queries = st.lists(
    st.tuples(
        st.floats(-1.0, 3.0),
        mostly(st.floats(-1.5, 1.5), st.floats(-12.0, 12.0)),
        mostly(st.floats(-0.3, 0.3), st.floats(-3.2, 3.2)),
        st.sampled_from(["yaw"] * 4 + ["no yaw"]),
        st.sampled_from(["last progress"] * 6 + ["none", "elsewhere"]),
        st.floats(-100.0, 2000.0),
        st.sampled_from([None] * 4 + [0.5, 3.0, 20.0]),
    ),
    min_size=10,
    max_size=60,
)


def as_tuple(m):
    return None if m is None else (m.index, m.s, m.progress, m.lap, m.xte, m.heading_error, m.search)


@settings(max_examples=500, deadline=None)
@given(
    route=routes,
    params=matcher_params,
    start=st.floats(-0.2, 1.2),
    laps=st.integers(0, 50),
    on_grid=st.booleans(),
    queries=queries,
)
def test_match_returns_what_the_reference_returns(route, params, start, laps, on_grid, queries):
    """on_grid puts the vehicle on a 0.5 m grid: on a lattice route, at exactly equal distances
    from several poses, or exactly at the radius. The reference's tree was over (x, y) alone: with
    the heading weighing nothing and no height given, today's {X, Y, Z, Ψ} tree must agree with it
    exactly (what the heading and the height change is tested on routes made for it, below)."""
    flat = PARAMS.model_copy(update={**params, "heading_scale_m": 0.0})
    index, reference = PathIndex(route, flat), ReferencePathIndex(route, **params)
    s = start * route.length + (laps * route.length if route.closed else 0.0)
    progress = None  # the reference's last match, the hint as the path manager keeps it
    for step, offset, dyaw, heading, hint_kind, elsewhere, radius in queries:
        s += step
        x, y, yaw = pose_along(route, s, offset)
        if on_grid:
            x, y = round(2.0 * x) / 2.0, round(2.0 * y) / 2.0
        yaw = None if heading == "no yaw" else yaw + dyaw
        hint = {"last progress": progress, "none": None, "elsewhere": elsewhere}[hint_kind]
        expected = reference.match(x, y, yaw, hint, radius)
        assert as_tuple(index.match(x, y, yaw, hint, radius)) == expected, (x, y, yaw, hint, radius)
        if expected is not None:
            progress = expected[2]


# ---- the parameters ---------------------------------------------------------------------------------


def straight_route_in_memory(length=100.0):
    x = np.arange(0.0, length + 0.25, 0.25)
    return Route("line", x, np.zeros_like(x), np.zeros_like(x), False, np.full(len(x), 4.0))


def test_the_index_takes_the_sections_values():
    params = PathManagerParams.model_validate(
        {
            "radius_m": 2.0,
            "fallback_radius_m": 20.0,
            "window_behind_m": 1.0,
            "window_ahead_m": 3.0,
            "max_heading_error_rad": 0.5,
        }
    )
    index = PathIndex(straight_route_in_memory(), params)
    assert (index.radius_m, index.fallback_radius_m, index.window_behind_m, index.window_ahead_m) == (
        2.0,
        20.0,
        1.0,
        3.0,
    )
    assert index.cos_heading_limit == pytest.approx(math.cos(0.5))


def test_an_index_built_without_params_takes_the_sections_defaults():
    built = PathIndex(straight_route_in_memory())
    configured = PathIndex(straight_route_in_memory(), PARAMS)
    for attr in ("radius_m", "fallback_radius_m", "cos_heading_limit", "window_behind_m", "window_ahead_m"):
        assert getattr(built, attr) == getattr(configured, attr), attr


@pytest.mark.parametrize("key, bad", [("radius_m", 0.0), ("window_ahead_m", -1.0), ("pose_topic", "x/y")])
def test_a_bad_path_manager_section_is_refused_naming_the_key(key, bad):
    with pytest.raises(ConfigError, match=f"section 'path_manager'.*{key}"):
        config.section({"path_manager": {key: bad}}, "path_manager", PathManagerParams)


# ---- the node -------------------------------------------------------------------------------------


def test_the_contract_reads_the_fused_pose_and_publishes_the_match():
    # the module's docstring: the pose in (fixed to localization/pose), path/match out, the
    # speed_profile section read for the limits ahead
    assert [(i.topic, i.attr) for i in PathManager.inputs()] == [("localization/pose", "pose")]
    assert [(o.topic, o.attr) for o in PathManager.outputs()] == [("path/match", "match")]
    assert PathManager.services() == {}
    assert PathManager.sections == {"speed_profile": SpeedProfileParams}
    assert "path/match" in path_module.__doc__ and "path_rematch" in path_module.__doc__
    assert "path_lost" in path_module.__doc__


class PathManagerOnTheBus:
    PERIOD = 0.05

    def __init__(self, cfg):
        self.clock = ManualClock()
        self.network = MemoryNetwork()
        self.node = PathManager(cfg, clock=self.clock, bus=self.network.bus("path_manager", self.clock))
        self.node.setup()
        self.bus = self.network.bus("test", self.clock)
        self.matches = self.bus.subscribe("path/match", queue=1000)
        self.events = self.bus.subscribe("events", queue=100)

    def step(self, t, pose: Pose | None = None):
        self.clock.set(t)
        if pose is not None:
            self.bus.publish("localization/pose", pose)
        self.node.step_once(t)

    def new_matches(self):
        return [m for _, m in self.matches.drain()]

    def new_events(self):
        return [e for _, e in self.events.drain()]


def pose_on(route, s, t, offset=0.3, var_yaw=1e-4) -> Pose:
    x, y, yaw = offset_pose(route, s, offset)
    return Pose(
        t=t,
        x=x,
        y=y,
        z=0.0,
        yaw=yaw,
        v=4.0,
        yaw_rate=0.0,
        cov_xx=1e-4,
        cov_xy=0.0,
        cov_yy=1e-4,
        var_yaw=var_yaw,
        var_v=1e-4,
        position_std_m=0.01,
        rtk=True,
        gnss_age_s=0.1,
    )


@pytest.fixture
def path_manager(run_config):
    return PathManagerOnTheBus(run_config)


def test_path_manager_node_matches_published_poses(path_manager, tour):
    pm = path_manager
    # along the first pass of the crossing, 1 m per period
    sent = [float(s) for s in np.arange(490.0, 546.0, 1.0)]
    t = 0.0
    for k, s in enumerate(sent):
        t = round(k * pm.PERIOD, 9)
        pm.step(t, pose_on(tour, s, t))
    got = pm.new_matches()
    assert len(got) == len(sent)
    for s, m in zip(sent, got):
        assert m.s == pytest.approx(s, abs=0.05)
        assert m.lap == 0 and m.xte == pytest.approx(0.3, abs=0.01)
        assert m.zones == (["intersection"] if 502.0 <= m.s <= 532.0 else [])
        assert m.force_odometry is (502.0 <= m.s <= 532.0)
        assert m.distance_to_end_m is None and len(m.ahead_s) == 61
        assert m.ahead_s[0] == pytest.approx(m.s)
    assert any(m.force_odometry for m in got) and not all(m.force_odometry for m in got)
    # the first match is the nearest reachable pose (nothing to track yet), then it tracks: no event
    assert pm.new_events() == []
    # the pose goes stale: nothing more is published
    last = t
    pm.step(round(last + PARAMS.pose_timeout_s - pm.PERIOD, 9))
    assert len(pm.new_matches()) == 1
    for k in range(1, 12):
        pm.step(round(last + PARAMS.pose_timeout_s + k * pm.PERIOD, 9))
    assert pm.new_matches() == []
    # back on the other pass of the crossing: found again by the wide search, and it says so
    t = round(last + 2.0, 9)
    for s in np.arange(1310.0, 1316.0, 1.0):
        t = round(t + pm.PERIOD, 9)
        pm.step(t, pose_on(tour, float(s), t))
    got = pm.new_matches()
    assert len(got) == 6 and got[-1].s == pytest.approx(1315.0, abs=0.05) and got[-1].force_odometry
    rematches = [e for e in pm.new_events() if e.kind == "path_rematch"]
    assert len(rematches) == 1 and rematches[0].level == EventLevel.WARNING
    assert rematches[0].data["previous_progress"] == pytest.approx(545.0, abs=0.05)
    assert rematches[0].data["s"] == pytest.approx(1310.0, abs=0.05)


def test_path_manager_node_says_once_that_it_lost_the_path(path_manager, tour):
    pm = path_manager
    pm.step(0.0, pose_on(tour, 400.0, 0.0))
    pm.new_events()
    for k in range(1, 6):  # 80 m beside the road: nothing reachable
        t = round(k * pm.PERIOD, 9)
        pm.step(t, pose_on(tour, 400.0, t, offset=80.0))
    lost = pm.new_events()
    assert [(e.kind, e.level) for e in lost] == [("path_lost", EventLevel.WARNING)]
    assert len(pm.new_matches()) == 1  # only the match before it went off
    # back on the road within the hint's window: tracked again, and a later loss is said again
    pm.step(0.3, pose_on(tour, 400.5, 0.3))
    assert pm.new_matches()[0].s == pytest.approx(400.5, abs=0.05) and pm.new_events() == []
    pm.step(0.35, pose_on(tour, 400.5, 0.35, offset=80.0))
    assert [e.kind for e in pm.new_events()] == ["path_lost"]


def test_a_vehicle_placed_off_its_path_at_start_up_is_found_by_the_wide_search(path_manager, tour):
    path_manager.step(0.0, pose_on(tour, 400.0, 0.0, offset=12.0))
    [m] = path_manager.new_matches()
    assert m.s == pytest.approx(400.0, abs=0.05) and m.xte == pytest.approx(12.0, abs=0.01)
    # nothing was tracked yet: worth a note, not a warning
    [found] = path_manager.new_events()
    assert (found.kind, found.level) == ("path_rematch", EventLevel.INFO)
    assert found.data["previous_progress"] is None


def test_path_manager_node_matches_by_position_while_the_heading_is_a_guess(path_manager, tour):
    pm = path_manager
    x, y, yaw = offset_pose(tour, 400.0, 0.3)
    backwards = Pose(
        t=0.0,
        x=x,
        y=y,
        z=0.0,
        yaw=yaw + math.pi,
        v=0.0,
        yaw_rate=0.0,
        cov_xx=1e-4,
        cov_xy=0.0,
        cov_yy=1e-4,
        var_yaw=PARAMS.max_heading_sigma_rad**2 * 4,
        var_v=1e-4,
        position_std_m=0.01,
        rtk=True,
        gnss_age_s=0.1,
    )
    pm.step(0.0, backwards)
    [m] = pm.new_matches()
    assert m.s == pytest.approx(400.0, abs=0.5)


def test_the_path_manager_refuses_an_undeclared_topic(path_manager):
    with pytest.raises(ContractError, match="does not declare"):
        path_manager.node.bus.publisher("control/setpoint")


# ---- `ares bench path` ----------------------------------------------------------------------------


def test_path_bench_reports_build_match_and_ukf_figures():
    from ares.cli import build_parser
    from ares.tools.bench import path as path_bench

    args = build_parser().parse_args(["bench", "path", "--json"])
    assert args.bench == "path" and args.json
    route = path_bench.bench_route(4000)
    assert len(route) == 4000 and route.closed and np.diff(route.s) == pytest.approx(np.full(3999, 0.5), abs=1e-3)
    result = path_bench.run_path_bench(poses=20_000, queries=1000, builds=2, ukf_steps=20)
    for key in (
        "kdtree_build_ms",
        "query_p50_us",
        "kd_ball_query_p50_us",
        "kd_nearest_query_p50_us",
        "ukf_step_p50_ms",
        "goals",
        "goals_met",
    ):
        assert key in result, key
    # the figures are measured, not judged here; what the matcher found is
    assert result["poses"] == 20_000 and result["queries"] == 1000
    assert result["matches_not_tracked"] == 0 and result["max_xte_error_m"] < 1e-3


def test_a_pose_with_an_unknown_heading_is_matched_by_position(index, tour):
    # before the vehicle has moved, the UKF's heading may be a guess; matching must not depend
    # on it, or a shuttle whose first fix came before its IMU would never set off
    x, y, yaw = offset_pose(tour, 400.0, 0.5)
    assert index.match(x, y, yaw + math.pi) is None
    m = index.match(x, y, None)
    assert m is not None and m.s == pytest.approx(400.0, abs=0.5)
