import math

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from ares.core import config
from ares.core.config import ConfigError, CoreConfig
from ares.core.route import SAMPLE_SPACING_M, Route, RouteError, load_route
from tests.helpers.path_match_reference import reference_project
from tests.helpers.random_routes import pose_along, routes


@pytest.fixture(scope="module")
def tour():
    return Route.from_tour("default")


def test_builtin_tour_meets_the_brief(tour):
    assert tour.closed
    assert 1000 <= tour.length <= 2000
    assert np.abs(tour.grade).max() <= 0.15  # hills up to about 15 %
    assert np.abs(tour.grade).max() >= 0.10
    assert 1 / np.abs(tour.curvature).max() <= 15  # sharp curves
    assert len(tour.pois) >= 4
    assert any(z.kind == "rtk_loss" for z in tour.zones)  # the sky blocked: no RTK
    assert any(z.kind == "no_4g" for z in tour.zones)  # no 4G: no corrections, the fix degrades as they age
    assert any(z.kind == "intersection" for z in tour.zones)
    assert tour.width.min() < 3.5  # a narrow stretch


def test_campus_route_is_the_dbw_papers_test_loop():
    """About 800 m of campus road with two roundabouts, back to the start (DBW paper §5.2)."""
    campus = Route.from_tour("campus")
    assert campus.closed and campus.length == pytest.approx(800, abs=25)
    assert np.abs(campus.grade).max() < 1e-9
    # A roundabout: round an island, turning left on radii <= 15 m through some 180 degrees
    # without a break (the rest of the way round is the entry and exit deflections).
    left = np.flatnonzero(campus.curvature >= 1 / 15.5)
    arcs = np.split(left, np.flatnonzero(np.diff(campus.s[left]) > 2.0) + 1)
    turned = [math.degrees(campus.curvature[a[0] : a[-1] + 1].sum() * SAMPLE_SPACING_M) for a in arcs]
    assert sum(t > 170 for t in turned) == 2, turned
    assert sum(z.kind == "intersection" for z in campus.zones) == 4  # their mouths
    profile = config.load_vehicle("techs4agecar")
    assert profile.max_speed_mps * 3.6 == pytest.approx(25, abs=0.1)  # the paper's 25 km/h


def test_tour_is_closed_and_evenly_sampled(tour):
    steps = np.hypot(np.diff(tour.x), np.diff(tour.y))
    closing = math.hypot(tour.x[0] - tour.x[-1], tour.y[0] - tour.y[-1])
    assert steps.max() < 0.3 and closing < 0.3
    assert steps.min() > 0.1


def test_the_route_crosses_itself_at_grade_inside_the_intersection_zones(tour):
    from scipy.spatial import cKDTree

    tree = cKDTree(np.column_stack([tour.x, tour.y]))
    crossings = [(i, j) for i, j in tree.query_pairs(0.3) if 100 < abs(tour.s[i] - tour.s[j]) < tour.length - 100]
    assert crossings
    for i, j in crossings:
        assert tour.in_zone(tour.s[i], "intersection") and tour.in_zone(tour.s[j], "intersection")
        assert abs(tour.z[i] - tour.z[j]) < 0.05


def test_projection_with_a_hint_keeps_to_the_pass_being_driven(tour):
    crossing_s = 517.0
    x, y, _, _ = tour.point_at(crossing_s)
    s_first, xte, _ = tour.project(x + 0.01, y, s_hint=crossing_s - 5)
    s_second, _, _ = tour.project(x + 0.01, y, s_hint=1320.0 - 5)
    assert abs(s_first - crossing_s) < 1.0
    assert abs(s_second - 1320.0) < 3.0
    assert abs(xte) < 0.05


def test_cross_track_error_sign_is_positive_to_the_left(tour):
    x, y, _, yaw = tour.point_at(400.0)
    left = (x - math.sin(yaw) * 0.5, y + math.cos(yaw) * 0.5)
    right = (x + math.sin(yaw) * 0.5, y - math.cos(yaw) * 0.5)
    assert tour.project(*left, s_hint=400.0)[1] == pytest.approx(0.5, abs=0.01)
    assert tour.project(*right, s_hint=400.0)[1] == pytest.approx(-0.5, abs=0.01)


def test_csv_route_is_read_and_resampled(tmp_path):
    path = tmp_path / "r.csv"
    path.write_text("x,y,z\n0,0,0\n10,0,1\n10,10,2\n")
    route = Route.from_csv(path)
    assert not route.closed
    assert route.length == pytest.approx(20.0, abs=1e-6)
    assert route.point_at(15.0)[:3] == pytest.approx((10.0, 5.0, 1.5))


@pytest.mark.parametrize(
    "text, message",
    [
        ("x,y\n0,0\n1,banana\n", ":3: expected numbers"),
        ("0,0\n1,2,3,4\n", ":2: expected 2 or 3"),
        ("0,0\n", "at least two points"),
        ("0,0\nnan,1\n", ":2: expected 2 or 3 finite"),
    ],
)
def test_bad_csv_files_name_the_line(tmp_path, text, message):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(RouteError, match=message):
        Route.from_csv(path)


def test_the_runs_route_is_the_configured_tour_or_the_route_file(tmp_path, tour):
    assert np.array_equal(load_route(CoreConfig()).x, tour.x)
    path = tmp_path / "r.csv"
    path.write_text("0,0\n10,0\n")
    route = load_route(CoreConfig(route_file=str(path)))
    assert not route.closed and route.length == pytest.approx(10.0)


def test_a_tour_file_missing_a_key_is_refused_naming_it(tmp_path):
    desc = config.load_yaml(config.named_file("tours", "default"))
    del desc["elevation"]
    desc["zones"][0]["kind"] = "rtk_lost"
    path = tmp_path / "broken_tour.yaml"
    path.write_text(yaml.safe_dump(desc))
    with pytest.raises(ConfigError) as info:
        Route.from_tour(str(path))
    message = str(info.value)
    assert str(path) in message and "elevation: required, missing" in message
    assert "zones.0.kind: Input should be 'rtk_loss'" in message


def test_an_unknown_tour_names_the_known_ones():
    with pytest.raises(ConfigError, match="unknown tour 'nowhere'; known: campus, default"):
        load_route(CoreConfig(tour="nowhere"))


def test_missing_route_file_is_a_clear_error(tmp_path):
    with pytest.raises(RouteError, match="cannot read"):
        Route.from_csv(tmp_path / "nope.csv")


def test_overshooting_the_end_of_an_open_route_is_not_cross_track_error(tmp_path):
    path = tmp_path / "line.csv"
    path.write_text("0,0\n10,0\n")
    route = Route.from_csv(path)
    s, xte, _ = route.project(11.0, 0.2, s_hint=9.5)
    assert s == pytest.approx(11.0) and xte == pytest.approx(0.2)
    s, xte, _ = route.project(-1.0, -0.1)
    assert s == pytest.approx(-1.0) and xte == pytest.approx(-0.1)


@settings(max_examples=300, deadline=None)
@given(
    route=routes,
    along=st.floats(-0.2, 1.2),
    offset=st.floats(-8.0, 8.0),
    hint_lag=st.one_of(st.none(), st.floats(-40.0, 40.0)),
    on_grid=st.booleans(),
)
def test_projection_returns_what_it_did_before_it_moved_to_ares_geometry(route, along, offset, hint_lag, on_grid):
    s = along * route.length
    x, y, _ = pose_along(route, s, offset)
    if on_grid:  # on a lattice route: exactly as near to two segments
        x, y = round(2.0 * x) / 2.0, round(2.0 * y) / 2.0
    hint = None if hint_lag is None else s - hint_lag
    assert route.project(x, y, s_hint=hint) == reference_project(route, x, y, s_hint=hint)
