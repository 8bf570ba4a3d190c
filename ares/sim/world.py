"""The 3-D world the simulated LiDARs see, built from the route.

The road follows the route's centre line, elevation and width, with a crowned cross-fall and the
roughness the plant's wheels ride on (ares/sim/road.py: the same surface). Beside it, stretch by
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

The truth of the world (`road_edges`) is for the evaluation only: no stack process sees it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ares.core.route import Route
from ares.sim.road import RoadRoughness


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


class World:
    """The static world of one route: terrain and roadside objects, and a raycasting scene."""

    def __init__(self, route: Route, roughness: RoadRoughness | None, seed: int = 7, roadside_objects: bool = True):
        self.route = route
        self.roughness = roughness
        self.rng = np.random.default_rng([seed, 2])
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

        kinds = [r.verge_at(si) for si in s]
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
        vertices = np.concatenate([xy, hgt[..., None]], axis=2).reshape(-1, 3)
        idx = np.arange(n * m).reshape(n, m)
        nxt = np.roll(idx, -1, axis=0) if r.closed else idx[1:]
        cur = idx if r.closed else idx[:-1]
        a, b = cur[:, :-1], cur[:, 1:]
        c, d = nxt[:, 1:], nxt[:, :-1]
        tris = np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3), np.stack([a, d, c], -1).reshape(-1, 3)])
        mats = np.stack(strip_mat, axis=1)[: len(cur)].reshape(-1)
        return Mesh(vertices.astype(np.float32), tris.astype(np.uint32), np.concatenate([mats, mats]).astype(np.uint8))

    # ---- trees and poles ---------------------------------------------------------------------
    def _roadside_objects(self, spacing_m: float = 12.0) -> list[Mesh]:
        r = self.route
        tree = cKDTree(np.stack([r.x, r.y], axis=1))
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
                near, _ = tree.query([px, py])
                if near < half + 2.0:  # on or by another stretch of road (the crossing, a hairpin)
                    continue
                base = float(self.centre_height(s0)) - CROSSFALL * half + _profile_height(kind, d) - 0.05
                if self.rng.random() < 0.7:
                    trunk = self.rng.uniform(0.12, 0.3)
                    top = self.rng.uniform(2.5, 4.0)
                    out.append(cylinder_mesh((px, py, base), trunk, top + 0.05, "bark"))
                    out.append(sphere_mesh((px, py, base + top + 1.0), self.rng.uniform(1.2, 2.2), "foliage"))
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
    points = VERGES[kind]
    ds = [0.0] + [p[0] for p in points]
    hs = [0.0] + [p[1] for p in points]
    return float(np.interp(d, ds, hs))
