"""Where the cells of a local grid lie: cells[row, col], row along y, col along x, cell (0, 0)'s
corner at (origin_x, origin_y), as in ares.core.messages.OccupancyGrid. A cell's flat index is
row * cols + col, the order of the cells array's memory."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class Grid(NamedTuple):
    origin_x: float
    origin_y: float
    cell_m: float
    cols: int  # along x
    rows: int  # along y

    @classmethod
    def centred(cls, centre_x: float, centre_y: float, width_m: float, height_m: float, cell_m: float) -> Grid:
        """width_m along x, height_m along y, both rounded to whole cells."""
        if cell_m <= 0 or width_m <= 0 or height_m <= 0:
            raise ValueError("the grid's size and its cells must be positive")
        cols, rows = max(int(round(width_m / cell_m)), 1), max(int(round(height_m / cell_m)), 1)
        return cls(centre_x - cols * cell_m / 2.0, centre_y - rows * cell_m / 2.0, cell_m, cols, rows)

    @property
    def size(self) -> int:
        return self.rows * self.cols

    @property
    def x_max(self) -> float:
        return self.origin_x + self.cols * self.cell_m

    @property
    def y_max(self) -> float:
        return self.origin_y + self.rows * self.cell_m

    def cell_index(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(flat index, inside the grid?) of each point; the index is meaningless outside.
        Computed in float64 whatever the points' type, so that a point's cell is ⌊(x − x0)/δ⌋
        exactly as a reader would compute it."""
        col = np.floor((np.asarray(x, dtype=np.float64) - self.origin_x) / self.cell_m).astype(np.int64)
        row = np.floor((np.asarray(y, dtype=np.float64) - self.origin_y) / self.cell_m).astype(np.int64)
        inside = (col >= 0) & (col < self.cols) & (row >= 0) & (row < self.rows)
        return row * self.cols + col, inside
