"""Roads drawn from straights and arcs, and how far a driven or imported path lies from one."""

from __future__ import annotations

import math

import numpy as np

from ares.core.route import Route


def road(pieces, start=(0.0, 0.0), heading_deg=0.0, step=0.05) -> np.ndarray:
    """Dense x, y of a road of straights ("L", metres) and arcs ("A", radius, degrees, + = left)."""
    x, y, h = start[0], start[1], math.radians(heading_deg)
    pts = [(x, y)]
    for piece in pieces:
        if piece[0] == "L":
            n = max(int(piece[1] / step), 1)
            for _ in range(n):
                x, y = x + math.cos(h) * piece[1] / n, y + math.sin(h) * piece[1] / n
                pts.append((x, y))
        else:
            _, radius, degrees = piece
            sweep = math.radians(degrees)
            n = max(int(abs(sweep) * radius / step), 1)
            cx, cy = (
                x - math.sin(h) * radius * math.copysign(1, sweep),
                y + math.cos(h) * radius * math.copysign(1, sweep),
            )
            for i in range(1, n + 1):
                a = h - math.copysign(math.pi / 2, sweep) + sweep * i / n
                pts.append((cx + radius * math.cos(a), cy + radius * math.sin(a)))
            h += sweep
            x, y = pts[-1]
    return np.array(pts)


def deviations(points: np.ndarray, reference: Route, start_s: float | None = None):
    """Distance of each point (taken in order) to the reference route, and the reference's yaw
    and z there. The projection follows the drive (hints), so a crossing matches the right pass."""
    dist, yaw, z, hint = [], [], [], start_s
    for x, y in points[:, :2]:
        s, xte, _ = reference.project(float(x), float(y), s_hint=hint)
        hint = s
        dist.append(abs(xte))
        z.append(reference.point_at(s)[2])
        # the tangent, not the yaw of the 0.25 m segment (which lags 0.02 rad on a 12 m arc)
        ahead, behind = reference.point_at(s + 0.1), reference.point_at(s - 0.1)
        yaw.append(math.atan2(ahead[1] - behind[1], ahead[0] - behind[0]))
    return np.array(dist), np.array(yaw), np.array(z)
