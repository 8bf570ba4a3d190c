"""Hypothesis strategies for routes with the shapes that make path matching hard: hairpins whose
legs lie within the search radius, figures of eight whose passes cross at a shallow angle,
loops shorter than the hint's window, random walks that cross themselves, and walks on a unit
lattice, whose whole-number coordinates put query points at exactly equal distances from two
poses (and a few poses on top of each other)."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import strategies as st

from ares.core.route import Route, resample


def _route(name: str, xy: np.ndarray, closed: bool) -> Route:
    return Route(name, xy[:, 0], xy[:, 1], np.zeros(len(xy)), closed, np.full(len(xy), 4.0))


@st.composite
def walks(draw) -> Route:
    count = draw(st.integers(2, 25))
    steps = draw(st.lists(st.floats(0.5, 25.0), min_size=count - 1, max_size=count - 1))
    turns = draw(st.lists(st.floats(-2.6, 2.6), min_size=count - 1, max_size=count - 1))
    heading = np.cumsum(turns)
    xy = np.vstack([[0.0, 0.0], np.cumsum(np.column_stack([steps * np.cos(heading), steps * np.sin(heading)]), axis=0)])
    return _route("walk", resample(xy, draw(st.floats(0.1, 1.5))), draw(st.booleans()))


@st.composite
def circles(draw) -> Route:
    radius = draw(st.floats(1.0, 40.0))
    count = max(int(2 * math.pi * radius / draw(st.floats(0.1, 1.5))), 6)
    a = np.linspace(0.0, 2 * math.pi, count, endpoint=False)
    return _route("circle", radius * np.column_stack([np.cos(a), np.sin(a)]), draw(st.booleans()))


@st.composite
def figures_of_eight(draw) -> Route:
    """Lobes `half_width` long either side of the crossing; the passes cross at an angle of
    2 atan(height / half_width), below 1 rad when height < 0.55 half_width."""
    half_width = draw(st.floats(5.0, 60.0))
    height = half_width * draw(st.floats(0.1, 1.5))
    count = max(int(8 * half_width / draw(st.floats(0.1, 1.0))), 20)
    a = np.linspace(0.0, 2 * math.pi, count, endpoint=False)
    xy = np.column_stack([half_width * np.sin(a), height * np.sin(a) * np.cos(a)])
    return _route("eight", xy, draw(st.booleans()))


@st.composite
def hairpins(draw) -> Route:
    """Out along y = 0, a half circle to the left, back along y = gap."""
    gap, leg, spacing = draw(st.floats(0.5, 8.0)), draw(st.floats(2.0, 40.0)), draw(st.floats(0.1, 1.0))
    r = gap / 2
    a = np.linspace(-math.pi / 2, math.pi / 2, max(int(math.pi * r / spacing), 2))
    corners = np.vstack([[[0.0, 0.0]], np.column_stack([leg + r * np.cos(a), r + r * np.sin(a)]), [[0.0, gap]]])
    return _route("hairpin", resample(corners, spacing), draw(st.booleans()))


@st.composite
def lattice_walks(draw) -> Route:
    moves = draw(st.lists(st.sampled_from([(1, 0), (0, 1), (-1, 0), (0, -1), (0, 0)]), min_size=1, max_size=80))
    xy = np.vstack([[0.0, 0.0], np.cumsum(np.array(moves, dtype=float), axis=0)])
    with np.errstate(divide="ignore", invalid="ignore"):  # no grade between poses on top of each other
        return _route("lattice", xy, draw(st.booleans()))


# a lattice walk that never moves has no length: not a route
routes = st.one_of(walks(), circles(), figures_of_eight(), hairpins(), lattice_walks()).filter(lambda r: r.length > 0)


def pose_along(route: Route, s: float, offset: float) -> tuple[float, float, float]:
    """(x, y, yaw) `offset` metres left of the route at s; an open route is extended straight
    on before its start and past its end."""
    end = route.length
    inside = s % end if route.closed else min(max(s, 0.0), end)
    x, y, _, yaw = route.point_at(inside)
    if not route.closed:
        x, y = x + (s - inside) * math.cos(yaw), y + (s - inside) * math.sin(yaw)
    return x - math.sin(yaw) * offset, y + math.cos(yaw) * offset, yaw
