"""Simulated spinning LiDARs: rays cast into the world with open3d.

Each sensor fires every laser of its datasheet (config.LIDAR_MODELS) at every azimuth step of a
10 Hz revolution (every `azimuth_decimation`-th step, so tests can run light), from where its
mount (vehicle profile, `lidars`) puts it on the vehicle's true pose. A return is the nearest of
the world, the moving obstacles and the shuttle's own body; what a real sensor adds is added:

- self-hits: rays that strike the body or another sensor's housing return from them, as the
  lower rings did on the ARES shuttle (§3.5.1);
- range noise (datasheet sigma), returns nearer than the minimum range discarded, and a range
  that shrinks on dark surfaces (reach = max range × sqrt(reflectivity / 0.8): about 50 m on
  asphalt, the HDL-64E's datasheet figure);
- random dropouts, intensity from the material's reflectivity and the angle of incidence;
- ghosts: a few spurious points in the near field in front of the sensor (interference, fog);
- a blocked sensor (an opaque cover, on command): every ray stops at the cover, nearer than the
  minimum range, so the point count falls to about zero, as the paper observed.

Points are in the sensor's frame (x forward, y left, z up); rings numbered from the lowest laser.
A point lies on the sensor's sampling grid (ares/core/cloud_grid.py), as a real sensor reports it:
its azimuth in 0.01° steps (a turn's firing offset drawn in those steps), its range in 2 mm, its
intensity a byte; so a recording stores it as those integers and gives it back exactly. Given
`directions` (a packet format's rays), the points are left as cast: the packets quantise them.
Motion during the 100 ms sweep is not modelled: each sweep is taken from one pose.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ares.core import cloud_grid
from ares.core.config import LidarMount, Params, VehicleProfile, param
from simulator.world import MATERIAL_IDS, REFLECTIVITY, Mesh, box_mesh, cylinder_mesh, open3d

FULL_REACH_REFLECTIVITY = 0.8
COVER_RANGE_M = 0.03


class LidarSimParams(Params):
    """The simulated LiDARs (simulator/lidar.py)."""

    rate_hz: float = param(10.0, "revolutions per second", unit="Hz", gt=0)
    azimuth_decimation: int = param(
        1, "fire every n-th azimuth step of the datasheet (1 = full resolution; tests run lighter)", ge=1
    )
    dropout: float = param(0.005, "share of returns lost at random", ge=0, lt=1)
    intensity_sigma: float = param(0.05, "relative noise on the intensity", ge=0)
    ghosts_per_sweep: float = param(8.0, "mean spurious near-field points per sweep and sensor", ge=0)
    ghost_range_m: tuple[float, float] = param((0.6, 3.0), "ghosts appear between these ranges", unit="m")
    ghost_half_angle_deg: float = param(
        60.0, "... within this angle either side of the sensor's front", unit="deg", gt=0, le=180
    )
    roadside_objects: bool = param(True, "trees and poles beside the road")
    raycast_threads: int = param(
        1,
        "open3d threads per cast (0: all cores); in a run the other processes need "
        "the second core more than the caster does (one thread: 30 ms of CPU a frame of three sensors, "
        "ares bench perception; all cores cost more CPU for less wall time)",
        ge=0,
    )
    seed: int = param(11, "seed of the LiDARs' random streams (noise, dropouts, ghosts, roadside objects)", ge=0)


def rotation(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """R = Rz(yaw) Ry(pitch) Rx(roll): a frame rotated by these angles, REP-103 signs."""
    cr, sr, cp, sp, cy, sy = (
        math.cos(roll),
        math.sin(roll),
        math.cos(pitch),
        math.sin(pitch),
        math.cos(yaw),
        math.sin(yaw),
    )
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def rotate_into(out: np.ndarray, columns: np.ndarray, matrix: np.ndarray, scratch: np.ndarray) -> None:
    """out[i] = Σ_j matrix[i, j] columns[j]: (3, n) column vectors turned, in contiguous rows (a
    BLAS product of (n, 3) by (3, 3) costs more in threads and calls than its 9 multiply-adds per
    row, and strided columns cost twice contiguous ones). scratch: (n,) of out's dtype."""
    for i in range(3):
        np.multiply(columns[0], matrix[i, 0], out=out[i])
        np.multiply(columns[1], matrix[i, 1], out=scratch)
        out[i] += scratch
        np.multiply(columns[2], matrix[i, 2], out=scratch)
        out[i] += scratch


def mount_pose(mount: LidarMount) -> tuple[np.ndarray, np.ndarray]:
    """(rotation, translation) of a sensor in the vehicle frame. Pitch positive is nose down:
    REP-103's rotation about y with y to the left."""
    roll, pitch, yaw = (math.radians(a) for a in mount.rpy_deg)
    return rotation(roll, pitch, yaw), np.asarray(mount.xyz_m, dtype=float)


def housing(mount: LidarMount) -> Mesh:
    """The sensor's own can, centred on its optical centre."""
    radius, height = (0.10, 0.28) if mount.model == "hdl64e" else (0.052, 0.072)
    x, y, z = mount.xyz_m
    return cylinder_mesh((x, y, z - height / 2), radius, height, "metal")


def body_parts(vehicle: VehicleProfile) -> list[Mesh]:
    """The shuttle's body as the LiDARs see it, in the vehicle frame: a box of its shape (rear axle
    at x = 0) and, for a roof sensor, its mast."""
    height = vehicle.height_m or 2.0
    clearance = vehicle.ground_clearance_m
    parts = [
        box_mesh(
            (vehicle.wheelbase_m / 2, 0.0, clearance),
            (vehicle.length_m, vehicle.width_m, height - clearance),
            0.0,
            "body",
        )
    ]
    roof = vehicle.lidars.get("roof")
    if roof is not None and roof.xyz_m[2] - 0.14 > height:
        parts.append(
            cylinder_mesh((roof.xyz_m[0], roof.xyz_m[1], height), 0.03, roof.xyz_m[2] - 0.14 - height, "metal")
        )
    return parts


@dataclass
class Sweep:
    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    intensity: np.ndarray
    ring: np.ndarray
    slot: np.ndarray | None = None  # with given rays: each point's ray index (-1: a ghost)

    @property
    def size(self) -> int:
        return len(self.x)


class SimulatedLidar:
    """One sensor on the vehicle. By default it fires the datasheet's lasers at every azimuth
    step, turned by a random fraction of a step each sweep; given `directions` (unit vectors in
    the sensor frame) and their `rings`, it casts exactly those rays every sweep (the firing
    pattern of a packet format, simulator/velodyne_wire.py) and tells each point's ray (Sweep.slot)."""

    def __init__(
        self,
        name: str,
        mount: LidarMount,
        vehicle: VehicleProfile,
        params: LidarSimParams,
        rng: np.random.Generator,
        directions: np.ndarray | None = None,
        rings: np.ndarray | None = None,
    ):
        self.name = name
        self.mount = mount
        self.sheet = mount.datasheet()
        self.params = params
        self.rng = rng
        self.rotation, self.position = mount_pose(mount)
        elevation = np.radians(self.sheet.elevations_deg())
        self.step = math.radians(self.sheet.azimuth_step_deg) * params.azimuth_decimation
        azimuth = np.arange(0.0, 2 * math.pi - 1e-9, self.step)
        el, az = np.meshgrid(elevation, azimuth, indexing="ij")  # ring-major, like a real packet order
        self.ring = np.repeat(np.arange(len(elevation), dtype=np.uint8), len(azimuth))
        self.elevation = el.ravel()
        self.azimuth = az.ravel()
        ce = np.cos(self.elevation)
        self.dirs0 = np.stack(
            [ce * np.cos(self.azimuth), ce * np.sin(self.azimuth), np.sin(self.elevation)], axis=1
        ).astype(np.float32)
        self.fixed_rays = directions is not None
        if directions is not None:
            if rings is None or len(rings) != len(directions):
                raise ValueError("given directions need a ring each")
            self.dirs0 = np.ascontiguousarray(directions, dtype=np.float32).reshape(-1, 3)
            self.ring = np.asarray(rings, dtype=np.uint8)
            self.elevation = np.arcsin(np.clip(self.dirs0[:, 2], -1.0, 1.0)).astype(np.float64)
            self.azimuth = np.arctan2(self.dirs0[:, 1], self.dirs0[:, 0]).astype(np.float64) % (2 * math.pi)
        self.grid = cloud_grid.SensorGrid(tuple(self.sheet.elevations_deg()))
        self.azimuth_steps = cloud_grid.azimuth_steps(self.azimuth).astype(np.int64)
        self.blocked = False
        others = [housing(m) for n, m in vehicle.lidars.items() if n != name]
        body = Mesh.join(body_parts(vehicle) + others)
        body_scene = open3d().t.geometry.RaycastingScene()
        body_scene.add_triangles(open3d().core.Tensor(body.vertices), open3d().core.Tensor(body.triangles))
        # The body does not move relative to the sensor: which rays it stops, and where, is worked
        # out once (the few hundredths of a degree a turn's firing varies are far below its detail).
        rays = np.empty((len(self.dirs0), 6), dtype=np.float32)
        rays[:, :3] = self.position
        rays[:, 3:] = self.dirs0 @ self.rotation.T.astype(np.float32)
        own = body_scene.cast_rays(open3d().core.Tensor.from_numpy(rays))
        t_body = own["t_hit"].numpy()
        stopped = np.isfinite(t_body)
        self.leaving = np.flatnonzero(~stopped)  # the rays that reach the world
        self.leaving_dirs = np.ascontiguousarray(self.dirs0[self.leaving])
        self.leaving_ring = self.ring[self.leaving]
        self.body_index = np.flatnonzero(stopped)
        self.body_t = t_body[stopped]
        self.body_dirs = self.dirs0[stopped]
        self.body_ring = self.ring[stopped]
        self.body_incidence = np.abs(
            np.einsum("ij,ij->i", own["primitive_normals"].numpy()[stopped], rays[stopped, 3:])
        )
        # Per sweep, everything is read column by column (contiguous: the (n, 3) rows' columns are
        # strided) and by index into these, the world's rays first, then the body's.
        self.leaving_columns = np.ascontiguousarray(self.leaving_dirs.T)
        self.all_columns = np.ascontiguousarray(np.concatenate([self.leaving_dirs, self.body_dirs]).T)
        self.all_ring = np.concatenate([self.leaving_ring, self.body_ring])
        self.all_index = np.concatenate([self.leaving, self.body_index])
        self.ghost_elevation = np.radians(self.sheet.elevations_deg())
        # Reused every sweep (nothing returned points into them): the rays cast, their world
        # directions in contiguous rows, and a row of scratch.
        self.rays = np.empty((len(self.leaving), 6), dtype=np.float32)
        self.world_directions = np.empty((3, len(self.leaving)), dtype=np.float32)
        self.scratch = np.empty(len(self.leaving), dtype=np.float32)
        # reach by material: max range × sqrt(reflectivity / 0.8), at most the max range
        self.reach = self.sheet.max_range_m * np.sqrt(np.minimum(REFLECTIVITY / FULL_REACH_REFLECTIVITY, 1.0))
        # what of a body return does not change from sweep to sweep: whether it is within reach, and
        # its intensity before the noise
        body_material = MATERIAL_IDS["body"]
        self.body_within_reach = self.body_t <= self.reach[body_material]
        self.body_brightness = REFLECTIVITY[body_material] * np.maximum(self.body_incidence, 0.05)

    @property
    def rays_per_sweep(self) -> int:
        return len(self.azimuth)

    def directions(self, azimuth_offset: float = 0.0) -> np.ndarray:
        """Unit vectors of every ray in the sensor frame, the revolution turned by an offset."""
        return (self.dirs0 @ rotation(0.0, 0.0, azimuth_offset).T.astype(np.float32)).astype(np.float32)

    def sweep(
        self,
        world_scene,
        vehicle_rotation: np.ndarray,
        vehicle_position: np.ndarray,
        obstacles_scene=None,
        material_of=None,
    ) -> Sweep:
        """One revolution from the vehicle's pose. `material_of(geometry_ids, primitive_ids)` gives
        each world hit's material (World.material_of)."""
        if self.blocked:
            return self._empty()
        rng = self.rng
        # firing azimuths vary a little per turn, in the sensor's azimuth steps
        spin_steps = int(cloud_grid.azimuth_steps(rng.uniform(0.0, self.step)))
        spin = rotation(0.0, 0.0, spin_steps * cloud_grid.AZIMUTH_UNIT_RAD)
        if self.fixed_rays:  # the rays are a packet format's: exactly those (the draw keeps the stream)
            spin = np.eye(3)
        to_world = (vehicle_rotation @ self.rotation @ spin).astype(np.float32)
        rays, directions = self.rays, self.world_directions
        origin = vehicle_rotation @ self.position + vehicle_position
        rotate_into(directions, self.leaving_columns, to_world, self.scratch)
        for i in range(3):  # a column at a time: 3x faster than broadcasting a row over (n, 3)
            rays[:, i] = origin[i]
            rays[:, 3 + i] = directions[i]
        hit = world_scene.cast_rays(open3d().core.Tensor.from_numpy(rays), nthreads=self.params.raycast_threads)
        t = hit["t_hit"].numpy()
        normal = hit["primitive_normals"].numpy()
        geometry, primitive = hit["geometry_ids"].numpy(), hit["primitive_ids"].numpy()
        if obstacles_scene is None:
            world = np.flatnonzero(np.isfinite(t))
            world_material = material_of(np.take(geometry, world), np.take(primitive, world))
        else:
            material = np.full(len(t), MATERIAL_IDS["asphalt"], dtype=np.uint8)
            found = np.flatnonzero(np.isfinite(t))
            material[found] = material_of(np.take(geometry, found), np.take(primitive, found))
            near = obstacles_scene.cast_rays(
                open3d().core.Tensor.from_numpy(rays), nthreads=self.params.raycast_threads
            )
            t_obs = near["t_hit"].numpy()
            closer = t_obs < t
            t = np.where(closer, t_obs, t)
            normal = np.where(closer[:, None], near["primitive_normals"].numpy(), normal)
            material[closer] = MATERIAL_IDS["metal"]
            world = np.flatnonzero(np.isfinite(t))
            world_material = np.take(material, world)

        # the world's returns, then the body's (the same every sweep); only hits are worth the noise.
        # Each array below is the world's part then the body's, handled apart where the body's is fixed.
        hits, m = len(world), len(world) + len(self.body_t)
        t_world = np.take(t, world)
        # the draws in their order: intensity noise, range noise, dropouts (each sensor's stream)
        intensity_noise = rng.standard_normal(m, dtype=np.float32)
        r = rng.standard_normal(m, dtype=np.float32)  # r = t + σ noise, in place (the same float32 sums)
        r *= self.sheet.range_sigma_m
        r[:hits] += t_world
        r[hits:] += self.body_t
        returned = r >= self.sheet.min_range_m
        returned[:hits] &= t_world <= np.take(self.reach, world_material)
        returned[hits:] &= self.body_within_reach
        returned &= rng.random(m, dtype=np.float32) >= self.params.dropout
        keep = np.flatnonzero(returned)
        kept_world = int(np.searchsorted(keep, hits))  # keep is sorted: the world's returns come first
        source = keep.copy()  # into the rays: the world's, then the body's
        np.take(world, keep[:kept_world], out=source[:kept_world])
        source[kept_world:] += len(self.leaving) - hits
        kept_body = keep[kept_world:] - hits
        intensity = np.empty(len(keep), dtype=np.float32)
        cosine = np.multiply(normal[:, 0], directions[0])  # over every ray: cheaper than gathering the hits' first
        cosine += np.multiply(normal[:, 1], directions[1], out=self.scratch)
        cosine += np.multiply(normal[:, 2], directions[2], out=self.scratch)
        incidence = np.abs(np.take(cosine, source[:kept_world]))
        np.take(REFLECTIVITY, np.take(world_material, keep[:kept_world]), out=intensity[:kept_world])
        intensity[:kept_world] *= np.maximum(incidence, 0.05, out=incidence)
        np.take(self.body_brightness, kept_body, out=intensity[kept_world:])
        noise = np.take(intensity_noise, keep)
        noise *= self.params.intensity_sigma
        noise += 1.0
        intensity *= noise
        ghosts = self._ghosts()
        if not self.fixed_rays:
            return self._on_grid(source, np.take(r, keep), intensity, spin_steps, ghosts)
        kept, total = len(keep), len(keep) + len(ghosts[0])
        columns = [np.empty(total, dtype=np.float32) for _ in range(3)]
        d0, d1, d2 = (np.take(self.all_columns[i], source) for i in range(3))
        spin32, range_kept = spin.astype(np.float32), np.take(r, keep)
        product = np.empty(kept, dtype=np.float32)
        for i, out in enumerate(columns):  # the direction turned by the spin, times the range
            np.multiply(d0, spin32[i, 0], out=out[:kept])
            out[:kept] += np.multiply(d1, spin32[i, 1], out=product)
            out[:kept] += np.multiply(d2, spin32[i, 2], out=product)
            out[:kept] *= range_kept
            out[kept:] = ghosts[i]
        out_intensity = np.empty(total, dtype=np.float32)
        np.clip(intensity, 0.0, 1.0, out=out_intensity[:kept])
        out_intensity[kept:] = ghosts[3]
        ring = np.empty(total, dtype=np.uint8)
        np.take(self.all_ring, source, out=ring[:kept])
        ring[kept:] = ghosts[4]
        slot = None
        if self.fixed_rays:
            slot = np.concatenate([np.take(self.all_index, source), np.full(len(ghosts[0]), -1)])
        return Sweep(x=columns[0], y=columns[1], z=columns[2], intensity=out_intensity, ring=ring, slot=slot)

    def _on_grid(self, source, range_kept, intensity, spin_steps: int, ghosts) -> Sweep:
        """The returns (rays `source`, their ranges and intensities) and the ghosts as the sensor
        reports them: on its grid of azimuth steps, range steps and intensity bytes."""
        gx, gy, gz, gi, gring = ghosts
        ring = np.concatenate([np.take(self.all_ring, source), gring.astype(np.uint8)])
        azimuth = np.concatenate(
            [
                np.take(self.azimuth_steps, np.take(self.all_index, source)) + spin_steps,
                cloud_grid.azimuth_steps(np.arctan2(gy, gx)).astype(np.int64),
            ]
        )
        azimuth = np.mod(azimuth, cloud_grid.AZIMUTH_STEPS).astype(np.uint16)
        ranges = np.concatenate([range_kept, np.sqrt(gx * gx + gy * gy + gz * gz)])
        x, y, z = cloud_grid.place(self.grid, ring, azimuth, cloud_grid.range_steps(ranges))
        brightness = np.concatenate([np.clip(intensity, 0.0, 1.0), gi])
        out_intensity = cloud_grid.intensity_of(cloud_grid.intensity_steps(brightness))
        return Sweep(x=x, y=y, z=z, intensity=out_intensity, ring=ring)

    def _ghosts(self):
        p, rng = self.params, self.rng
        k = int(rng.poisson(p.ghosts_per_sweep))
        elevation = self.ghost_elevation
        ring = rng.integers(0, len(elevation), k)
        az = rng.uniform(-1.0, 1.0, k) * math.radians(p.ghost_half_angle_deg)
        r = rng.uniform(max(p.ghost_range_m[0], self.sheet.min_range_m), p.ghost_range_m[1], k)
        ghost_elevation = elevation[ring]
        across = r * np.cos(ghost_elevation)
        return (across * np.cos(az), across * np.sin(az), r * np.sin(ghost_elevation), rng.uniform(0.0, 0.1, k), ring)

    def _empty(self) -> Sweep:
        # behind the cover every ray returns at a few centimetres, below the minimum range
        none = np.zeros(0, dtype=np.float32)
        return Sweep(none, none, none, none, np.zeros(0, dtype=np.uint8))


def vehicle_pose(x: float, y: float, z: float, yaw: float, pitch: float, roll: float = 0.0):
    """(rotation, position) of the vehicle frame in the world."""
    return rotation(roll, pitch, yaw), np.array([x, y, z])
