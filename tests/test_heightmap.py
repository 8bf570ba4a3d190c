"""Heightmap ground removal (perception/heightmap.py, ARES Algorithm 2): hand-made clouds, and
random clouds against a brute-force reading of the algorithm."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from perception.heightmap import ground_mask


def brute_force(points, w, h, d, th):
    """Algorithm 2 line by line: a dictionary of cells, min and max per cell, then each point."""
    W, H = round(w / d), round(h / d)
    low, high = {}, {}

    def cell(x, y):
        return W // 2 + math.floor(x / d), H // 2 + math.floor(y / d)

    for x, y, z in points:
        i, j = cell(x, y)
        if 0 <= i < W and 0 <= j < H:
            low[i, j] = min(low.get((i, j), math.inf), z)
            high[i, j] = max(high.get((i, j), -math.inf), z)
    out = []
    for x, y, _ in points:
        i, j = cell(x, y)
        out.append(0 <= i < W and 0 <= j < H and high[i, j] - low[i, j] < th)
    return np.array(out, dtype=bool)


def test_a_flat_road_is_ground_and_a_kerb_or_a_pole_is_not():
    road = [(x, y, 0.01 * (x + y)) for x in np.arange(-5, 5, 0.05) for y in (-1.0, 0.0, 1.0)]
    pole = [(3.05, 0.05, z) for z in np.arange(0.0, 2.0, 0.1)]  # in the cell of road points
    kerb = [(-2.03, 2.03, 0.0), (-2.07, 2.07, 0.14), (-2.09, 2.01, 0.16)]
    cloud = np.array(road + pole + kerb)
    ground = ground_mask(cloud, cell_m=0.2, threshold_m=0.15)
    road_xy = np.array(road)[:, :2]
    beside_pole = (road_xy[:, 0] >= 3.0) & (road_xy[:, 0] < 3.2) & (road_xy[:, 1] >= 0.0) & (road_xy[:, 1] < 0.2)
    assert beside_pole.sum() == 4 and (ground[: len(road)] == ~beside_pole).all()  # the pole's cell is not ground
    assert not ground[len(road) : len(road) + len(pole)].any()
    assert not ground[-3:].any()  # 0.16 m of step in one cell


def test_a_point_alone_in_its_cell_is_ground_and_outside_the_grid_never():
    cloud = np.array([[1.0, 1.0, 5.0], [10.5, 0.0, 0.0], [-10.01, 0.0, 0.0], [0.0, 9.99, 0.0]])
    assert ground_mask(cloud).tolist() == [True, False, False, True]


def test_edges_of_the_grid_follow_the_floor_of_x_over_delta():
    # 20 m at 0.2 m: cells -10 .. 10 m; x = -10.0 is cell 0, x = 9.999 cell 99, x = 10.0 outside
    cloud = np.array([[-10.0, 0.0, 0.0], [9.999, 0.0, 0.0], [10.0, 0.0, 0.0]])
    assert ground_mask(cloud).tolist() == [True, True, False]


def test_empty_and_bad_grids():
    assert ground_mask(np.zeros((0, 3))).shape == (0,)
    with pytest.raises(ValueError, match="positive"):
        ground_mask(np.zeros((1, 3)), cell_m=0.0)


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(1, 400),
    th=st.floats(0.01, 1.0),
    d=st.sampled_from([0.1, 0.2, 0.5, 1.0]),
    w=st.sampled_from([4.0, 10.0, 20.0]),
)
def test_matches_the_algorithm_read_line_by_line(seed, n, th, d, w):
    rng = np.random.default_rng(seed)
    # clustered points, so that cells hold several, some near the grid's edge
    centres = rng.uniform(-w * 0.6, w * 0.6, (max(n // 20, 1), 2))
    xy = centres[rng.integers(0, len(centres), n)] + rng.normal(0, d, (n, 2))
    z = rng.choice([0.0, 0.05, 0.3, 1.5], n) + rng.normal(0, 0.02, n)
    cloud = np.column_stack([xy, z])
    assert ground_mask(cloud, w, w * 0.5, d, th).tolist() == brute_force(cloud, w, w * 0.5, d, th).tolist()
