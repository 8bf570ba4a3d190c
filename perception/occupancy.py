"""The local occupancy grid (ARES paper §3.5.2): 20 × 20 m at 0.2 m around the shuttle, each
cell occupied (100), free (0) or unknown (255), from the filtered cloud of the three LiDARs
merged in the vehicle frame and its ground mask (perception/heightmap.py).

Occupied: a cell holding a point that is not ground and lies between `min_height_m` and
`max_height_m` above the local ground. Lower points are the road's roughness, kerbs and
whatever the heightmap left of the road; higher ones are branches and signs the shuttle passes
under.

The local ground is the mean height of the ground points within `ground_radius_m` of the cell
(a square window). Not the cell's own: the heightmap leaves no ground point in a cell that holds
an obstacle (its height span is too large), so an obstacle's cell never has one. Not the
heightmap's per-cell minimum either: in an obstacle's cell that is the obstacle's lowest
return, its foot when the foot was seen, but the obstacle itself when it was not (a car's body
over its shadow, a low branch), which would put the obstacle at 0 m above "ground" and hide
it. Where the window holds no ground point the ground is the vehicle frame's z = 0, the plane
the wheels stand on; so is it for points outside the grid.

A low flat-topped obstacle (a 0.3 m box) defeats the heightmap when only its top is seen: its
cells span a few centimetres, so Algorithm 2 calls them ground. So a "ground" point is occupied
too when it stands `min_height_m` or more above the floor around it: the lowest return within
`floor_window_m` (the heightmap cells' minima, a square window). On the road that floor is a
centimetre or two below the surface (cross-fall, roughness); beside a box it is the road.

Free: the cells the rays crossed before their returns (perception/free_space.py, with its
approximation); ground returns and obstacle returns both clear the cells in front of them, a
ray stops at the first occupied cell, returns above the band clear nothing. Each sensor traces
its own rays; a cell is free if any sensor saw through it, and occupied wins over free.
Unknown: the rest — behind obstacles, outside every ray fan, never seen.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import minimum_filter

from ares.core.config import Params, param
from ares.core.messages import OccupancyGrid
from perception.free_space import FreeSpaceTracer
from perception.grid_geometry import Grid

FREE, OCCUPIED, UNKNOWN = 0, 100, 255


class OccupancyParams(Params):
    """The local occupancy grid around the vehicle (ARES §3.5.2)."""

    width_m: float = param(20.0, "extent along x (the paper's: twice the 10 m ACC range)", unit="m", gt=0)
    height_m: float = param(20.0, "extent along y", unit="m", gt=0)
    cell_m: float = param(0.2, "cell size", unit="m", gt=0)
    centre_x_m: float = param(
        1.4,
        "the grid's centre ahead of the rear-axle centre: the ARES shuttle's "
        "body centre (length/2 minus the rear overhang, (length - wheelbase)/2)",
        unit="m",
    )
    centre_y_m: float = param(0.0, "the grid's centre, left of the rear-axle centre", unit="m")
    min_height_m: float = param(0.2, "lower bound of obstacles above the local ground", unit="m", ge=0)
    max_height_m: float = param(3.2, "upper bound: higher points (branches, signs) are passed under", unit="m", gt=0)
    ground_radius_m: float = param(
        1.0, "the local ground is the mean height of the ground points this close (square window)", unit="m", ge=0
    )
    floor_window_m: float = param(
        0.4,
        "a ground point this much above the lowest return within this distance is "
        "an obstacle's top (see the module's docstring)",
        unit="m",
        ge=0,
    )
    azimuth_step_rad: float = param(
        0.005,
        "rays are traced in azimuth bins this wide around each sensor (no finer than the LiDARs' own step)",
        unit="rad",
        gt=0,
        le=0.1,
    )


def local_ground(grid: Grid, cells: np.ndarray, z: np.ndarray, radius_cells: int) -> np.ndarray:
    """Flat array of the local ground height of every cell: the mean z of the ground points
    (flat cell index `cells`, height `z`) in the (2k+1)² cells around it, 0 where there are none."""
    shape = (grid.rows, grid.cols)
    table = []
    for weights in (z, None):  # summed-area tables of heights and counts
        per_cell = np.bincount(cells, weights=weights, minlength=grid.size).astype(np.float64).reshape(shape)
        table.append(np.pad(per_cell.cumsum(0).cumsum(1), ((1, 0), (1, 0))))
    rows_lo, rows_hi = _window(grid.rows, radius_cells)
    cols_lo, cols_hi = _window(grid.cols, radius_cells)
    sums, counts = (
        (
            t[np.ix_(rows_hi, cols_hi)]
            - t[np.ix_(rows_lo, cols_hi)]
            - t[np.ix_(rows_hi, cols_lo)]
            + t[np.ix_(rows_lo, cols_lo)]
        )
        for t in table
    )
    return np.divide(sums, counts, out=np.zeros(shape), where=counts > 0).reshape(-1)


def _window(n: int, k: int) -> tuple[np.ndarray, np.ndarray]:
    i = np.arange(n)
    return np.clip(i - k, 0, n), np.clip(i + k + 1, 0, n)


class OccupancyMapper:
    """Makes the grid of each frame; the sensors' origins are fixed, so their rays' cells are
    worked out once, here."""

    def __init__(self, params: OccupancyParams, sensor_origins: np.ndarray):
        self.params = params
        self.grid = Grid.centred(params.centre_x_m, params.centre_y_m, params.width_m, params.height_m, params.cell_m)
        self.tracer = FreeSpaceTracer(self.grid, np.asarray(sensor_origins)[:, :2], params.azimuth_step_rad)
        self.radius_cells = int(round(params.ground_radius_m / params.cell_m))
        self.floor_cells = int(round(params.floor_window_m / params.cell_m))

    def cells(self, points: np.ndarray, ground: np.ndarray, sensor_index: np.ndarray) -> np.ndarray:
        """(rows, cols) uint8 grid, cells[row, col]: row along y, col along x. points: (N, ≥3)
        vehicle frame; ground: the heightmap's mask; sensor_index: each point's sensor."""
        p = self.params
        x, y, z = points[:, 0], points[:, 1], points[:, 2]
        flat, inside = self.grid.cell_index(x, y)
        on_road = np.flatnonzero(ground & inside)
        road_cells, road_z = flat[on_road], z[on_road]
        ground_z = local_ground(self.grid, road_cells, road_z, self.radius_cells)
        others = np.flatnonzero(~ground)
        held = inside[others]
        above = z[others] - np.where(held, ground_z[np.where(held, flat[others], 0)], 0.0)
        occupied = np.zeros(self.grid.size, dtype=bool)
        occupied[flat[others[held & (above >= p.min_height_m) & (above <= p.max_height_m)]]] = True
        occupied[road_cells[self._raised(road_cells, road_z, flat[inside], z[inside])]] = True
        returns = np.ones(len(points), dtype=bool)
        returns[others[above > p.max_height_m]] = False
        free = self.tracer.free(x, y, sensor_index, returns, occupied)
        out = np.full(self.grid.size, UNKNOWN, dtype=np.uint8)
        out[free] = FREE
        out[occupied] = OCCUPIED
        return out.reshape(self.grid.rows, self.grid.cols)

    def _raised(self, cells: np.ndarray, z: np.ndarray, all_cells: np.ndarray, all_z: np.ndarray) -> np.ndarray:
        """Which ground points stand min_height_m..max_height_m above the floor around them."""
        if not len(cells):
            return np.zeros(0, dtype=bool)
        lowest = np.full(self.grid.size, np.inf, dtype=np.float32)
        np.minimum.at(lowest, all_cells, all_z.astype(np.float32))
        floor = minimum_filter(
            lowest.reshape(self.grid.rows, self.grid.cols), size=2 * self.floor_cells + 1, mode="nearest"
        ).reshape(-1)[cells]
        rise = z - floor
        return (rise >= self.params.min_height_m) & (rise <= self.params.max_height_m)

    def message(
        self, t: float, points: np.ndarray, ground: np.ndarray, sensor_index: np.ndarray, frame: str = "vehicle"
    ) -> OccupancyGrid:
        return OccupancyGrid(
            t=t,
            frame=frame,
            resolution_m=self.grid.cell_m,
            origin_x=self.grid.origin_x,
            origin_y=self.grid.origin_y,
            cells=self.cells(points, ground, sensor_index),
        )
