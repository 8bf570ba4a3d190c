"""A headless run's picture (ares/app/lap_figure.py, `lap.svg` in the run's folder), read back as
SVG: the route and the path driven on one map, the cross-track error along the distance driven."""

from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from scipy.spatial import cKDTree

from ares.app.lap_figure import write_lap_svg
from ares.core.route import Route

SVG = "{http://www.w3.org/2000/svg}"
PERIODS = 20  # of the error's sine round the lap


def vertices(root: ET.Element, gid: str) -> np.ndarray:
    """The (x, y) points, in the picture's pixels, of the curve drawn with this id."""
    group = root.find(f".//{SVG}g[@id='{gid}']")
    assert group is not None, f"no curve {gid!r} in the picture"
    numbers = [float(v) for p in group.iter(f"{SVG}path") for v in re.findall(r"-?\d+(?:\.\d+)?", p.get("d", ""))]
    return np.array(numbers).reshape(-1, 2)


def texts(root: ET.Element) -> str:
    return "\n".join("".join(t.itertext()) for t in root.iter(f"{SVG}text"))


@pytest.fixture(scope="module")
def route():
    return Route.from_tour("default")


def test_the_picture_holds_the_route_the_path_driven_and_the_error_along_it(route, tmp_path):
    # driven: the route itself, moved across it by xte = 0.1 m sin(...) over whole periods: max
    # 0.100 m, RMSE 0.1 / sqrt(2) = 0.071 m, and 2 * PERIODS humps of |xte|
    s = route.s
    xte = 0.1 * np.sin(2.0 * math.pi * PERIODS * s / route.length)
    yaw = np.array([route.point_at(float(v))[3] for v in s])
    xs, ys = route.x - np.sin(yaw) * xte, route.y + np.cos(yaw) * xte
    out = write_lap_svg(tmp_path / "run" / "lap.svg", route, xs, ys, s, xte, "default: 1588 m in 499 s, ares_shuttle")
    assert out == tmp_path / "run" / "lap.svg"
    root = ET.parse(out).getroot()
    assert root.tag == f"{SVG}svg"

    words = texts(root)
    assert "default: 1588 m in 499 s, ares_shuttle" in words
    assert all(poi.name in words for poi in route.pois) and "driven" in words and "rtk loss" in words
    assert "max 0.100 m, RMSE 0.071 m" in words and f"({s[-1]:.0f} m)" in words

    # the route and the path driven on one map, at one scale both ways: every point drawn of either,
    # taken back to metres, lies on the route (the drive is 0.1 m off it, a fraction of a pixel)
    on_map, driven = vertices(root, "route"), vertices(root, "driven")
    assert len(on_map) > 20 and len(driven) > 20  # matplotlib leaves out the points of straight runs
    scale = np.ptp(on_map, axis=0) / (np.ptp(route.x), np.ptp(route.y))
    assert scale[0] == pytest.approx(scale[1], rel=0.02)
    origin_px = on_map[:, 0].min(), on_map[:, 1].max()  # the route's west and south ends
    along = cKDTree(np.column_stack([route.x, route.y]))
    for drawn in (on_map, driven):
        x_m = route.x.min() + (drawn[:, 0] - origin_px[0]) / scale[0]
        y_m = route.y.min() + (origin_px[1] - drawn[:, 1]) / scale[1]
        assert along.query(np.column_stack([x_m, y_m]))[0].max() < 1.0
    assert np.allclose(np.ptp(driven, axis=0), np.ptp(on_map, axis=0), rtol=0.01)  # the whole lap driven

    # the error: below the map, one hump per half period, each up to the same 0.1 m
    error = vertices(root, "xte")
    assert error[:, 1].min() > on_map[:, 1].max()  # SVG's y grows downwards
    top = error[:, 1].min()
    near_top = error[:, 1] < top + 0.02 * np.ptp(error[:, 1])
    humps = int(np.sum(np.diff(near_top.astype(int)) == 1)) + int(near_top[0])
    assert humps == 2 * PERIODS


def test_a_run_that_drove_nothing_still_shows_its_route(route, tmp_path):
    out = write_lap_svg(tmp_path / "lap.svg", route, np.array([]), np.array([]), np.array([]), np.array([]), "none")
    root = ET.parse(out).getroot()
    assert len(vertices(root, "route")) > 20
    assert root.find(f".//{SVG}g[@id='driven']") is None and root.find(f".//{SVG}g[@id='xte']") is None
    assert "nothing driven" in texts(root)
