"""Routes: a sampled path {X, Y, Z, Psi} with its POIs and zones.

A built-in tour is described in config/tours/*.yaml as a closed polygon whose corners are
rounded with circular arcs (a road with fillets), an elevation profile along the path, road
widths, POIs and zones (GNSS-correction dead zones, intersections). An open route can also
be read from a CSV of x,y[,z] points; such a file may say where on Earth its frame is (a
`# origin: lat=..., lon=..., altitude_m=..., utm_zone=..., hemisphere=...` comment, written by
`ares route import`), and a run that drives it uses that origin instead of the configured one.

Every consumer (simulator, controllers, the headless runner) builds the same Route from the
same description, so no process has to ship the geometry to another.
"""

from __future__ import annotations

import csv
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import utm

from ares.core import config
from ares.core.config import CoreConfig, TourDescription, UtmOrigin
from ares.core.geodesy import FrameError, origin_at
from ares.core.geometry import project_on_segments, signed_distance

SAMPLE_SPACING_M = 0.25
CSV_WIDTH_M = 4.0  # a route file's road width when its comments record none
CURVATURE_SPAN_M = 1.0  # curvature is measured over +-1 m of path


class RouteError(ValueError):
    """A route file or tour description that cannot be turned into a route."""


@dataclass(frozen=True)
class Poi:
    name: str
    s: float
    actions: tuple[str, ...] = ()


@dataclass(frozen=True)
class Zone:
    kind: str  # "rtk_loss" (sky blocked) | "no_4g" (no corrections) | "intersection" | "road_opening" | "narrow"
    s_start: float
    s_end: float
    full_stop: bool = False  # an intersection with a stop line at s_start (the mission's FULL_STOP)

    def contains(self, s: float) -> bool:
        return self.s_start <= s <= self.s_end


@dataclass(frozen=True)
class Verge:
    """What lies beside the road from s_start to s_end, left and right (config.VERGE_KINDS)."""

    s_start: float
    s_end: float
    left: str
    right: str

    def contains(self, s: float) -> bool:
        return self.s_start <= s < self.s_end


OPEN_ZONES = ("intersection", "road_opening")  # no road boundary exists there


@dataclass
class Route:
    name: str
    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    closed: bool
    width: np.ndarray
    pois: list[Poi] = field(default_factory=list)
    zones: list[Zone] = field(default_factory=list)
    origin: UtmOrigin | None = None  # where on Earth the frame is, when the route file says
    verges: list[Verge] = field(default_factory=list)
    default_verge: str = "kerb"
    speed_limit_mps: float | None = None  # the road's limit (a tour's speed_limit_mps)

    def __post_init__(self) -> None:
        if len(self.x) < 2:
            raise RouteError("a route needs at least two points")
        dx = np.diff(self.x)
        dy = np.diff(self.y)
        seg = np.hypot(dx, dy)
        self.s = np.concatenate([[0.0], np.cumsum(seg)])
        yaw = np.arctan2(dy, dx)
        self.yaw = np.concatenate([yaw, yaw[-1:]])
        if self.closed:
            self.yaw[-1] = math.atan2(self.y[0] - self.y[-1], self.x[0] - self.x[-1])
        self.curvature = _curvature(self.x, self.y, self.closed)
        self.grade = np.gradient(self.z, self.s, edge_order=1) if len(self.s) > 2 else np.zeros_like(self.s)

    # ---- geometry -------------------------------------------------------------------
    @property
    def length(self) -> float:
        closing = math.hypot(self.x[0] - self.x[-1], self.y[0] - self.y[-1]) if self.closed else 0.0
        return float(self.s[-1] + closing)

    def __len__(self) -> int:
        return len(self.x)

    def wrap_s(self, s: float) -> float:
        return s % self.length if self.closed else min(max(s, 0.0), self.length)

    def step_between(self, s_from: float, s_to: float) -> float:
        """Signed distance along the route from s_from to s_to, taking the short way round a
        closed tour (so crossing the start line counts as a small step forward)."""
        step = s_to - s_from
        if self.closed and abs(step) > self.length / 2:
            step -= math.copysign(self.length, step)
        return step

    def index_at(self, s: float) -> int:
        return min(int(np.searchsorted(self.s, self.wrap_s(s), side="right")) - 1, len(self.s) - 1)

    def point_at(self, s: float) -> tuple[float, float, float, float]:
        """(x, y, z, yaw) at arc length s, interpolated along the segment."""
        s = self.wrap_s(s)
        i = self.index_at(s)
        j = (i + 1) % len(self.x) if self.closed else min(i + 1, len(self.x) - 1)
        seg_len = math.hypot(self.x[j] - self.x[i], self.y[j] - self.y[i])
        f = 0.0 if seg_len == 0 else min(max((s - self.s[i]) / seg_len, 0.0), 1.0)
        return (
            float(self.x[i] + f * (self.x[j] - self.x[i])),
            float(self.y[i] + f * (self.y[j] - self.y[i])),
            float(self.z[i] + f * (self.z[j] - self.z[i])),
            float(self.yaw[i]),
        )

    def project(
        self, x: float, y: float, s_hint: float | None = None, window_m: float = 30.0
    ) -> tuple[float, float, int]:
        """Nearest point of the route to (x, y): (s, signed cross-track error, segment index).

        With a hint, only the stretch within `window_m` of the hint is searched, so that a
        vehicle at a crossing or a hairpin is matched to the pass it is driving, not the other.
        The cross-track error is positive when the point lies left of the route.
        """
        n = len(self.x)
        if s_hint is None:
            idx = np.arange(n)
        else:
            half = int(window_m / SAMPLE_SPACING_M) + 2
            centre = self.index_at(s_hint)
            idx = np.arange(centre - half, centre + half + 1)
            idx = idx % n if self.closed else idx[(idx >= 0) & (idx < n)]
        if not self.closed:
            idx = idx[idx < n - 1]
            if len(idx) == 0:
                idx = np.array([n - 2])
        j = (idx + 1) % n
        ax, ay = self.x[idx], self.y[idx]
        ex, ey = self.x[j] - ax, self.y[j] - ay
        first, last = (False, False) if self.closed else (idx == 0, idx == n - 2)
        t, d2 = project_on_segments(x, y, ax, ay, ex, ey, extend_back=first, extend_ahead=last)
        k = int(np.argmin(d2))
        i = int(idx[k])
        seg_len = math.sqrt(ex[k] * ex[k] + ey[k] * ey[k])
        xte = signed_distance(x, y, ax[k], ay[k], ex[k], ey[k], d2[k])
        return float(self.s[i] + t[k] * seg_len), xte, i  # s may leave [0, length] on an open route

    def zones_at(self, s: float) -> list[Zone]:
        s = self.wrap_s(s)
        return [z for z in self.zones if z.contains(s)]

    def in_zone(self, s: float, kind: str) -> bool:
        return any(z.kind == kind for z in self.zones_at(s))

    def verge_at(self, s: float) -> tuple[str, str]:
        """(left, right) verge kinds at s: intersections and road openings are open."""
        s = self.wrap_s(s)
        if any(z.kind in OPEN_ZONES for z in self.zones_at(s)):
            return "open", "open"
        for verge in self.verges:
            if verge.contains(s):
                return verge.left, verge.right
        return self.default_verge, self.default_verge

    # ---- construction ---------------------------------------------------------------
    @classmethod
    def from_tour(cls, name: str) -> Route:
        return tour_from_description(config.load_tour(name))

    @classmethod
    def from_csv(cls, path: str | Path, name: str | None = None) -> Route:
        """An open route from a CSV of x,y[,z] points in metres. A header line and '#' comment
        lines are allowed; a header `x,y,z,yaw` (as `ares route import` writes) allows a 4th
        column, yaw, which is checked but not used: the route's yaw comes from its geometry. The
        road's width is the comment `# road: width_m=5.5` when there is one, else 4 m."""
        path = Path(path)
        points: list[tuple[float, float, float]] = []
        try:
            text = path.read_text()
        except OSError as exc:
            raise RouteError(f"{path}: cannot read: {exc.strerror}") from exc
        columns: tuple[int, ...] = (2, 3)
        first_row = True
        for lineno, row in enumerate(csv.reader(text.splitlines()), start=1):
            if not row or not "".join(row).strip() or row[0].lstrip().startswith("#"):
                continue
            try:
                values = [float(v) for v in row]
            except ValueError:
                if first_row:
                    first_row = False
                    if [c.strip().lower() for c in row] == ["x", "y", "z", "yaw"]:
                        columns = (4,)
                    continue  # header
                raise RouteError(f"{path}:{lineno}: expected numbers x,y[,z], got {','.join(row)!r}") from None
            first_row = False
            if len(values) not in columns or not all(math.isfinite(v) for v in values):
                expected = "2 or 3" if columns == (2, 3) else "4"
                raise RouteError(f"{path}:{lineno}: expected {expected} finite numbers, got {','.join(row)!r}")
            points.append((values[0], values[1], values[2] if len(values) >= 3 else 0.0))
        if len(points) < 2:
            raise RouteError(f"{path}: a route needs at least two points, found {len(points)}")
        xyz = resample(np.array(points), SAMPLE_SPACING_M)
        return cls(
            name=name or path.stem,
            x=xyz[:, 0],
            y=xyz[:, 1],
            z=xyz[:, 2],
            closed=False,
            width=np.full(len(xyz), width_in(text, path) or CSV_WIDTH_M),
            origin=origin_in(text, path),
        )


# ---- a route file's origin ------------------------------------------------------------

_ORIGIN_LINE = re.compile(r"#\s*origin:(.*)")
_WIDTH_LINE = re.compile(r"#\s*road:\s*width_m\s*=\s*(\S+)")
_ORIGIN_KEYS = {
    "lat": float,
    "lon": float,
    "altitude_m": float,
    "utm_zone": int,
    "hemisphere": str,
    "easting": float,
    "northing": float,
}


def origin_comment(origin: UtmOrigin) -> str:
    """The comment line (without '# ') that records a frame's origin in a route file."""
    lat, lon = utm.to_latlon(
        origin.easting, origin.northing, origin.zone, northern=origin.hemisphere == "N", strict=False
    )
    return (
        f"origin: lat={float(lat):.9f}, lon={float(lon):.9f}, altitude_m={origin.altitude_m:.3f}, "
        f"utm_zone={origin.zone}, hemisphere={origin.hemisphere}, easting={origin.easting:.3f}, "
        f"northing={origin.northing:.3f}"
    )


def origin_in(text: str, path: Path | str = "route") -> UtmOrigin | None:
    """The origin a route file's comment records; None when it records none. lat, lon and
    altitude_m are needed; the UTM zone and hemisphere default to the position's own, easting
    and northing to its projection there."""
    for lineno, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if stripped and not stripped.startswith("#"):
            return None  # the comments come first
        m = _ORIGIN_LINE.match(stripped)
        if m:
            return _parse_origin(m[1], f"{path}:{lineno}")
    return None


def width_comment(width_m: float) -> str:
    """The comment line (without '# ') that records a route file's road width."""
    return f"road: width_m={width_m:g}"


def width_in(text: str, path: Path | str = "route") -> float | None:
    """The road width a route file's leading comments record; None when they record none."""
    for lineno, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if stripped and not stripped.startswith("#"):
            return None
        m = _WIDTH_LINE.match(stripped)
        if m:
            try:
                width = float(m[1])
            except ValueError:
                width = math.nan
            if not (math.isfinite(width) and width > 0):
                raise RouteError(f"{path}:{lineno}: road width must be a positive number of metres, got {m[1]!r}")
            return width
    return None


def read_origin(path: str | Path) -> UtmOrigin | None:
    try:
        with open(path, errors="replace") as f:
            head = "".join(line for line, _ in zip(f, range(50)))
    except OSError as exc:
        raise RouteError(f"{path}: cannot read: {exc.strerror}") from exc
    return origin_in(head, path)


def _parse_origin(text: str, where: str) -> UtmOrigin:
    values = {}
    for item in filter(None, (part.strip() for part in text.split(","))):
        key, _, value = item.partition("=")
        key, value = key.strip(), value.strip()
        if key not in _ORIGIN_KEYS:
            raise RouteError(f"{where}: unknown origin key {key!r}; known: {', '.join(_ORIGIN_KEYS)}")
        try:
            values[key] = _ORIGIN_KEYS[key](value)
        except ValueError:
            raise RouteError(f"{where}: origin {key} must be a {_ORIGIN_KEYS[key].__name__}, got {value!r}") from None
    missing = [k for k in ("lat", "lon", "altitude_m") if k not in values]
    if missing:
        raise RouteError(f"{where}: the origin needs {', '.join(missing)}")
    zone, hemisphere = values.get("utm_zone"), values.get("hemisphere")
    if hemisphere not in (None, "N", "S") or not 1 <= (zone or 1) <= 60:
        raise RouteError(f"{where}: origin utm_zone must be 1-60 and hemisphere N or S")
    try:
        at = origin_at(values["lat"], values["lon"], values["altitude_m"], zone=zone, hemisphere=hemisphere)
    except FrameError as exc:
        raise RouteError(f"{where}: {exc}") from None
    given = (values.get("easting", at.easting), values.get("northing", at.northing))
    off = math.hypot(given[0] - at.easting, given[1] - at.northing)
    if off > 1.0:
        raise RouteError(
            f"{where}: the origin's easting and northing disagree with its latitude and longitude by {off:.1f} m"
        )
    return at.model_copy(
        update={"easting": float(given[0]), "northing": float(given[1]), "altitude_m": values["altitude_m"]}
    )


def resample(points: np.ndarray, spacing: float) -> np.ndarray:
    """Points evenly spaced along the polyline (duplicates dropped)."""
    step = np.hypot(np.diff(points[:, 0]), np.diff(points[:, 1]))
    keep = np.concatenate([[True], step > 1e-6])
    points = points[keep]
    if len(points) < 2:
        raise RouteError("a route needs at least two distinct points")
    s = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(points[:, 0]), np.diff(points[:, 1])))])
    s_new = np.arange(0.0, s[-1], spacing)
    if s[-1] - s_new[-1] > 1e-6:
        s_new = np.append(s_new, s[-1])
    return np.column_stack([np.interp(s_new, s, points[:, k]) for k in range(points.shape[1])])


def _curvature(x: np.ndarray, y: np.ndarray, closed: bool, span_m: float = CURVATURE_SPAN_M) -> np.ndarray:
    """Signed curvature (positive = left): the turn of the heading between the points about
    span_m behind and ahead, per metre. A span of a metre or two, not adjacent samples, so that
    a polyline resampled between its own vertices does not read as alternating curves."""
    n = len(x)
    step = np.hypot(np.diff(x), np.diff(y))
    spacing = float(np.median(step)) if len(step) else 1.0
    k = max(int(round(span_m / max(spacing, 1e-6))), 1)
    idx = np.arange(n)
    if closed:
        back, ahead = (idx - k) % n, (idx + k) % n
    else:
        back, ahead = np.clip(idx - k, 0, n - 1), np.clip(idx + k, 0, n - 1)
    yaw_in = np.arctan2(y[idx] - y[back], x[idx] - x[back])
    yaw_out = np.arctan2(y[ahead] - y[idx], x[ahead] - x[idx])
    turn = np.angle(np.exp(1j * (yaw_out - yaw_in)))
    dist = np.hypot(x[idx] - x[back], y[idx] - y[back]) + np.hypot(x[ahead] - x[idx], y[ahead] - y[idx])
    valid = (idx != back) & (idx != ahead) & (dist > 1e-9)
    curvature = np.where(valid, 2.0 * turn / np.where(dist > 1e-9, dist, 1.0), 0.0)
    if not closed and n > 2 * k:
        curvature[:k] = curvature[k]
        curvature[-k:] = curvature[-k - 1]
    return curvature


# ---- built-in tours ---------------------------------------------------------------------


def tour_from_description(desc: TourDescription) -> Route:
    """A closed tour: polygon corners rounded by arcs, elevation and width profiles along s."""
    corners = np.array([c.xy for c in desc.corners], dtype=float)
    radii = [c.radius_m for c in desc.corners]
    xy = _filleted_loop(corners, radii, SAMPLE_SPACING_M)
    s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(np.vstack([xy, xy[:1]]), axis=0).T))])
    length = s[-1]
    s = s[:-1]
    z = _smooth_profile(s, length, [(p.s, p.z) for p in desc.elevation])
    width = np.full(len(s), desc.default_width_m)
    for stretch in desc.narrow:
        width[(s >= stretch.s_start) & (s <= stretch.s_end)] = stretch.width_m
    pois = [Poi(p.name, p.s, tuple(p.actions)) for p in desc.pois]
    zones = [Zone(zd.kind, zd.s_start, zd.s_end, zd.full_stop) for zd in desc.zones]
    zones += [Zone("narrow", n.s_start, n.s_end) for n in desc.narrow]
    verges = [Verge(v.s_start, v.s_end, v.left, v.right) for v in desc.verges]
    return Route(
        name=desc.name,
        x=xy[:, 0],
        y=xy[:, 1],
        z=z,
        closed=True,
        width=width,
        pois=pois,
        zones=zones,
        verges=verges,
        default_verge=desc.default_verge,
        speed_limit_mps=desc.speed_limit_mps,
    )


def _filleted_loop(corners: np.ndarray, radii: list[float], spacing: float) -> np.ndarray:
    """Sample a closed polygon whose corner i is replaced by an arc of radius radii[i]."""
    n = len(corners)
    if n < 3:
        raise RouteError("a closed tour needs at least three corners")
    arcs = []  # (tangent point in, tangent point out, centre, start angle, sweep)
    for i in range(n):
        prev_pt, pt, next_pt = corners[i - 1], corners[i], corners[(i + 1) % n]
        d_in = (pt - prev_pt) / np.linalg.norm(pt - prev_pt)
        d_out = (next_pt - pt) / np.linalg.norm(next_pt - pt)
        turn = math.atan2(d_in[0] * d_out[1] - d_in[1] * d_out[0], float(np.dot(d_in, d_out)))
        r = radii[i]
        tangent = r * math.tan(abs(turn) / 2)
        room = min(np.linalg.norm(pt - prev_pt), np.linalg.norm(next_pt - pt)) / 2
        if tangent > room:
            raise RouteError(f"corner {i}: radius {r} m does not fit between its neighbours")
        t_in, t_out = pt - d_in * tangent, pt + d_out * tangent
        left = np.array([-d_in[1], d_in[0]]) * math.copysign(1.0, turn)
        centre = t_in + left * r
        start = math.atan2(t_in[1] - centre[1], t_in[0] - centre[0])
        arcs.append((t_in, t_out, centre, start, turn))
    pts = []
    for i in range(n):
        t_in, t_out, centre, start, sweep = arcs[i]
        r = radii[i]
        m = max(math.ceil(abs(sweep) * r / spacing), 1)
        for k in range(m):
            a = start + sweep * k / m
            pts.append(centre + r * np.array([math.cos(a), math.sin(a)]))
        nxt_in = arcs[(i + 1) % n][0]
        seg = nxt_in - t_out
        m = max(math.ceil(np.linalg.norm(seg) / spacing), 1)
        for k in range(m):
            pts.append(t_out + seg * k / m)
    return np.array(pts)


def _smooth_profile(s: np.ndarray, length: float, keypoints: list[tuple[float, float]]) -> np.ndarray:
    """Periodic elevation through keypoints with cosine easing, so grades change smoothly."""
    keys = sorted(keypoints)
    keys = keys + [(keys[0][0] + length, keys[0][1])]
    s_wrapped = np.where(s < keys[0][0], s + length, s)
    z = np.empty_like(s)
    for (s0, z0), (s1, z1) in zip(keys[:-1], keys[1:]):
        m = (s_wrapped >= s0) & (s_wrapped < s1)
        f = (s_wrapped[m] - s0) / (s1 - s0)
        z[m] = z0 + (z1 - z0) * (1 - np.cos(math.pi * f)) / 2
    return z


def load_route(core: CoreConfig) -> Route:
    """The run's route: a CSV given with --route, else the configured built-in tour."""
    if core.route_file:
        return Route.from_csv(core.route_file)
    return Route.from_tour(core.tour)
