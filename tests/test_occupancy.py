"""Local occupancy grid (perception/occupancy.py, free_space.py, grid_geometry.py; ARES §3.5.2):
hand-made clouds, and random clouds against a brute-force tracing of every ray."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from perception.free_space import FreeSpaceTracer
from perception.grid_geometry import Grid
from perception.occupancy import FREE, OCCUPIED, UNKNOWN, OccupancyMapper, OccupancyParams, local_ground

ROOF, LEFT, RIGHT = (3.0, 0.0, 2.94), (3.3, 0.95, 0.9), (3.3, -0.95, 0.9)
ORIGINS = np.array([ROOF, LEFT, RIGHT])
X0, Y0, D, N = -8.6, -10.0, 0.2, 100  # the default grid: 20 m around x = 1.4, y = 0


def cell(x, y):
    """(row, col) of a point: row along y, col along x."""
    return math.floor((y - Y0) / D), math.floor((x - X0) / D)


def centre(row, col):
    return X0 + (col + 0.5) * D, Y0 + (row + 0.5) * D


def grid_of(points, ground=None, sensors=None, origins=ORIGINS, **params):
    points = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    ground = np.zeros(len(points), bool) if ground is None else np.asarray(ground, bool)
    sensors = np.zeros(len(points), int) if sensors is None else np.asarray(sensors)
    return OccupancyMapper(OccupancyParams(**params), origins).cells(points, ground, sensors)


def counts(cells):
    return {
        name: int((cells == value).sum())
        for name, value in (("free", FREE), ("occupied", OCCUPIED), ("unknown", UNKNOWN))
    }


def test_one_obstacle_point_clears_its_ray_and_hides_what_lies_behind():
    cells = grid_of([(8.1, 0.1, 1.0)])  # roof sensor at (3, 0): the ray stays in row 50
    row, col = cell(8.1, 0.1)
    assert (row, col) == (50, 83) and cells[row, col] == OCCUPIED
    first = cell(3.05, 0.0)[1]  # the sensor's own cell (x = 3.0 is a grid line)
    assert (cells[50, first:col] == FREE).all()
    assert (cells[50, col + 1 :] == UNKNOWN).all()
    assert counts(cells) == {"free": col - first, "occupied": 1, "unknown": N * N - (col - first) - 1}


def test_two_sensors_see_one_spot_from_both_sides():
    spot = np.array([7.1, 0.1, 0.8])
    # behind the spot as the right sensor sees it, a cell the left sensor sees through to the road
    shadow = spot[:2] + 0.5 * (spot[:2] - ORIGINS[2, :2])
    seen = np.array(centre(*cell(*shadow)))
    road = ORIGINS[1, :2] + 1.6 * (seen - ORIGINS[1, :2])
    cells = grid_of([spot, spot, (*road, 0.0)], ground=[False, False, True], sensors=[1, 2, 1])
    assert cells[cell(*spot[:2])] == OCCUPIED
    for origin in ORIGINS[1:, :2]:  # halfway along each sensor's ray: free
        assert cells[cell(*(origin + 0.5 * (spot[:2] - origin)))] == FREE
    assert cells[cell(*seen)] == FREE  # hidden from one sensor, seen by the other
    behind_left = spot[:2] + 0.3 * (spot[:2] - ORIGINS[1, :2])
    assert cells[cell(*behind_left)] == UNKNOWN  # hidden from the left one, never seen by the right
    assert counts(cells)["occupied"] == 1


def test_a_ground_ring_clears_the_disc_inside_it_and_marks_nothing_occupied():
    azimuth = np.linspace(0, 2 * np.pi, 3000, endpoint=False)
    ring = np.column_stack([3.0 + 6.0 * np.cos(azimuth), 6.0 * np.sin(azimuth), np.zeros_like(azimuth)])
    cells = grid_of(ring, ground=np.ones(len(ring), bool))
    x, y = np.meshgrid(X0 + (np.arange(N) + 0.5) * D, Y0 + (np.arange(N) + 0.5) * D)
    distance = np.hypot(x - 3.0, y)  # of each cell's centre, [row, col]
    assert counts(cells)["occupied"] == 0
    assert (cells[distance < 5.8] == FREE).all()
    assert (cells[distance > 6.2] == UNKNOWN).all()


def test_points_above_the_band_are_passed_under_and_heights_count_from_the_local_ground():
    road = [(x, y, 0.0) for x in np.arange(5.0, 8.0, 0.1) for y in (-0.5, 0.5)]
    ramp = [(x, y, 1.0) for x in np.arange(-7.0, -5.0, 0.1) for y in (-3.5, -2.5)]  # a raised patch
    branch, child, low = (6.5, 0.0, 3.5), (7.5, 0.0, 1.0), (5.5, 0.0, 0.15)
    on_ramp = [(-6.0, -3.0, 1.25), (-6.4, -3.0, 1.1), (-5.6, -3.0, 4.3), (-6.6, -2.6, 4.1)]
    points = road + ramp + [branch, child, low] + on_ramp
    ground = [True] * (len(road) + len(ramp)) + [False] * 7
    cells = grid_of(points, ground=ground)
    assert cells[cell(6.5, 0.0)] != OCCUPIED and cells[cell(5.5, 0.0)] != OCCUPIED
    assert cells[cell(7.5, 0.0)] == OCCUPIED
    # 0.25 m above the raised ground: an obstacle; 0.1 m: not; 3.3 and 3.1 m: above and inside the band
    assert [cells[cell(x, y)] == OCCUPIED for x, y, _ in on_ramp] == [True, False, False, True]
    # under the branch's ray the road's rays clear the cells; alone, the branch's ray clears none
    assert cells[cell(4.75, 0.0)] == FREE
    assert counts(grid_of([branch])) == {"free": 0, "occupied": 0, "unknown": N * N}


def test_rays_outside_the_fan_leave_their_cells_unknown():
    # road returns only ahead, within ±20° of the roof sensor's x axis
    azimuth = np.radians(np.linspace(-20, 20, 400))
    r = np.repeat([5.0, 7.0, 9.0], len(azimuth))
    a = np.tile(azimuth, 3)
    road = np.column_stack([3.0 + r * np.cos(a), r * np.sin(a), np.zeros_like(r)])
    cells = grid_of(road, ground=np.ones(len(road), bool))
    assert cells[cell(6.0, 0.0)] == FREE
    assert cells[cell(6.0, 3.0)] == UNKNOWN and cells[cell(-2.0, 0.0)] == UNKNOWN  # aside, behind
    assert cells[cell(3.0 + 8.0 * math.cos(0.40), 8.0 * math.sin(0.40))] == UNKNOWN  # 23°: outside
    assert cells[cell(3.0 + 8.0 * math.cos(0.40), -8.0 * math.sin(0.40))] == UNKNOWN
    assert cells[cell(3.0 + 8.0 * math.cos(0.33), 8.0 * math.sin(0.33))] == FREE  # 19°: inside


def test_cells_at_the_edges_row_along_y_col_along_x():
    corners = [
        (X0 + 0.1, Y0 + 0.1),
        (X0 + 19.9, Y0 + 0.1),
        (X0 + 0.1, Y0 + 19.9),
        (X0 + 19.9, Y0 + 19.9),
        (X0 + 0.1, 0.1),
    ]
    outside = [(X0 - 0.01, 0.0), (X0 + 20.01, 0.0), (1.0, Y0 - 0.01), (1.0, Y0 + 20.01)]
    points = [(x, y, 1.0) for x, y in corners + outside]
    cells = grid_of(points)
    assert set(zip(*np.nonzero(cells == OCCUPIED))) == {(0, 0), (0, 99), (99, 0), (99, 99), (50, 0)}
    none = np.zeros(len(points), int)
    message = OccupancyMapper(OccupancyParams(), ORIGINS).message(2.5, np.array(points, np.float32), none == 1, none)
    assert (message.origin_x, message.origin_y, message.resolution_m, message.cells.shape) == (X0, Y0, 0.2, (N, N))
    assert (message.cells == cells).all()


def test_grid_size_and_centre_follow_the_settings():
    grid = Grid.centred(1.4, 0.0, 12.0, 8.0, 0.5)
    assert (grid.origin_x, grid.origin_y, grid.cols, grid.rows) == (-4.6, -4.0, 24, 16)
    cells = grid_of([(7.0, 3.9, 1.0)], width_m=12.0, height_m=8.0, cell_m=0.5)
    assert cells.shape == (16, 24) and cells[15, 23] == OCCUPIED
    with pytest.raises(ValueError, match="positive"):
        Grid.centred(0.0, 0.0, 10.0, 10.0, 0.0)
    assert counts(grid_of(np.zeros((0, 3)))) == {"free": 0, "occupied": 0, "unknown": N * N}


def test_local_ground_is_the_mean_of_the_ground_points_around():
    grid = Grid.centred(0.0, 0.0, 2.0, 2.0, 0.2)  # 10 × 10
    flat = np.array([0, 0, 1, 55])
    ground = local_ground(grid, flat, np.array([1.0, 2.0, 3.0, 7.0]), 1).reshape(10, 10)
    assert ground[0, 0] == pytest.approx(2.0) and ground[1, 1] == pytest.approx(2.0)  # (1 + 2 + 3) / 3
    assert ground[0, 2] == pytest.approx(3.0) and ground[5, 5] == pytest.approx(7.0)
    assert ground[9, 9] == 0.0  # no ground around: the road plane z = 0


def test_the_tracer_bins_tile_the_circle():
    tracer = FreeSpaceTracer(Grid.centred(0.0, 0.0, 4.0, 4.0, 0.2), [(0.0, 0.0)], azimuth_step_rad=0.01)
    assert tracer.bins % 4 == 0 and tracer.bins * tracer.step == pytest.approx(2 * math.pi)
    # every cell of the grid lies on some bin's centre line, and the origin's four cells at range 0
    assert set(tracer.pair_cell.tolist()) == set(range(400))
    assert tracer.pair_entry.min() == 0.0


# ---- against brute force -------------------------------------------------------------------------


def brute_force(points, ground, sensors, origins, low=0.2, high=3.2):
    """Every ray walked in 5 mm steps, cell after cell; the ground is the plane z = 0."""

    def inside(r, c):
        return 0 <= r < N and 0 <= c < N

    occupied = {cell(x, y) for (x, y, z), g in zip(points, ground) if not g and low <= z <= high}
    occupied = {rc for rc in occupied if inside(*rc)}
    free = set()
    for (x, y, z), g, s in zip(points, ground, sensors):
        if not g and z > high:
            continue  # passed over the cells, saw none of them
        ox, oy = origins[s][:2]
        length = math.hypot(x - ox, y - oy)
        # every sample before the return; from half a step on, so that a sensor on a grid
        # line starts in the cell its ray goes into
        t = np.arange(0.0025, length, 0.005)
        rows = np.floor((oy + t * (y - oy) / length - Y0) / D).astype(int)
        cols = np.floor((ox + t * (x - ox) / length - X0) / D).astype(int)
        new = np.ones(len(t), bool)
        new[1:] = (rows[1:] != rows[:-1]) | (cols[1:] != cols[:-1])
        for r, c in zip(rows[new], cols[new]):
            if not inside(r, c) or (r, c) in occupied:
                break
            free.add((r, c))
    cells = np.full((N, N), UNKNOWN, np.uint8)
    for r, c in free:
        cells[r, c] = FREE
    for r, c in occupied:
        cells[r, c] = OCCUPIED
    return cells


def random_sweeps(rng, step_rad=math.radians(0.2)):
    """What the three sensors return over random sectors, firing every `step_rad` like a real
    LiDAR: two rings on the road at random ranges, cut by a few obstacles (arcs at random ranges,
    of random heights: under, inside and above the band) that shadow what lies behind them."""
    points, ground, sensors = [], [], []
    for s, (ox, oy, _) in enumerate(ORIGINS):
        start, width = rng.uniform(-np.pi, np.pi), rng.uniform(0.1, 2 * np.pi)
        azimuth = start + np.arange(0.0, width, step_rad)
        for road in rng.uniform(2.0, 16.0, 2):
            r, z = np.full(len(azimuth), road), np.zeros(len(azimuth))
            for _ in range(rng.integers(0, 6)):
                a0, span, at = rng.uniform(start, start + width), rng.uniform(0.01, 0.5), rng.uniform(1.0, 15.0)
                hit = (azimuth >= a0) & (azimuth <= a0 + span) & (r > at)
                r[hit], z[hit] = at, rng.choice([0.1, 0.5, 1.2, 2.9, 4.0])
            points += list(zip(ox + r * np.cos(azimuth), oy + r * np.sin(azimuth), z))
            ground += list(z == 0.0)
            sensors += [s] * len(azimuth)
    return np.array(points, np.float32).reshape(-1, 3), np.array(ground, bool), np.array(sensors, int)


def random_rays(rng, rays):
    """The worst case: isolated rays in random directions, no neighbour to cover a cell that a
    ray clips and its bin's centre line misses (or the other way round)."""
    points, ground, sensors = [], [], []
    for s, (ox, oy, _) in enumerate(ORIGINS):
        azimuth, r = rng.uniform(-np.pi, np.pi, rays), rng.uniform(1.0, 16.0, rays)
        z = rng.choice([0.0, 0.0, 0.0, 0.1, 1.2, 4.0], rays)
        points += list(zip(ox + r * np.cos(azimuth), oy + r * np.sin(azimuth), z))
        ground += list(z == 0.0)
        sensors += [s] * rays
    return np.array(points, np.float32), np.array(ground, bool), np.array(sensors, int)


def fast_and_slow(points, ground, sensors):
    fast = OccupancyMapper(OccupancyParams(), ORIGINS).cells(points, ground, sensors)
    return fast, brute_force(points.astype(np.float64), ground, sensors, ORIGINS)


@settings(max_examples=8, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_the_fast_tracer_agrees_with_brute_force_on_sweeps(seed):
    fast, slow = fast_and_slow(*random_sweeps(np.random.default_rng(seed)))
    assert ((fast == OCCUPIED) == (slow == OCCUPIED)).all()
    assert (fast == slow).mean() >= 0.97  # 0.993 at worst over 40 seeds, 0.998 median


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), rays=st.integers(1, 300))
def test_isolated_rays_are_the_worst_case(seed, rays):
    fast, slow = fast_and_slow(*random_rays(np.random.default_rng(seed), rays))
    assert ((fast == OCCUPIED) == (slow == OCCUPIED)).all()
    assert (fast == slow).mean() >= 0.94  # 0.961 at worst over 300 seeds, 0.979 median


def test_the_top_of_a_low_box_the_heightmap_called_ground_is_occupied():
    # only the box's top was seen: its cells span millimetres, so Algorithm 2 calls them ground;
    # the road around is the floor it stands 0.3 m above
    road = [
        (x, y, 0.0)
        for x in np.arange(5.0, 9.0, 0.1)
        for y in np.arange(-1.0, 1.0, 0.1)
        if not (6.6 <= x <= 7.0 and 0.0 <= y <= 0.4)
    ]
    top = [(x, y, 0.3) for x in np.arange(6.62, 7.0, 0.05) for y in np.arange(0.02, 0.4, 0.05)]
    points = road + top
    cells = grid_of(points, ground=np.ones(len(points), bool))
    assert cells[cell(6.8, 0.2)] == OCCUPIED
    assert counts(cells)["occupied"] == len({cell(x, y) for x, y, _ in top})  # the road stays clear
    low = [(x, y, 0.1) for x, y, _ in top]  # a 0.1 m bump is not
    assert counts(grid_of(road + low, ground=np.ones(len(road + low), bool)))["occupied"] == 0
