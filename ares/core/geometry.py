"""Plane geometry shared by the route, the path manager, perception and the controllers: angles,
frames, a step along an arc, and the projection of a point onto the segments of a polyline.

A segment runs from its start (ax, ay) along (ex, ey) to (ax + ex, ay + ey). The projection is
given twice, for one segment on plain floats (a matcher refining two segments per pose pays
more for numpy's call overhead than for the arithmetic) and for arrays of segments (a search
along a stretch of route); the two are the same formula, line for line. (Their squared
distances may differ in the last bit: `** 2` on a float is the C library's pow(), on an array
an exact product.)
"""

from __future__ import annotations

import math
from typing import TypeVar

import numpy as np

TWO_PI = 2.0 * math.pi

Coord = TypeVar("Coord", float, np.ndarray)  # one point's coordinate, or an array of them


def vehicle_to_local(x: float, y: float, yaw: float, xv: Coord, yv: Coord) -> tuple[Coord, Coord]:
    """Points of the vehicle frame (x ahead, y left; floats or arrays) in the local frame, the
    vehicle at (x, y) heading yaw."""
    c, s = math.cos(yaw), math.sin(yaw)
    return x + c * xv - s * yv, y + s * xv + c * yv


def local_to_vehicle(x: float, y: float, yaw: float, xl: Coord, yl: Coord) -> tuple[Coord, Coord]:
    """Points of the local frame in the vehicle frame (the inverse of vehicle_to_local)."""
    c, s = math.cos(yaw), math.sin(yaw)
    dx, dy = xl - x, yl - y
    return c * dx + s * dy, -s * dx + c * dy


def arc_step(x: float, y: float, yaw: float, ds: float, kappa: float) -> tuple[float, float, float]:
    """The pose after ds metres along an arc of curvature kappa (exact for a constant kappa;
    ds < 0 goes back along it)."""
    dyaw = kappa * ds
    chord = ds if abs(dyaw) < 1e-9 else 2.0 * math.sin(dyaw / 2.0) / kappa
    return x + chord * math.cos(yaw + dyaw / 2.0), y + chord * math.sin(yaw + dyaw / 2.0), yaw + dyaw


def wrap_angle(a: float) -> float:
    """An angle in [-pi, pi)."""
    return (a + math.pi) % TWO_PI - math.pi


def project_on_segment(
    x: float,
    y: float,
    ax: float,
    ay: float,
    ex: float,
    ey: float,
    extend_back: bool = False,
    extend_ahead: bool = False,
) -> tuple[float, float]:
    """Foot of the perpendicular from (x, y) on a segment, as (t, squared distance to the foot):
    the foot is (ax + t ex, ay + t ey), t clamped to [0, 1] except on an extended side. An open
    route extends its first segment back and its last ahead, so that before its start or past
    its end only the distance across it counts: overshooting the end is no cross-track error."""
    seg2 = ex * ex + ey * ey
    t = ((x - ax) * ex + (y - ay) * ey) / seg2 if seg2 > 0.0 else 0.0
    lo = -math.inf if extend_back else 0.0
    hi = math.inf if extend_ahead else 1.0
    t = lo if t < lo else hi if t > hi else t
    return t, (x - (ax + t * ex)) ** 2 + (y - (ay + t * ey)) ** 2


def project_on_segments(
    x: float,
    y: float,
    ax: np.ndarray,
    ay: np.ndarray,
    ex: np.ndarray,
    ey: np.ndarray,
    extend_back: np.ndarray | bool,
    extend_ahead: np.ndarray | bool,
) -> tuple[np.ndarray, np.ndarray]:
    """project_on_segment for arrays of segments: arrays of t and of squared distances
    (extend_back and extend_ahead are boolean arrays, or one bool for every segment)."""
    seg2 = ex * ex + ey * ey
    t = np.divide((x - ax) * ex + (y - ay) * ey, seg2, out=np.zeros_like(seg2), where=seg2 > 0.0)
    lo = np.where(extend_back, -np.inf, 0.0)
    hi = np.where(extend_ahead, np.inf, 1.0)
    t = np.minimum(np.maximum(t, lo), hi)
    return t, (x - (ax + t * ex)) ** 2 + (y - (ay + t * ey)) ** 2


def signed_distance(x: float, y: float, ax: float, ay: float, ex: float, ey: float, d2: float) -> float:
    """The distance sqrt(d2) of (x, y) from a segment (d2 as the projection gives it), positive
    when the point lies left of the segment's direction: the cross-track error."""
    side = ex * (y - ay) - ey * (x - ax)
    return math.copysign(math.sqrt(d2), side) if d2 > 0.0 else 0.0


def rectangle_corners(cx: float, cy: float, yaw: float, front: float, back: float, half_width: float) -> np.ndarray:
    """The 4 corners (counter-clockwise) of a rectangle reaching `front` ahead of and `back` behind
    (cx, cy) along yaw, half_width either side."""
    c, s = math.cos(yaw), math.sin(yaw)
    local = [(front, -half_width), (front, half_width), (-back, half_width), (-back, -half_width)]
    return np.array([(cx + c * x - s * y, cy + s * x + c * y) for x, y in local])


def convex_gap(a: np.ndarray, b: np.ndarray) -> float:
    """The distance between two convex polygons (corners in order); 0 when they overlap."""

    def separated_along_an_edge_of(p: np.ndarray, q: np.ndarray) -> bool:
        for i in range(len(p)):
            edge = p[(i + 1) % len(p)] - p[i]
            normal = np.array([-edge[1], edge[0]])
            if (p @ normal).max() < (q @ normal).min() or (q @ normal).max() < (p @ normal).min():
                return True
        return False

    if not separated_along_an_edge_of(a, b) and not separated_along_an_edge_of(b, a):
        return 0.0
    best = math.inf
    for p, q in ((a, b), (b, a)):
        for x, y in p:
            for i in range(len(q)):
                ax, ay = q[i]
                bx, by = q[(i + 1) % len(q)]
                _, d2 = project_on_segment(x, y, ax, ay, bx - ax, by - ay)
                best = min(best, d2)
    return math.sqrt(best)
