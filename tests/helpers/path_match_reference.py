"""Frozen reference: PathIndex.match and Route.project as they were before the tracked search
scanned the hint's window directly and the polyline projection moved to ares.core.geometry
(commit 0646498).

Kept, unchanged, only so that tests/test_path_manager.py can check that the faster code returns
exactly the same results on random routes and drives. Do not edit it to follow later changes
of the matching rules: change or drop the comparison test instead.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

from ares.core.route import SAMPLE_SPACING_M, Route

TWO_PI = 2.0 * math.pi


def wrap_angle(a: float) -> float:
    return (a + math.pi) % TWO_PI - math.pi


class ReferencePathIndex:
    """match() returns (index, s, progress, lap, xte, heading_error, search) or None."""

    def __init__(
        self,
        route: Route,
        *,
        radius_m: float = 5.0,
        fallback_radius_m: float = 50.0,
        max_heading_error_rad: float = 1.0,
        window_behind_m: float = 5.0,
        window_ahead_m: float = 15.0,
    ):
        self.route = route
        self.closed = route.closed
        self.length = route.length
        self.n = len(route)
        self.radius_m = float(radius_m)
        self.fallback_radius_m = float(fallback_radius_m)
        self.cos_heading_limit = math.cos(float(max_heading_error_rad))
        self.window_behind_m = float(window_behind_m)
        self.window_ahead_m = float(window_ahead_m)
        self.tree = cKDTree(np.column_stack([route.x, route.y]))
        nxt = np.roll(np.arange(self.n), -1)
        ex, ey = route.x[nxt] - route.x, route.y[nxt] - route.y
        if not self.closed:
            ex[-1] = ey[-1] = 0.0
        self._cos_yaw = np.cos(route.yaw)
        self._sin_yaw = np.sin(route.yaw)
        self._px, self._py, self._ps = route.x.tolist(), route.y.tolist(), route.s.tolist()
        self._pyaw = route.yaw.tolist()
        self._pex, self._pey = ex.tolist(), ey.tolist()
        self._pseg2 = (ex * ex + ey * ey).tolist()

    def match(self, x, y, yaw, s_hint=None, radius=None):
        r = self.radius_m if radius is None else float(radius)
        search = "tracked" if s_hint is not None else "nearest"
        i = self._nearest_reachable(x, y, yaw, s_hint, r)
        if i is None:
            search = "wide"
            i = self._nearest_reachable(x, y, yaw, None, max(r, self.fallback_radius_m))
            if i is None:
                return None
        return self._refine(i, x, y, yaw, s_hint, search)

    def _nearest_reachable(self, x, y, yaw, s_hint, r):
        cand = self.tree.query_ball_point((x, y), r)
        if not cand:
            return None
        c = np.array(cand, dtype=np.intp)
        if yaw is None:
            ok = np.ones(len(c), dtype=bool)
        else:
            ok = self._cos_yaw[c] * math.cos(yaw) + self._sin_yaw[c] * math.sin(yaw) > self.cos_heading_limit
        if s_hint is not None:
            ds = self.route.s[c] - self._wrap(s_hint)
            if self.closed:
                ds = (ds + 0.5 * self.length) % self.length - 0.5 * self.length
            ok &= (ds >= -self.window_behind_m) & (ds <= self.window_ahead_m)
        c = c[ok]
        if len(c) == 0:
            return None
        dx = self.route.x[c] - x
        dy = self.route.y[c] - y
        return int(c[np.argmin(dx * dx + dy * dy)])

    def _refine(self, i, x, y, yaw, s_hint, search):
        n = self.n
        if self.closed:
            segments = ((i - 1) % n, i)
        else:
            segments = tuple(k for k in (i - 1, i) if 0 <= k <= n - 2)
        best = None
        for k in segments:
            ax, ay, ex, ey, seg2 = self._px[k], self._py[k], self._pex[k], self._pey[k], self._pseg2[k]
            t = ((x - ax) * ex + (y - ay) * ey) / seg2 if seg2 > 0.0 else 0.0
            lo = -math.inf if (not self.closed and k == 0) else 0.0
            hi = math.inf if (not self.closed and k == n - 2) else 1.0
            t = lo if t < lo else hi if t > hi else t
            fx, fy = ax + t * ex, ay + t * ey
            d2 = (x - fx) ** 2 + (y - fy) ** 2
            if best is None or d2 < best[0]:
                best = (d2, k, t, ex, ey, ax, ay)
        d2, k, t, ex, ey, ax, ay = best
        side = ex * (y - ay) - ey * (x - ax)
        xte = math.copysign(math.sqrt(d2), side) if d2 > 0.0 else 0.0
        s = self._ps[k] + t * math.sqrt(self._pseg2[k])
        if self.closed:
            s %= self.length
        if s_hint is None:
            progress = s
        else:
            progress = s_hint + self._step(self._wrap(s_hint), s)
        lap = int(progress // self.length) if self.closed else 0
        heading_error = 0.0 if yaw is None else wrap_angle(yaw - self._pyaw[k])
        return k, s, progress, lap, xte, heading_error, search

    def _wrap(self, s):
        return s % self.length if self.closed else s

    def _step(self, s_from, s_to):
        step = s_to - s_from
        if self.closed:
            step = (step + 0.5 * self.length) % self.length - 0.5 * self.length
        return step


def reference_project(
    route: Route, x: float, y: float, s_hint: float | None = None, window_m: float = 30.0
) -> tuple[float, float, int]:
    n = len(route.x)
    if s_hint is None:
        idx = np.arange(n)
    else:
        half = int(window_m / SAMPLE_SPACING_M) + 2
        centre = route.index_at(s_hint)
        idx = np.arange(centre - half, centre + half + 1)
        idx = idx % n if route.closed else idx[(idx >= 0) & (idx < n)]
    if not route.closed:
        idx = idx[idx < n - 1]
        if len(idx) == 0:
            idx = np.array([n - 2])
    j = (idx + 1) % n
    ax, ay = route.x[idx], route.y[idx]
    ex, ey = route.x[j] - ax, route.y[j] - ay
    seg2 = ex * ex + ey * ey
    lo = np.zeros(len(idx))
    hi = np.ones(len(idx))
    if not route.closed:
        lo[idx == 0] = -np.inf
        hi[idx == n - 2] = np.inf
    t = np.clip(((x - ax) * ex + (y - ay) * ey) / np.where(seg2 > 0, seg2, 1.0), lo, hi)
    px, py = ax + t * ex, ay + t * ey
    d2 = (x - px) ** 2 + (y - py) ** 2
    k = int(np.argmin(d2))
    i = int(idx[k])
    seg_len = math.sqrt(seg2[k])
    side = ex[k] * (y - ay[k]) - ey[k] * (x - ax[k])
    xte = math.copysign(math.sqrt(d2[k]), side) if d2[k] > 0 else 0.0
    return float(route.s[i] + t[k] * seg_len), xte, i
