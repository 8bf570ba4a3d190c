"""Ground removal by heightmap (ARES paper §3.5, Algorithm 2).

A grid of w × h metres at δ metres per cell is laid around the vehicle. Each cell keeps the
lowest and the highest z of the points that fall in it. A point whose cell spans less than
`threshold` in height (max − min < Th) is ground. A cell holding a kerb, a pole or a pedestrian
spans more, and all its points are kept.

The paper indexes the cell of a point without a bounds check in its second loop. Here a point
outside the grid is never ground: nothing is known about its neighbourhood, so it is kept for
whatever comes next to judge.

    i = W/2 + ⌊x/δ⌋,  j = H/2 + ⌊y/δ⌋,  W = w/δ,  H = h/δ
"""

from __future__ import annotations

import numpy as np


def cell_indices(points: np.ndarray, width_m: float, height_m: float, cell_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(flat cell index, inside the grid?) of each point (N × ≥2: x, y, ...)."""
    cols, rows = int(round(width_m / cell_m)), int(round(height_m / cell_m))
    i = np.floor(points[:, 0] / cell_m).astype(np.int64) + cols // 2
    j = np.floor(points[:, 1] / cell_m).astype(np.int64) + rows // 2
    inside = (i >= 0) & (i < cols) & (j >= 0) & (j < rows)
    return i * rows + j, inside


def ground_mask(
    points: np.ndarray, width_m: float = 20.0, height_m: float = 20.0, cell_m: float = 0.2, threshold_m: float = 0.15
) -> np.ndarray:
    """True for the points of an N × 3 (or wider) cloud that are ground (Algorithm 2)."""
    if cell_m <= 0 or width_m <= 0 or height_m <= 0:
        raise ValueError("the grid's size and its cells must be positive")
    ground = np.zeros(len(points), dtype=bool)
    if len(points) == 0:
        return ground
    cells, inside = cell_indices(points, width_m, height_m, cell_m)
    cells, z = cells[inside], points[inside, 2]
    size = int(round(width_m / cell_m)) * int(round(height_m / cell_m))
    lowest = np.full(size, np.inf, dtype=z.dtype)
    highest = np.full(size, -np.inf, dtype=z.dtype)
    np.minimum.at(lowest, cells, z)
    np.maximum.at(highest, cells, z)
    ground[inside] = highest[cells] - lowest[cells] < threshold_m
    return ground
