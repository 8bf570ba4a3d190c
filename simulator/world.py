"""The 3-D world the simulated LiDARs see, built from the route.

The road follows the route's centre line, elevation and width, with a crowned cross-fall and the
roughness the plant's wheels ride on (simulator/road.py: the same surface). Beside it, stretch by
stretch, the verges the tour file names (`Route.verge_at`), each a cross-section profile laid out
from the road's edge:

    grass      no step: the slope turns from the road's cross-fall to a gentle rise, with tufts
               of vegetation (the ARES paper's hardest case)
    rock_wall  a near-vertical face starting 0.1 m beyond the edge
    ravine     the ground falls away from the edge, no barrier
    kerb       a 0.12 m step, a pavement, then grass
    open       the paving goes on: no boundary (intersections, the road opening)

Trees and poles stand beside the road on the grass, kerb and open verges. Everything is one
triangle mesh with a material per triangle (its reflectivity gives the LiDAR intensity).

The road a route drives stays clear, whatever the route's shape. A cross-section is laid along
its own station's normal, and on a route imported from a recorded drive (sharp town corners, the
metre-level wiggle of fixes without RTK) those normals cross: inside a corner the verge of one
leg reaches over the road of the next, and where the smoothed centre line wiggles its curvature
spikes and the clamp that keeps an inner verge short of the centre of curvature pulls it onto
the road. So each verge vertex is judged against the whole centre line (a KD-tree of it, not its
own normal): one that lies nearer to the route than its cross-section meant is lowered to what
the nearest stretch has at that distance — the road's surface within the road, the verge's
profile beyond its edge. Trees and poles, crowns included, keep off every stretch alike
(`clearance`).

The truth of the world (`road_edges`) is for the evaluation only: no stack process sees it.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ares.core.route import Route
from simulator.road import RoadRoughness

RUNOUT_M = 30.0  # road built past an open route's end (the LiDARs' road detection needs to see it there)


def open3d():  # noqa: ANN201 (the module)
    """open3d, imported when first used: it costs ~1 s, and whatever imports this module only for
    its parameters (the run configuration, `ares run` before any process starts) never needs it."""
    import open3d as o3d

    return o3d


CROSSFALL = 0.025  # the road falls 2.5 % from its crown to each edge
VERGE_REACH_M = 10.0  # how far beyond the edge the verge mesh goes

# materials: name -> reflectivity (0..1), the intensity a return gets at normal incidence
MATERIALS = {
    "asphalt": 0.12,
    "concrete": 0.35,
    "grass": 0.28,
    "rock": 0.40,
    "soil": 0.22,
    "bark": 0.30,
    "metal": 0.60,
    "foliage": 0.25,
    "body": 0.50,
    "cover": 0.05,
}
MATERIAL_IDS = {name: i for i, name in enumerate(MATERIALS)}
REFLECTIVITY = np.array(list(MATERIALS.values()), dtype=np.float32)

# Verge cross-sections: (d, h, material of the strip that ends here, roughness of h), d metres
# beyond the road's edge, h metres above it. Eight points each, so strips of any two kinds join.
_A, _C, _G, _R, _S = "asphalt", "concrete", "grass", "rock", "soil"
VERGES: dict[str, list[tuple[float, float, str, float]]] = {
    "grass": [
        (0.3, 0.024, _G, 0.03),
        (0.7, 0.056, _G, 0.04),
        (1.2, 0.096, _G, 0.05),
        (2.0, 0.16, _G, 0.05),
        (3.0, 0.24, _G, 0.06),
        (5.0, 0.40, _G, 0.06),
        (7.5, 0.60, _G, 0.06),
        (10.0, 0.80, _G, 0.06),
    ],
    "rock_wall": [
        (0.1, 0.25, _R, 0.0),
        (0.3, 1.2, _R, 0.05),
        (0.5, 2.4, _R, 0.08),
        (0.8, 3.6, _R, 0.1),
        (1.5, 4.6, _R, 0.1),
        (3.0, 5.2, _R, 0.1),
        (6.0, 5.6, _R, 0.1),
        (10.0, 6.0, _R, 0.1),
    ],
    "ravine": [
        (0.2, -0.15, _S, 0.0),
        (0.6, -0.8, _S, 0.05),
        (1.2, -2.0, _S, 0.1),
        (2.5, -4.0, _S, 0.1),
        (4.0, -5.5, _S, 0.1),
        (6.0, -6.5, _S, 0.1),
        (8.0, -7.0, _S, 0.1),
        (10.0, -7.2, _S, 0.1),
    ],
    "kerb": [
        (0.0, 0.12, _C, 0.0),
        (0.3, 0.123, _C, 0.0),
        (1.0, 0.13, _C, 0.0),
        (2.0, 0.14, _C, 0.0),
        (2.2, 0.20, _G, 0.02),
        (4.0, 0.30, _G, 0.05),
        (7.0, 0.45, _G, 0.05),
        (10.0, 0.60, _G, 0.05),
    ],
    "open": [
        (0.5, 0.0, _A, 0.0),
        (1.0, 0.0, _A, 0.0),
        (2.0, 0.0, _A, 0.0),
        (3.0, 0.0, _A, 0.0),
        (4.5, 0.0, _A, 0.0),
        (6.0, 0.0, _A, 0.0),
        (8.0, 0.0, _A, 0.0),
        (10.0, 0.0, _A, 0.0),
    ],
}
ROAD_FRACTIONS = (-1.0, -0.5, 0.0, 0.5, 1.0)  # lateral vertices of the road, in half-widths
BOUNDARY_VERGES = ("grass", "rock_wall", "ravine", "kerb")  # "open" has no boundary
# A verge vertex this much nearer to the route than its cross-section put it has met another
# stretch (or a fold): above the route's sampling error (0.5 m samples, densified to CENTRE_STEP_M)
NEARER_TOL_M = 0.05
CENTRE_STEP_M = 0.1  # the centre line is densified to this for the distance queries
FAN_TURN_RAD = 0.035  # a heading step of 2 degrees between stations (R < 14 m at 0.5 m): a fan
NEAR_REACH_M = 4.0  # beyond the widest road's edge: far enough that a verge there cannot reach over it
OBJECT_ROAD_GAP_M = 2.0  # a trunk or pole stands at least this far beyond every stretch's edge
CROWN_ROAD_GAP_M = 0.3  # a crown hangs no nearer than this to any stretch's edge


@dataclass
class Mesh:
    vertices: np.ndarray  # (n, 3) float32
    triangles: np.ndarray  # (m, 3) uint32
    material: np.ndarray  # (m,) uint8, MATERIAL_IDS

    @staticmethod
    def join(parts: list[Mesh]) -> Mesh:
        offsets = np.cumsum([0] + [len(p.vertices) for p in parts[:-1]])
        return Mesh(
            np.vstack([p.vertices for p in parts]).astype(np.float32),
            np.vstack([p.triangles + o for p, o in zip(parts, offsets)]).astype(np.uint32),
            np.concatenate([p.material for p in parts]).astype(np.uint8),
        )


def box_mesh(centre, size, yaw: float, material: str) -> Mesh:
    """A box standing on its base: centre (x, y, z of the base's centre), size (l, w, h)."""
    legacy = open3d().geometry.TriangleMesh.create_box(*size)
    v = np.asarray(legacy.vertices) - [size[0] / 2, size[1] / 2, 0.0]
    return _placed(v, np.asarray(legacy.triangles), centre, yaw, material)


def cylinder_mesh(centre, radius: float, height: float, material: str, resolution: int = 12) -> Mesh:
    legacy = open3d().geometry.TriangleMesh.create_cylinder(radius, height, resolution=resolution, split=1)
    v = np.asarray(legacy.vertices) + [0.0, 0.0, height / 2]
    return _placed(v, np.asarray(legacy.triangles), centre, 0.0, material)


def sphere_mesh(centre, radius: float, material: str, resolution: int = 6) -> Mesh:
    legacy = open3d().geometry.TriangleMesh.create_sphere(radius, resolution=resolution)
    return _placed(np.asarray(legacy.vertices), np.asarray(legacy.triangles), centre, 0.0, material)


def _placed(v: np.ndarray, tri: np.ndarray, centre, yaw: float, material: str) -> Mesh:
    c, s = math.cos(yaw), math.sin(yaw)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return Mesh(
        (v @ rot.T + np.asarray(centre, dtype=float)).astype(np.float32),
        tri.astype(np.uint32),
        np.full(len(tri), MATERIAL_IDS[material], dtype=np.uint8),
    )


def with_runout(route: Route, length_m: float, step_m: float = 2.0) -> Route:
    """The open route with `length_m` of straight road added past its end, at its last heading,
    width and height."""
    k = np.arange(1, int(math.ceil(length_m / step_m)) + 1) * step_m
    yaw = float(route.yaw[-1])
    return dataclasses.replace(
        route,
        x=np.concatenate([route.x, route.x[-1] + k * math.cos(yaw)]),
        y=np.concatenate([route.y, route.y[-1] + k * math.sin(yaw)]),
        z=np.concatenate([route.z, np.full(len(k), route.z[-1])]),
        width=np.concatenate([route.width, np.full(len(k), route.width[-1])]),
    )


class World:
    """The static world of one route: terrain and roadside objects, and a raycasting scene."""

    def __init__(self, route: Route, roughness: RoadRoughness | None, seed: int = 7, roadside_objects: bool = True):
        # an open route's road goes on past its last point, as a real road does: the LiDARs still see road
        # when the shuttle stops at the end (arc lengths along the route are unchanged)
        self.route = route if route.closed else with_runout(route, RUNOUT_M)
        self.roughness = roughness
        self.rng = np.random.default_rng([seed, 2])
        self._centre: tuple[cKDTree, np.ndarray] | None = None  # see _centre_line
        self._kinds = [self.route.verge_at(si) for si in self.route.s]  # (left, right) verge kinds per station
        self.terrain = self._terrain()
        self.objects = self._roadside_objects() if roadside_objects else []
        self.mesh = Mesh.join([self.terrain, *self.objects])
        self.scene = open3d().t.geometry.RaycastingScene()
        self.scene.add_triangles(open3d().core.Tensor(self.mesh.vertices), open3d().core.Tensor(self.mesh.triangles))

    # ---- the road's surface ------------------------------------------------------------------
    def centre_height(self, s: np.ndarray) -> np.ndarray:
        """Height of the road's crown at arc lengths s: the elevation profile plus the roughness."""
        r = self.route
        s = np.asarray(s, dtype=float)
        z = np.interp(np.mod(s, r.length) if r.closed else s, r.s, r.z, period=r.length if r.closed else None)
        return z + (self.roughness.heights(s) if self.roughness is not None else 0.0)

    def _stations(self):
        r = self.route
        s = r.s.copy()
        heading = np.unwrap(r.yaw)
        if r.closed:  # the yaw of a sample is its segment's: average the two segments meeting there
            mid = 0.5 * (heading + np.roll(heading, 1))
            mid[0] = 0.5 * (heading[0] + heading[-1] - 2 * np.pi * round((heading[-1] - heading[0]) / (2 * np.pi)))
        else:
            mid = np.concatenate([[heading[0]], 0.5 * (heading[1:] + heading[:-1])])
        return s, mid

    def _terrain(self) -> Mesh:
        r = self.route
        s, heading = self._stations()
        n = len(s)
        normal = np.stack([-np.sin(heading), np.cos(heading)], axis=1)  # to the left
        half = r.width / 2.0
        zc = self.centre_height(s)
        # the inner side of a tight bend cannot reach further than its centre of curvature
        room = np.where(np.abs(r.curvature) > 1e-6, 0.9 / np.maximum(np.abs(r.curvature), 1e-6), np.inf)
        room_left = np.where(r.curvature > 0, room, np.inf)
        room_right = np.where(r.curvature < 0, room, np.inf)

        kinds = self._kinds
        cols_lat, cols_h, strip_mat = [], [], []  # per lateral vertex column: offset, height; per strip: material
        # left verge, outermost first
        left = [VERGES[k[0]] for k in kinds]
        for p in range(7, -1, -1):
            d = np.array([lv[p][0] for lv in left])
            h = np.array([lv[p][1] + self.rng.uniform(-1, 1) * lv[p][3] for lv in left])
            cols_lat.append(np.minimum(half + d, room_left))
            cols_h.append(-CROSSFALL * half + h)
            if p > 0:
                strip_mat.append(np.array([MATERIAL_IDS[lv[p][2]] for lv in left]))
        strip_mat.append(np.array([MATERIAL_IDS[lv[0][2]] for lv in left]))  # edge -> first verge point
        for i, f in enumerate(ROAD_FRACTIONS):
            cols_lat.append(-f * half)
            cols_h.append(-CROSSFALL * np.abs(f) * half)
            if i < len(ROAD_FRACTIONS) - 1:
                strip_mat.append(np.full(n, MATERIAL_IDS["asphalt"]))
        right = [VERGES[k[1]] for k in kinds]
        for p in range(8):
            d = np.array([rv[p][0] for rv in right])
            h = np.array([rv[p][1] + self.rng.uniform(-1, 1) * rv[p][3] for rv in right])
            cols_lat.append(-np.minimum(half + d, room_right))
            cols_h.append(-CROSSFALL * half + h)
            strip_mat.append(np.array([MATERIAL_IDS[rv[p][2]] for rv in right]))
        lat = np.stack(cols_lat, axis=1)  # (n, m) lateral offset, + left
        hgt = np.stack(cols_h, axis=1) + zc[:, None]
        m = lat.shape[1]
        xy = np.stack([r.x, r.y], axis=1)[:, None, :] + lat[..., None] * normal[:, None, :]
        verge_cols = np.ones(m, dtype=bool)
        verge_cols[8 : 8 + len(ROAD_FRACTIONS)] = False  # the road's own columns
        dist, st = self._nearest_on_centre_line(xy.reshape(-1, 2))
        dist, st = dist.reshape(n, m), st.reshape(n, m)
        hgt[:, verge_cols] = self._kept_off_the_road(
            xy[:, verge_cols], lat[:, verge_cols], hgt[:, verge_cols], zc, dist[:, verge_cols], st[:, verge_cols]
        )
        vertices = np.concatenate([xy, hgt[..., None]], axis=2).reshape(-1, 3)
        idx = np.arange(n * m).reshape(n, m)
        nxt = np.roll(idx, -1, axis=0) if r.closed else idx[1:]
        cur = idx if r.closed else idx[:-1]
        a, b = cur[:, :-1], cur[:, 1:]
        c, d = nxt[:, 1:], nxt[:, :-1]
        tris = np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3), np.stack([a, d, c], -1).reshape(-1, 3)])
        mats = np.stack(strip_mat, axis=1)[: len(cur)].reshape(-1)
        mats = np.concatenate([mats, mats])
        on_verge = np.concatenate([np.tile(verge_cols[:-1] | verge_cols[1:], len(cur))] * 2)
        keep = np.ones(len(tris), dtype=bool)
        gap = (dist - r.width[np.minimum(st, n - 1)] / 2.0).reshape(-1)  # inf where far from the road
        # a straight chord along a smooth edge stays off the road (by its sagitta, millimetres): only
        # where the route folds back near itself or turns sharply between two stations (a fan of
        # long triangles) can one cut across it
        nearer = (dist < np.abs(lat) - NEARER_TOL_M).reshape(-1)
        turning = np.abs(np.diff(np.append(heading, heading[0]) if r.closed else heading)) > FAN_TURN_RAD
        fan = np.concatenate([np.repeat(turning[: len(cur)], m - 1)] * 2)
        suspect = on_verge & (fan | nearer[tris].any(axis=1))
        keep[suspect] = ~self._over_the_road(vertices, tris[suspect], gap)
        return Mesh(vertices.astype(np.float32), tris[keep].astype(np.uint32), mats[keep].astype(np.uint8))

    def _over_the_road(self, vertices: np.ndarray, tris: np.ndarray, gap: np.ndarray) -> np.ndarray:
        """Which verge triangles reach over a stretch's road above its surface: a triangle whose
        corners all lie beyond the road can still cut across the inner corner of a sharp turn.
        Only a triangle larger than its corners' clearance (`gap`, per vertex) can; those are
        sampled."""
        r = self.route
        corners = vertices[tris]  # (k, 3, 3)
        size = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).max(axis=1)
        out = np.zeros(len(tris), dtype=bool)
        maybe = np.nonzero(gap[tris].min(axis=1) < size)[0]
        if len(maybe) == 0:
            return out
        w = np.array([(a, b, 4 - a - b) for a in range(5) for b in range(5 - a)], dtype=float) / 4.0
        samples = np.einsum("sw,kwc->ksc", w, corners[maybe])  # (k, 15, 3)
        dist, st = self._nearest_on_centre_line(samples[..., :2].reshape(-1, 2))
        st = np.minimum(st, len(r.s) - 1)
        surface = self.centre_height(r.s[st]) - CROSSFALL * dist
        inside = dist < r.width[st] / 2.0 - NEARER_TOL_M
        above = samples[..., 2].reshape(-1) > surface + NEARER_TOL_M
        out[maybe] = (inside & above).reshape(len(maybe), -1).any(axis=1)
        return out

    def _centre_line(self) -> tuple[cKDTree, np.ndarray]:
        """The whole centre line, densified, as a KD-tree, and each dense point's station."""
        if self._centre is None:
            r = self.route
            xy = np.stack([r.x, r.y], axis=1)
            nxt = np.roll(xy, -1, axis=0) if r.closed else xy[1:]
            cur = xy if r.closed else xy[:-1]
            steps = np.maximum(np.ceil(np.hypot(*(nxt - cur).T) / CENTRE_STEP_M).astype(int), 1)
            seg = np.repeat(np.arange(len(cur)), steps)
            frac = np.arange(len(seg)) - np.repeat(np.cumsum(steps) - steps, steps)
            f = (frac / steps[seg])[:, None]
            dense = cur[seg] + f * (nxt[seg] - cur[seg])
            station = np.where(f[:, 0] < 0.5, seg, (seg + 1) % len(xy))
            if not r.closed:
                dense, station = np.vstack([dense, xy[-1:]]), np.append(station, len(xy) - 1)
            self._centre = (cKDTree(dense), station)
        return self._centre

    def _nearest_on_centre_line(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distance of points (k, 2) to the whole centre line and the nearest station; inf (and
        station len(route)) beyond NEAR_REACH_M of every stretch's edge, which nothing here asks about."""
        tree, station = self._centre_line()
        reach = float(self.route.width.max()) / 2.0 + NEAR_REACH_M
        dist, j = tree.query(points, distance_upper_bound=reach)
        return dist, np.append(station, len(self.route.s))[j]

    def _kept_off_the_road(
        self, xy: np.ndarray, lat: np.ndarray, hgt: np.ndarray, zc: np.ndarray, dist: np.ndarray, st: np.ndarray
    ) -> np.ndarray:
        """Verge heights (n, k) at points xy (n, k, 2), `dist` from the centre line, nearest to
        stations `st`: lowered where a point lies nearer to the route than its own lateral offset,
        to the road's surface within the nearest stretch's half-width, to that stretch's verge
        profile beyond its edge (never raised)."""
        r = self.route
        dist, st = dist.reshape(-1), st.reshape(-1)
        own = np.abs(lat).reshape(-1)
        nearer = dist < own - NEARER_TOL_M
        if not nearer.any():
            return hgt
        pts, dist, st = xy.reshape(-1, 2)[nearer], dist[nearer], st[nearer]
        half = r.width[st] / 2.0
        heading = r.yaw[st]
        left = np.cos(heading) * (pts[:, 1] - r.y[st]) - np.sin(heading) * (pts[:, 0] - r.x[st]) > 0
        beyond = dist - half
        edge = zc[st] - CROSSFALL * half
        there = zc[st] - CROSSFALL * np.minimum(dist, half)  # on that stretch's road
        kind_there = np.array([self._kinds[i][0 if lf else 1] for i, lf in zip(st, left)])
        for kind in VERGES:
            out = (kind_there == kind) & (beyond > 0)
            there[out] = edge[out] + _profile_heights(kind, beyond[out])
        out = hgt.reshape(-1).copy()
        out[nearer] = np.minimum(out[nearer], there)
        return out.reshape(hgt.shape)

    # ---- trees and poles ---------------------------------------------------------------------
    def clearance(self, points: np.ndarray) -> np.ndarray:
        """How far points (k, 2) are from the route's road: their distance to the nearest point
        of the whole centre line less that stretch's half-width (negative: on the road)."""
        tree, station = self._centre_line()
        dist, j = tree.query(np.asarray(points, dtype=float).reshape(-1, 2))
        return dist - self.route.width[station[j]] / 2.0

    def _roadside_objects(self, spacing_m: float = 12.0) -> list[Mesh]:
        r = self.route
        out: list[Mesh] = []
        for s0 in np.arange(spacing_m / 2, r.length, spacing_m):
            for side, sign in ((0, 1.0), (1, -1.0)):
                kind = r.verge_at(s0)[side]
                if kind not in ("grass", "kerb", "open") or self.rng.random() < 0.5:
                    continue
                x, y, _, yaw = r.point_at(s0 + self.rng.uniform(-3, 3))
                half = float(r.width[r.index_at(s0)]) / 2
                d = self.rng.uniform(2.5, 7.0)
                px, py = x - sign * math.sin(yaw) * (half + d), y + sign * math.cos(yaw) * (half + d)
                gap = float(self.clearance(np.array([px, py]))[0])
                if gap < OBJECT_ROAD_GAP_M:  # on or by another stretch of road (a crossing, a sharp corner)
                    continue
                base = float(self.centre_height(s0)) - CROSSFALL * half + _profile_height(kind, d) - 0.05
                if self.rng.random() < 0.7:
                    trunk = self.rng.uniform(0.12, 0.3)
                    top = self.rng.uniform(2.5, 4.0)
                    crown = self.rng.uniform(1.2, 2.2)
                    if gap - crown < CROWN_ROAD_GAP_M:  # its crown would hang over a stretch's road
                        continue
                    out.append(cylinder_mesh((px, py, base), trunk, top + 0.05, "bark"))
                    out.append(sphere_mesh((px, py, base + top + 1.0), crown, "foliage"))
                else:
                    out.append(cylinder_mesh((px, py, base), 0.08, self.rng.uniform(4.0, 6.0), "metal", resolution=8))
        return out

    def material_of(self, geometry: np.ndarray, primitive: np.ndarray) -> np.ndarray:
        """The material of each hit triangle (the scene holds one geometry: the whole mesh)."""
        return self.mesh.material[primitive]

    # ---- truth, for the evaluation -------------------------------------------------------------
    def road_edges(self, s: float) -> tuple[float | None, float | None]:
        """Lateral offsets (left +, right −) of the road's boundaries at s, None where the verge
        is open (no boundary exists)."""
        left, right = self.route.verge_at(s)
        half = float(self.route.width[self.route.index_at(s)]) / 2
        return (half if left in BOUNDARY_VERGES else None, -half if right in BOUNDARY_VERGES else None)


def _profile_height(kind: str, d: float) -> float:
    return float(_profile_heights(kind, np.array([d]))[0])


def _profile_heights(kind: str, d: np.ndarray) -> np.ndarray:
    """The verge's height above the road's edge at distances d beyond it (its mean profile)."""
    points = VERGES[kind]
    ds = [0.0] + [p[0] for p in points]
    hs = [0.0] + [p[1] for p in points]
    return np.interp(d, ds, hs)
