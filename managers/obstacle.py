"""The obstacle manager's search area and its speed limit (ARES §3.5.3), without a bus.

The area is a trapezoid laid along the trajectory the vehicle will drive, from the front bumper
on: a centre line (the path ahead, while a path follower drives) or the arc of the curvature its
wheels are at now (from the CAN steering angle). Its length grows with speed, `headway_s` × v
(10 m at 4 m/s), never shorter than `min_length_m`; its half-width is half the body plus
`near_margin_m` at the bumper, narrowing to half the body plus `far_margin_m` at its end: far
ahead the trajectory is less certain. `ares bench obstacle-zone` counts the false stops of this
trapezoid and of a rectangle as wide as its near end in the tour's narrow lane: along the path
ahead 0 and 0 in 70 frames; along the arc 3 and 3, where the lane's curvature changes and the arc
meets a wall 7-10 m ahead (docs/safety.md).

An occupied cell of the occupancy grid inside the area is an obstacle; the nearest one's
distance along the arc, as a share f of the length, sets the limit:

    f >= 0.9          ready: no limit
    0.5 <= f < 0.9    slow in proportion: v_max · (f − 0.5) / 0.4
    f < 0.5           stop

and the score is f (1: nothing in the area). The speed v that sizes the area is the larger of the
speed now and the speed the shuttle is allowed (the speed manager's limit): sized from the speed
now alone, the area would shrink as the shuttle slowed for an obstacle and let it go again.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ares.core.config import Params, param

OCCUPIED = 100


class ObstacleParams(Params):
    rate_hz: float = param(10.0, "checks per second (the grid comes at the LiDARs' 10 Hz)", unit="Hz", gt=0)
    headway_s: float = param(2.5, "the area's length per m/s of speed (ARES §3.5.3: 10 m at 4 m/s)", unit="s", gt=0)
    min_length_m: float = param(4.0, "the area's length at walking pace and standstill", unit="m", gt=0)
    near_margin_m: float = param(
        0.3,
        "beyond half the body's width on each side, at the bumper (the tour's narrow "
        "lane leaves 0.6 m each side of the ARES shuttle)",
        unit="m",
        ge=0,
    )
    far_margin_m: float = param(0.05, "... and at the area's far end", unit="m", ge=0)
    ready_share: float = param(0.9, "an obstacle beyond this share of the length: be ready, no limit", gt=0, le=1)
    stop_share: float = param(0.5, "an obstacle nearer than this share of the length: stop", ge=0, lt=1)
    min_cells: int = param(2, "occupied cells an obstacle needs (one stray cell is noise)", ge=1)
    path_max_yaw_std_rad: float = param(
        0.03,
        "the area follows the path ahead only while the pose's heading is this "
        "sure (0.3 m across at 10 m); else the arc: a shuttle standing at start "
        "has its magnetometer's 0.1 rad error, which swung the path into the "
        "narrow lane's wall",
        unit="rad",
        gt=0,
    )
    grid_timeout_s: float = param(0.5, "an older grid or CAN frame: the area is unknown, so stop", unit="s", gt=0)


@dataclass(frozen=True)
class Zone:
    """The area for one cycle: along the arc of curvature kappa from the rear axle, or along a
    centre line (`centre`: points of the vehicle frame, the path ahead), starting at the front
    bumper (`start_m` ahead of the axle), `length_m` long."""

    kappa: float
    start_m: float
    length_m: float
    near_half_width_m: float
    far_half_width_m: float
    centre: np.ndarray | None = None  # (k, 2), in driving order, reaching past the area's end

    def half_width(self, s: np.ndarray) -> np.ndarray:
        share = np.clip(s / self.length_m, 0.0, 1.0)
        return self.near_half_width_m + (self.far_half_width_m - self.near_half_width_m) * share

    def along(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For points of the vehicle frame (x ahead, y left, from the rear axle): the distance
        along the arc (or centre line) ahead of the bumper and the offset across it."""
        if self.centre is not None:
            s, d = _along_polyline(self.centre, np.asarray(x, float), np.asarray(y, float))
            bumper, _ = _along_polyline(self.centre, np.array([self.start_m]), np.array([0.0]))
            return s - bumper[0], d
        if abs(self.kappa) < 1e-6:
            return x - self.start_m, y
        radius = 1.0 / self.kappa  # the turn's centre is at (0, radius)
        dy = y - radius
        angle = np.arctan2(x, -dy) if radius > 0 else np.arctan2(x, dy)
        arc = angle * abs(radius)
        across = abs(radius) - np.hypot(x, dy)  # + towards the centre
        return arc - self.start_m, across if radius > 0 else -across

    def contains(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        s, d = self.along(x, y)
        return (s >= 0.0) & (s <= self.length_m) & (np.abs(d) <= self.half_width(s)), s

    def outline(self, steps: int = 12) -> list[tuple[float, float]]:
        """The trapezoid's corners along the arc or centre line, in the vehicle frame (for the pages)."""
        s = np.linspace(0.0, self.length_m, steps)
        if self.centre is not None:
            return _polyline_outline(self.centre, self.start_m, s, self.half_width(s))
        left, right = [], []
        for si, wi in zip(s, self.half_width(s)):
            a = si + self.start_m
            if abs(self.kappa) < 1e-6:
                cx, cy, hx, hy = a, 0.0, 0.0, 1.0
            else:
                heading = a * self.kappa
                cx, cy = math.sin(heading) / self.kappa, (1.0 - math.cos(heading)) / self.kappa
                hx, hy = -math.sin(heading), math.cos(heading)
            left.append((cx + wi * hx, cy + wi * hy))
            right.append((cx - wi * hx, cy - wi * hy))
        return [*left, *reversed(right)]


def _along_polyline(centre: np.ndarray, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each point's distance along the polyline (from its first point) to its foot on the nearest
    segment, and its offset across (left +)."""
    a, seg = centre[:-1], np.diff(centre, axis=0)
    seg_len2 = np.maximum((seg**2).sum(axis=1), 1e-12)
    rel_x, rel_y = x[:, None] - a[None, :, 0], y[:, None] - a[None, :, 1]
    t = np.clip((rel_x * seg[None, :, 0] + rel_y * seg[None, :, 1]) / seg_len2[None, :], 0.0, 1.0)
    dist2 = (rel_x - t * seg[None, :, 0]) ** 2 + (rel_y - t * seg[None, :, 1]) ** 2
    j = np.argmin(dist2, axis=1)
    rows = np.arange(len(x))
    lengths = np.sqrt(seg_len2)
    starts = np.concatenate([[0.0], np.cumsum(lengths)[:-1]])
    s = starts[j] + t[rows, j] * lengths[j]
    cross = seg[j, 0] * rel_y[rows, j] - seg[j, 1] * rel_x[rows, j]
    return s, np.sign(cross) * np.sqrt(dist2[rows, j])


def _polyline_outline(centre: np.ndarray, start_m: float, s: np.ndarray, half: np.ndarray) -> list[tuple[float, float]]:
    seg = np.diff(centre, axis=0)
    lengths = np.hypot(seg[:, 0], seg[:, 1])
    cum = np.concatenate([[0.0], np.cumsum(lengths)])
    bumper, _ = _along_polyline(centre, np.array([start_m]), np.array([0.0]))
    at = np.clip(s + bumper[0], 0.0, cum[-1])
    cx, cy = np.interp(at, cum, centre[:, 0]), np.interp(at, cum, centre[:, 1])
    j = np.clip(np.searchsorted(cum, at, side="right") - 1, 0, len(seg) - 1)
    hx, hy = -seg[j, 1] / np.maximum(lengths[j], 1e-12), seg[j, 0] / np.maximum(lengths[j], 1e-12)
    left = [(float(a + w * b), float(c + w * d)) for a, c, b, d, w in zip(cx, cy, hx, hy, half)]
    right = [(float(a - w * b), float(c - w * d)) for a, c, b, d, w in zip(cx, cy, hx, hy, half)]
    return [*left, *reversed(right)]


@dataclass(frozen=True)
class ObstacleVerdict:
    share: float  # f: the nearest obstacle's distance / the length (1: none)
    nearest_m: float | None  # along the arc from the bumper
    limit_mps: float
    band: str  # clear, ready, slow, stop
    cells: int  # occupied cells in the area


def zone_for(
    p: ObstacleParams,
    speed_mps: float,
    kappa: float,
    body_width_m: float,
    bumper_m: float,
    far_margin_m: float | None = None,
    centre: np.ndarray | None = None,
) -> Zone:
    half = body_width_m / 2.0
    far = p.far_margin_m if far_margin_m is None else far_margin_m
    return Zone(
        kappa,
        bumper_m,
        max(p.min_length_m, p.headway_s * max(speed_mps, 0.0)),
        half + p.near_margin_m,
        half + far,
        centre,
    )


def judge(
    p: ObstacleParams, zone: Zone, occupied_x: np.ndarray, occupied_y: np.ndarray, v_max: float
) -> ObstacleVerdict:
    inside, s = zone.contains(occupied_x, occupied_y)
    count = int(inside.sum())
    if count < p.min_cells:
        return ObstacleVerdict(1.0, None, v_max, "clear", count)
    nearest = float(np.sort(s[inside])[p.min_cells - 1])  # the nearest distance that min_cells cells reach
    share = min(max(nearest / zone.length_m, 0.0), 1.0)
    if share >= p.ready_share:
        return ObstacleVerdict(share, nearest, v_max, "ready", count)
    if share >= p.stop_share:
        limit = v_max * (share - p.stop_share) / (p.ready_share - p.stop_share)
        return ObstacleVerdict(share, nearest, limit, "slow", count)
    return ObstacleVerdict(share, nearest, 0.0, "stop", count)


def occupied_cells(
    cells: np.ndarray, origin_x: float, origin_y: float, resolution_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """Centres of the occupied cells of a grid (cells[row, col], row along y)."""
    rows, cols = np.nonzero(cells == OCCUPIED)
    return origin_x + (cols + 0.5) * resolution_m, origin_y + (rows + 0.5) * resolution_m
