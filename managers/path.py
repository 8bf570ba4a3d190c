"""The path manager's match: where the vehicle is on its route, and the path ahead (ARES §3.2).

path/match carries the segment index, s, lap, signed cross-track and heading errors, the zones
at s, force_odometry (inside an intersection or road opening the path manager forces odometry
control), the distance to the end (open routes), and the poses ahead with their speed limits
(the speed_profile section, until the speed manager exists).

Events:  path_rematch when the tracked match is lost and a wider search finds the vehicle
         again; path_lost when nothing reachable is found at all

Each pose estimate asks for "the nearest *reachable* path pose within radius r": among the
poses within r, only those whose heading agrees with the vehicle's, whose height is the
vehicle's within max_height_error_m and — once tracking — whose s lies in a short window around
the last matched progress qualify. The heading test keeps a vehicle off the opposite leg of a
hairpin and off the other direction of a road driven both ways; the height test off the other
level of a ramp or a bridge over the route; the window keeps it on its own pass of a crossing
and on its own lap. The route is recorded once, so its poses go into a KD-tree over
{X, Y, Z, Ψ} as the paper builds it (§3.2): x, y, height_scale·z and the heading as the point
heading_scale_m·(cos ψ, sin ψ), so that "nearest" weighs a metre of height and a radian of
heading against metres on the ground and never sees a jump at ±π. The tree answers the searches
without a window; while tracking, the window's few dozen poses are read straight from the route
instead, in the same metric. The nearest qualifying pose is then refined to the foot of the
perpendicular on its segments, for a continuous s and a signed cross-track error.

A heading or a height the localization is not sure of (max_heading_sigma_rad,
max_height_sigma_m: a standing vehicle's first fix, a fix without altitude) is left out: the
heading as the origin of its plane (every pose then adds the same heading_scale_m², so the
order is the ground's and the height's), the height by a second tree over {X, Y, Ψ}.

When nothing qualifies (no hint yet and the vehicle beyond r, or a pose jump out of the
window) the search widens to path_manager.fallback_radius_m without the window, and the
match says so (search "wide"; the node raises a path_rematch event). Progress is unwrapped s:
it starts at the first match's s, so the lap count goes up each time the start line (s = 0)
is crossed; after a wide match it moves by the short way round from the last progress.

PathIndex and PathTracker do the work without the bus (tests, benches); managers.path_node is
the process around them.

A stale pose (older than path_manager.pose_timeout_s) is not matched: nothing is published,
so the controller goes quiet and the drive-by-wire watchdog stops the vehicle.
"""

from __future__ import annotations

import math
from bisect import bisect_left, bisect_right
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ares.core.config import Params, param
from ares.core.geometry import project_on_segment, signed_distance, wrap_angle
from ares.core.messages import PathMatch
from ares.core.route import Route

# The tracked search takes the poses whose s lies within this much more than the hint's window,
# then applies the window test itself: rounding at the window's edges cannot drop a pose
WINDOW_SLACK_M = 1e-6
FLAT = [0, 1, 3, 4]  # the KD-tree's columns without the height: a pose whose height is not known


class PathManagerParams(Params):
    """KD-tree match of the pose to the route, path ahead (ARES §3.2)."""

    rate_hz: float = param(20.0, "loop and publishing rate", unit="Hz", gt=0)
    pose_timeout_s: float = param(
        1.0,
        "an older pose is not matched: nothing is published (1 s of vehicle time is "
        "0.2 s of wall time at --speed 5: a busy machine, not a dead localization)",
        unit="s",
        gt=0,
    )
    radius_m: float = param(5.0, "search radius r around the vehicle", unit="m", gt=0)
    max_heading_error_rad: float = param(
        1.0, "path poses facing further from the vehicle's yaw are unreachable (hairpins)", unit="rad", gt=0
    )
    max_heading_sigma_rad: float = param(
        0.5, "a pose whose heading is less certain than this is matched by position only", unit="rad", gt=0
    )
    heading_scale_m: float = param(
        1.0,
        "the KD-tree's heading: a radian between the vehicle's and a pose's weighs about this many metres",
        unit="m/rad",
        ge=0,
    )
    height_scale: float = param(1.0, "the KD-tree's Z: a metre of height weighs this many metres on the ground", ge=0)
    max_height_error_m: float = param(
        2.0, "path poses further above or below the vehicle are unreachable (a ramp's other level)", unit="m", gt=0
    )
    max_height_sigma_m: float = param(
        1.5, "a pose whose height is less certain than this is matched without it", unit="m", gt=0
    )
    window_behind_m: float = param(5.0, "once tracking, only poses this far behind the last match ...", unit="m", ge=0)
    window_ahead_m: float = param(
        15.0, "... or this far ahead qualify: never the other pass of a crossing or a later lap", unit="m", gt=0
    )
    fallback_radius_m: float = param(
        50.0, "nothing qualifies (start-up, a pose jump): search this wide, without the window", unit="m", gt=0
    )
    ahead_length_m: float = param(30.0, "path sent ahead of the match", unit="m", gt=0)
    ahead_step_m: float = param(0.5, "spacing of the poses ahead", unit="m", gt=0)
    force_odometry_zones: list[str] = param(
        doc="docs/design.md §3: odometry control is forced in these zones",
        factory=lambda: ["intersection", "road_opening"],
    )


@dataclass(frozen=True)
class Match:
    index: int  # route segment the vehicle is on (from sample index to index + 1)
    s: float  # continuous arc length: [0, length) on a closed route; on an open
    # one it may leave [0, length] before the start / past the end
    progress: float  # unwrapped s (laps included): the hint for the next match
    lap: int  # progress // length on a closed route, 0 on an open one
    xte: float  # signed cross-track error, m, positive when left of the path
    heading_error: float  # vehicle yaw minus path yaw, rad in [-pi, pi)
    search: str  # "tracked": in the hint's window; "nearest": no hint yet;
    # "wide": nothing qualified, found by the wider fallback search


@dataclass(frozen=True)
class Ahead:
    """Route poses from a starting s, every step metres (numpy arrays of equal length)."""

    x: np.ndarray
    y: np.ndarray
    yaw: np.ndarray
    curvature: np.ndarray
    speed: np.ndarray
    s: np.ndarray


class PathIndex:
    """A route with a KD-tree over its {X, Y, Z, Ψ} poses, answering reachable-nearest queries, with
    the search settings of the path_manager section (`PathManagerParams`; its defaults when none given)."""

    def __init__(self, route: Route, params: PathManagerParams | None = None, speed_limit: np.ndarray | None = None):
        params = PathManagerParams() if params is None else params
        self.route = route
        self.closed = route.closed
        self.length = route.length
        self.n = len(route)
        self.radius_m = float(params.radius_m)
        self.fallback_radius_m = float(params.fallback_radius_m)
        self.cos_heading_limit = math.cos(float(params.max_heading_error_rad))
        self.window_behind_m = float(params.window_behind_m)
        self.window_ahead_m = float(params.window_ahead_m)
        self.heading_scale_m = float(params.heading_scale_m)
        self.max_height_error_m = float(params.max_height_error_m)
        # the tree's points, one per pose: x, y, scaled z, scaled heading (the flat tree: without z)
        self.points = np.column_stack(
            [
                route.x,
                route.y,
                float(params.height_scale) * route.z,
                self.heading_scale_m * np.cos(route.yaw),
                self.heading_scale_m * np.sin(route.yaw),
            ]
        )
        self._height_scale = float(params.height_scale)
        self.tree = cKDTree(self.points)
        self._flat_tree = cKDTree(self.points[:, FLAT])
        self._heading_ball2 = self.heading_scale_m**2 * (2.0 - 2.0 * self.cos_heading_limit)
        # the squared columns weighed into (the tree's distance, the ground's, the height's), the
        # height known or not; a height_scale of 0 turns the height off, the check with it
        self._measures = {
            known: np.array([[1, 1, 0], [1, 1, 0], [known, 0, known], [1, 0, 0], [1, 0, 0]], dtype=float)
            for known in (False, True)
        }
        limit = self._height_scale * self.max_height_error_m
        self._height_limit2 = limit * limit if limit > 0 else math.inf
        if speed_limit is None:
            speed_limit = np.zeros(self.n)  # no profile given: nothing ahead may be driven
        if len(speed_limit) != self.n:
            raise ValueError(f"speed limit has {len(speed_limit)} values for {self.n} route poses")
        self.speed_limit = np.asarray(speed_limit, dtype=float)
        # per-segment geometry (segment i runs from pose i to pose i+1; a closed route's last
        # segment closes the loop; an open route's last "segment" is empty)
        nxt = np.roll(np.arange(self.n), -1)
        ex, ey = route.x[nxt] - route.x, route.y[nxt] - route.y
        if not self.closed:
            ex[-1] = ey[-1] = 0.0
        self._seg_len = np.hypot(ex, ey)
        # single poses are read from plain lists: indexing one costs a fraction of indexing a
        # numpy array, and a match reads a handful
        self._x, self._y, self._s, self._yaw = route.x.tolist(), route.y.tolist(), route.s.tolist(), route.yaw.tolist()
        self._cos_yaw, self._sin_yaw = np.cos(route.yaw).tolist(), np.sin(route.yaw).tolist()
        self._ex, self._ey = ex.tolist(), ey.tolist()
        # pose numbers over two laps of a loop, so that a window across its start is one slice
        self._pose_numbers = np.arange(2 * self.n) % self.n if self.closed else np.arange(self.n)
        self._window_points = np.vstack([self.points, self.points]) if self.closed else self.points
        # each pose's place in the KD-tree's leaf order, the order in which a ball query lists
        # poses: equally near poses are taken in that order, whichever search found them
        self._kd_order = np.empty(self.n, dtype=np.intp)
        self._kd_order[self.tree.indices] = np.arange(self.n)

    # ---- matching ---------------------------------------------------------------------------
    def match(
        self,
        x: float,
        y: float,
        yaw: float | None,
        s_hint: float | None = None,
        radius: float | None = None,
        z: float | None = None,
    ) -> Match | None:
        """The nearest reachable path pose within `radius` (default radius_m) of (x, y) on the
        ground, at height `z` (None: not known, matched without it).

        `s_hint` is the last match's progress (unwrapped s). Without a match within the hint's
        window (start-up, a relocalisation jump, a long outage) the search widens to
        fallback_radius_m around the vehicle, heading and height still checked but the window
        dropped, and says so (search == "wide"). None when nothing reachable is found at all,
        e.g. the vehicle faces against the route, is far off it or on another level.
        """
        r = self.radius_m if radius is None else float(radius)
        query = self.query_point(x, y, z, yaw)
        if s_hint is None:
            search, i = "nearest", self._nearest_in_ball(query, yaw, z, r)
        else:
            search, i = "tracked", self._nearest_in_window(query, yaw, z, self._wrap(s_hint), r)
        if i is None:
            search, i = "wide", self._nearest_in_ball(query, yaw, z, max(r, self.fallback_radius_m))
            if i is None:
                return None
        return self._refine(i, x, y, yaw, s_hint, search)

    def query_point(self, x: float, y: float, z: float | None, yaw: float | None) -> np.ndarray:
        """The vehicle in the tree's space: an unknown heading at the origin of the heading's plane,
        an unknown height at 0 (weighed by nothing: `_measures`)."""
        hx, hy = (
            (0.0, 0.0) if yaw is None else (self.heading_scale_m * math.cos(yaw), self.heading_scale_m * math.sin(yaw))
        )
        return np.array([x, y, 0.0 if z is None else self._height_scale * z, hx, hy])

    def _nearest_in_ball(self, query: np.ndarray, yaw: float | None, z: float | None, r: float) -> int | None:
        # the ball holds every pose within r on the ground that may qualify: it reaches as far
        # as the heading limit and the height limit let a qualifying pose lie in the tree's space
        reach2 = r * r + (self.heading_scale_m**2 if yaw is None else self._heading_ball2)
        if z is None:
            found = self._flat_tree.query_ball_point(query[FLAT], math.sqrt(reach2))
        else:
            found = self.tree.query_ball_point(query, math.sqrt(reach2 + self._height_limit2))
        poses = np.array(found, dtype=np.intp)
        return self._nearest_reachable(poses, self.points[poses], query, yaw, z, None, r * r)

    def _nearest_in_window(
        self, query: np.ndarray, yaw: float | None, z: float | None, hint: float, r: float
    ) -> int | None:
        """While tracking, only the hint's window qualifies: a few dozen poses, taken straight
        from the route (one slice), where a ball query would gather the whole neighbourhood."""
        first = hint - self.window_behind_m - WINDOW_SLACK_M
        last = hint + self.window_ahead_m + WINDOW_SLACK_M
        if self.closed:
            # poses numbered on from the start of the lap in which `first` lies (n and more are
            # the next lap's); a window longer than the loop takes each pose once
            lap, first = divmod(first, self.length)
            laps_on, last = divmod(last - lap * self.length, self.length)
            begin = bisect_left(self._s, first)
            end = min(int(laps_on) * self.n + bisect_right(self._s, last), begin + self.n)
        else:
            begin, end = bisect_left(self._s, first), bisect_right(self._s, last)
        rows = self._window_points[begin:end]
        return self._nearest_reachable(self._pose_numbers[begin:end], rows, query, yaw, z, hint, r * r)

    def _nearest_reachable(
        self,
        poses: np.ndarray,
        rows: np.ndarray,
        query: np.ndarray,
        yaw: float | None,
        z: float | None,
        hint: float | None,
        r2: float,
    ) -> int | None:
        """The nearest of `poses` (pose numbers; `rows`: their points) in the tree's metric that lies
        within sqrt(r2) of the vehicle on the ground, at its height, and is reachable."""
        diff = rows - query
        # one product gives each pose's distance in the tree's metric, on the ground, in height
        distance2, ground2, height2 = ((diff * diff) @ self._measures[z is not None]).T
        near = ground2 <= r2
        if z is not None:
            near &= height2 <= self._height_limit2
        poses, distance2 = poses[near], distance2[near]
        # nearest first, equally near poses in the KD-tree's order; the first reachable one wins
        for k in np.lexsort((self._kd_order[poses], distance2)):
            i = int(poses[k])
            if self._reachable(i, yaw, hint):
                return i
        return None

    def _reachable(self, i: int, yaw: float | None, hint: float | None) -> bool:
        """Pose i faces within the heading limit of `yaw` and, given a (wrapped) hint, lies within
        the hint's window. Without a heading (not known yet: a standing vehicle's first fix) any
        pose faces right."""
        if yaw is not None:  # heading agreement as a dot product of unit vectors: cos(dyaw) > cos(limit)
            if self._cos_yaw[i] * math.cos(yaw) + self._sin_yaw[i] * math.sin(yaw) <= self.cos_heading_limit:
                return False
        if hint is None:
            return True
        ds = self._s[i] - hint
        if self.closed:  # signed along-route step, the short way round the loop
            ds = (ds + 0.5 * self.length) % self.length - 0.5 * self.length
        return -self.window_behind_m <= ds <= self.window_ahead_m

    def _refine(self, i: int, x: float, y: float, yaw: float | None, s_hint: float | None, search: str) -> Match:
        """Foot of the perpendicular on the segments either side of pose i."""
        n, closed = self.n, self.closed
        if closed:
            segments = ((i - 1) % n, i)
        else:
            segments = tuple(k for k in (i - 1, i) if 0 <= k <= n - 2)
        best = None
        for k in segments:
            t, d2 = project_on_segment(
                x,
                y,
                self._x[k],
                self._y[k],
                self._ex[k],
                self._ey[k],
                extend_back=not closed and k == 0,
                extend_ahead=not closed and k == n - 2,
            )
            if best is None or d2 < best[0]:
                best = d2, k, t
        d2, k, t = best
        ax, ay, ex, ey = self._x[k], self._y[k], self._ex[k], self._ey[k]
        xte = signed_distance(x, y, ax, ay, ex, ey, d2)
        s = self._s[k] + t * math.sqrt(ex * ex + ey * ey)
        if closed:
            s %= self.length
        if s_hint is None:
            progress = s
        else:
            progress = s_hint + self._step(self._wrap(s_hint), s)
        lap = int(progress // self.length) if closed else 0
        return Match(
            index=k,
            s=s,
            progress=progress,
            lap=lap,
            xte=xte,
            heading_error=0.0 if yaw is None else wrap_angle(yaw - self._yaw[k]),
            search=search,
        )

    def _wrap(self, s: float) -> float:
        return s % self.length if self.closed else s

    def _step(self, s_from: float, s_to: float) -> float:
        step = s_to - s_from
        if self.closed:
            step = (step + 0.5 * self.length) % self.length - 0.5 * self.length
        return step

    # ---- the path ahead ---------------------------------------------------------------------
    def ahead(self, index: int, length_m: float, step_m: float, s: float | None = None) -> Ahead:
        """Poses from `s` (default: pose `index`'s own s) every `step_m` for `length_m`,
        interpolated along the segments. A closed route wraps past its start; an open one
        stops at its end, whose exact pose is always the last sample when within reach."""
        route = self.route
        s0 = float(route.s[index]) if s is None else float(s)
        count = int(math.floor(length_m / step_m + 1e-9)) + 1
        sq = s0 + step_m * np.arange(count)
        if self.closed:
            sq %= self.length
            idx = np.searchsorted(route.s, sq, side="right") - 1
            nxt = (idx + 1) % self.n
        else:
            end = float(route.s[-1])
            sq = np.clip(s0, 0.0, end) + step_m * np.arange(count)  # from the start or the end if outside
            reaches_end = sq[-1] >= end
            sq = sq[sq < end - 1e-9]
            if reaches_end or len(sq) == 0:
                sq = np.append(sq, end)
            idx = np.clip(np.searchsorted(route.s, sq, side="right") - 1, 0, self.n - 2)
            nxt = idx + 1
        seg = self._seg_len[idx]
        f = np.where(seg > 0.0, (sq - route.s[idx]) / np.where(seg > 0.0, seg, 1.0), 0.0)
        lerp = lambda a: a[idx] + f * (a[nxt] - a[idx])  # noqa: E731
        return Ahead(
            x=lerp(route.x),
            y=lerp(route.y),
            yaw=route.yaw[idx].copy(),
            curvature=lerp(route.curvature),
            speed=lerp(self.speed_limit),
            s=sq,
        )


def zone_kinds_at(route: Route, s: float) -> list[str]:
    """Names of the kinds of zone containing s, each once, sorted."""
    return sorted({zone.kind for zone in route.zones_at(s)})


class PathTracker:
    """The path manager's work without the bus: successive poses in, PathMatch messages out.
    It keeps the last matched progress as the hint of the next match."""

    def __init__(self, route: Route, params: PathManagerParams, speed_limit: np.ndarray | None = None):
        self.route = route
        self.index = PathIndex(route, params, speed_limit)
        self.ahead_length_m = params.ahead_length_m
        self.ahead_step_m = params.ahead_step_m
        self.force_odometry_zones = frozenset(params.force_odometry_zones)
        self.max_heading_var = params.max_heading_sigma_rad**2
        self.max_height_var = params.max_height_sigma_m**2
        self.progress: float | None = None  # last matched progress: the next query's hint

    def update(
        self,
        now: float,
        x: float,
        y: float,
        yaw: float,
        var_yaw: float = 0.0,
        z: float | None = None,
        var_z: float | None = None,
    ) -> tuple[Match | None, PathMatch | None]:
        # until the vehicle has moved, the UKF's heading may be a guess (no magnetometer reading
        # before the first fix): then match by position, or the vehicle would never set off; a
        # height not known (no altitude in the fixes, an old recording) is left out alike
        yaw_known = var_yaw <= self.max_heading_var
        z_known = z is not None and var_z is not None and var_z <= self.max_height_var
        m = self.index.match(x, y, yaw if yaw_known else None, self.progress, z=z if z_known else None)
        if m is None:
            return None, None  # keep the hint: the vehicle may come back to where it was
        self.progress = m.progress
        zones = zone_kinds_at(self.route, m.s)
        ahead = self.index.ahead(m.index, self.ahead_length_m, self.ahead_step_m, s=m.s)
        return m, PathMatch(
            t=now,
            index=m.index,
            s=m.s,
            lap=m.lap,
            xte=m.xte,
            heading_error=m.heading_error,
            zones=zones,
            force_odometry=not self.force_odometry_zones.isdisjoint(zones),
            distance_to_end_m=None if self.route.closed else max(self.route.length - m.s, 0.0),
            # a creep or a stop must not carry a wide road's bounds into a narrow one
            road_width_ahead_m=float(
                min(self.route.width[m.index], np.interp(ahead.s, self.route.s, self.route.width).min())
            ),
            ahead_x=ahead.x.tolist(),
            ahead_y=ahead.y.tolist(),
            ahead_yaw=ahead.yaw.tolist(),
            ahead_curvature=ahead.curvature.tolist(),
            ahead_speed=ahead.speed.tolist(),
            ahead_s=ahead.s.tolist(),
        )
