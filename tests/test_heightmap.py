"""Heightmap ground removal (perception/heightmap.py, ARES Algorithm 2): hand-made clouds, and
random clouds against a brute-force reading of the algorithm; then the floor method the pipeline
runs (floor_ground_mask): kerbs, slopes, low boxes, stray returns, and a small simulated street
beside Patchwork++."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from perception.heightmap import floor_ground_mask, ground_mask, window_min
from perception.lidar_perception import GroundParams
from perception.occupancy import OccupancyParams
from tests.helpers.street_scan import simulated_street


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


def patch(x0, x1, y0, y1, z, step=0.05):
    """Points every `step` over a rectangle, at height z (a number or a function of x, y)."""
    x, y = np.meshgrid(np.arange(x0, x1, step), np.arange(y0, y1, step), indexing="ij")
    x, y = x.ravel(), y.ravel()
    height = z(x, y) if callable(z) else np.full(len(x), z)
    return np.column_stack([x, y, height])


def test_a_road_cell_holding_a_kerb_or_a_pole_keeps_its_road_points():
    road = patch(2.0, 6.0, -2.0, 1.1, 0.0)
    pavement = patch(2.0, 6.0, 1.1, 3.0, 0.16)  # behind a 0.16 m kerb; cells y 1.0-1.2 hold both
    pole = np.array([(4.05, -0.95, z) for z in np.arange(0.2, 2.5, 0.1)])  # in a road cell
    cloud = np.vstack([road, pavement, pole])
    floor, paper = floor_ground_mask(cloud), ground_mask(cloud)
    shares_the_kerb = (road[:, 1] >= 1.0) & (road[:, 1] < 1.2)
    beside_pole = (road[:, 0] >= 4.0) & (road[:, 0] < 4.2) & (road[:, 1] >= -1.0) & (road[:, 1] < -0.8)
    assert shares_the_kerb.sum() == 160 and beside_pole.sum() == 16
    assert floor[: len(road)].all()  # all the road, its kerb's and its pole's cells too
    assert not paper[: len(road)][shares_the_kerb | beside_pole].any()  # Algorithm 2 lost them
    on_pavement = floor[len(road) : len(road) + len(pavement)]
    assert on_pavement[pavement[:, 1] >= 1.2].all()  # a kerb's height above the road is ground
    assert not on_pavement[pavement[:, 1] < 1.2].any()  # the kerb's top in the road's cells is not
    assert not floor[-len(pole) :].any()


@pytest.mark.parametrize(
    ("size", "seen"),
    [((0.4, 0.4, 0.3), "top"), ((0.4, 0.4, 0.3), "sides"), ((0.8, 0.6, 0.6), "top"), ((4.2, 1.8, 1.5), "top")],
)
def test_a_box_on_the_road_stays_obstacle_down_to_0_3_m(size, seen):
    (length, width, height), x, y = size, 5.0, 0.6
    road = patch(0.0, 12.0, -3.0, 3.0, 0.0)
    road = road[~((np.abs(road[:, 0] - x) < length / 2) & (np.abs(road[:, 1] - y) < width / 2))]
    box = patch(x - length / 2, x + length / 2, y - width / 2, y + width / 2, height)
    if seen == "sides":  # the face towards the sensor, from the road up
        box = np.vstack(
            [
                box,
                [
                    (x - length / 2, b, z)
                    for b in np.arange(y - width / 2, y + width / 2, 0.05)
                    for z in np.arange(0.0, height, 0.05)
                ],
            ]
        )
    ground = floor_ground_mask(np.vstack([road, box]))
    assert ground[: len(road)].all()
    on_box = ground[len(road) :]
    assert not on_box[np.vstack([box])[:, 2] >= 0.15].any()  # the foot of a seen face is ground
    assert on_box[box[:, 2] < 0.15].all()


def test_a_graded_cambered_road_is_ground_and_stray_returns_below_it_sink_nothing():
    road = patch(-15.0, 25.0, -4.0, 4.0, lambda x, y: 0.1 * x - 0.03 * np.abs(y), step=0.1)
    strays = np.array([(6.03, 1.03), (6.05, 1.07), (6.13, 1.01)])  # in one cell, half a metre under the road
    strays = np.column_stack([strays, 0.1 * strays[:, 0] - 0.03 * strays[:, 1] - 0.5])
    assert floor_ground_mask(road).all()
    in_their_cell = (road[:, 0] >= 6.0) & (road[:, 0] < 6.2) & (road[:, 1] >= 1.0) & (road[:, 1] < 1.2)
    ground = floor_ground_mask(np.vstack([road, strays]))[: len(road)]
    assert in_their_cell.sum() == 4 and (ground == ~in_their_cell).all()  # the cell's lowest is theirs
    sunk = floor_ground_mask(np.vstack([road, strays]), floor_rank=1)[: len(road)]
    assert (~sunk).sum() > 50  # taken as the floor, they would sink the road around them


def test_a_canopy_over_road_the_sensors_cannot_see_is_not_ground_nor_is_beyond_the_heightmap():
    canopy = patch(-3.0, 2.0, 1.8, 2.6, 2.4)  # nothing seen under it
    far = patch(60.0, 61.0, 0.0, 1.0, 0.0)  # past the 100 m heightmap's edge
    ground = floor_ground_mask(np.vstack([canopy, far]))
    assert not ground.any()
    assert floor_ground_mask(canopy, plane_m=5.0).all()  # without the plane, nothing tells it from a floor


def test_ground_params_run_the_configured_method_in_the_vehicle_frame():
    grid = OccupancyParams()
    cloud = np.vstack([patch(0.0, 6.0, -2.0, 2.0, 0.0), [(3.05, 0.05, z) for z in np.arange(0.2, 2.0, 0.1)]])
    shifted = cloud - [grid.centre_x_m, grid.centre_y_m, 0.0]
    paper = GroundParams(method="cell_span").mask(cloud.astype(np.float32), grid)
    assert (paper == ground_mask(shifted, grid.width_m, grid.height_m, grid.cell_m, 0.15)).all()
    floor = GroundParams(method="floor").mask(cloud.astype(np.float32), grid)
    assert (floor == floor_ground_mask(shifted)).all()
    assert paper.sum() < floor.sum()
    assert GroundParams().method == "floor"  # the stack's default (it drove whole laps: docs/performance.md)


def test_a_small_simulated_street_agrees_with_patchwork_and_keeps_its_obstacles():
    pypatchworkpp = pytest.importorskip("pypatchworkpp")
    points, obstacle = simulated_street()
    ours = floor_ground_mask(points)
    params = pypatchworkpp.Parameters()
    params.sensor_height = 1.73
    params.enable_RNR = False
    reference = pypatchworkpp.patchworkpp(params)
    reference.estimateGround((points - [0.0, 0.0, 1.73]).astype(np.float64))
    theirs = np.zeros(len(points), dtype=bool)
    theirs[reference.getGroundIndices()] = True
    assert (ours & theirs).sum() / (ours | theirs).sum() >= 0.9
    assert abs(ours.mean() - theirs.mean()) < 0.05
    raised = obstacle & (points[:, 2] >= 0.2)  # the occupancy grid's obstacles start there
    assert raised.sum() > 300 and not ours[raised].any()


@pytest.mark.parametrize("k", [0, 1, 2, 3])
def test_window_min_is_a_square_minimum_filter_with_nothing_past_the_edges(k):
    from scipy.ndimage import minimum_filter

    grid = np.random.default_rng(k).normal(size=(13, 17)).astype(np.float32)
    grid[np.random.default_rng(k + 10).random(grid.shape) < 0.3] = np.inf  # cells without returns
    expected = minimum_filter(grid, size=2 * k + 1, mode="constant", cval=np.inf)
    assert (window_min(grid, k) == expected).all()
