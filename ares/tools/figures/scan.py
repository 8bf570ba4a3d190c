"""The top view `ares perception scan` draws of one frame: the occupancy grid underneath
(occupied black, free white, unknown grey), the ground and other points over it, the road's
boundaries and centre line, the vehicle's body and its sensors. Vehicle frame: x forward to the
right, y left upwards, metres, equal scales."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from perception.cloud_filters import BodyBox
from perception.grid_geometry import Grid
from perception.lidar_perception import FrameResult
from perception.occupancy import FREE, OCCUPIED
from perception.road_detection import RoadDetectionParams, poly

GREY = (0.62, 0.62, 0.62)
GROUND, OTHER = "#2a9d8f", "#e76f51"
LEFT, RIGHT, CENTRE = "#1d4ed8", "#c026d3", "#f4a261"


def write_scan_png(
    path: str | Path,
    frame: FrameResult,
    grid: Grid,
    body: BodyBox,
    sensors_xy: np.ndarray,
    road: RoadDetectionParams,
    title: str,
) -> Path:
    import matplotlib

    matplotlib.use("Agg")  # no display: a file is all we want
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle

    fig, ax = plt.subplots(figsize=(11, 8), dpi=110)
    rgb = np.empty(frame.grid.shape + (3,))
    rgb[:] = GREY
    rgb[frame.grid == FREE] = 1.0
    rgb[frame.grid == OCCUPIED] = 0.0
    ax.imshow(
        rgb,
        origin="lower",
        extent=(grid.origin_x, grid.x_max, grid.origin_y, grid.y_max),
        interpolation="nearest",
        zorder=0,
    )

    # the view: the grid and the road detector's region ahead; farther points are clipped
    x_lo, x_hi = min(grid.origin_x, -5.0) - 2.0, max(grid.x_max, road.x_max_m) + 2.0
    y_half = max(grid.y_max, -grid.origin_y, road.half_width_m) + 2.0
    pts = frame.points
    seen = (pts[:, 0] > x_lo) & (pts[:, 0] < x_hi) & (np.abs(pts[:, 1]) < y_half)
    for mask, colour, label in (
        (seen & frame.ground, GROUND, "ground"),
        (seen & ~frame.ground, OTHER, "not ground, or off the grid"),
    ):
        ax.scatter(pts[mask, 0], pts[mask, 1], s=0.15, c=colour, linewidths=0, label=label, rasterized=True, zorder=1)

    model = frame.road.model
    x = np.linspace(0.0, road.fit_x_max_m, 100)
    for coef, colour, label, style in (
        (model.left, LEFT, "left boundary", "-"),
        (model.right, RIGHT, "right boundary", "-"),
        (model.centre(), CENTRE, "centre line", "--"),
    ):
        if coef is not None:
            ax.plot(x, poly.polyval(x, coef), style, color=colour, lw=2, label=label, zorder=3)
    for points, colour in ((frame.road.left_points, LEFT), (frame.road.right_points, RIGHT)):
        if len(points):
            ax.plot(points[:, 0], points[:, 1], "o", ms=3, mfc="none", color=colour, zorder=3)

    ax.add_patch(
        Rectangle(
            (body.x_min, body.y_min),
            body.x_max - body.x_min,
            body.y_max - body.y_min,
            fill=False,
            ec="black",
            lw=1.5,
            zorder=4,
            label="vehicle",
        )
    )
    ax.plot(sensors_xy[:, 0], sensors_xy[:, 1], "k^", ms=6, zorder=4)
    ax.set_xlim(x_lo, x_hi)
    ax.set_ylim(-y_half, y_half)
    ax.set_aspect("equal")
    ax.set_xlabel("x forward (m)")
    ax.set_ylabel("y left (m)")
    ax.set_title(title, fontsize=10)
    legend = ax.legend(loc="upper right", fontsize=8, framealpha=0.9)
    for handle in legend.legend_handles:
        if hasattr(handle, "set_sizes"):
            handle.set_sizes([20])
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, bbox_inches="tight")
    plt.close(fig)
    return path
