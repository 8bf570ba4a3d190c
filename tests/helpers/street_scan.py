"""A small simulated 64-layer scan of a street, made in a tenth of a second: the ground tests
(tests/test_heightmap.py) and the reference bench's tests compare with Patchwork++ on it."""

from __future__ import annotations

import numpy as np


def simulated_street(sensor_height=1.73):
    """A 64-layer scan (the HDL-64E's elevations, 0.4° azimuth steps) of a street: road, 0.14 m
    pavements, façades, a parked car, a pedestrian and a 0.3 m box, seen from sensor_height above the
    origin: (points with the road at z = 0, which of them hit the obstacles)."""
    import open3d as o3d

    from ares.core.config import LIDAR_MODELS
    from simulator.world import Mesh, box_mesh

    parts = [
        box_mesh((0.0, 0.0, -1.0), (160.0, 14.0, 1.0), 0.0, "asphalt"),
        box_mesh((0.0, 8.0, -1.0), (160.0, 2.0, 1.14), 0.0, "concrete"),
        box_mesh((0.0, -8.0, -1.0), (160.0, 2.0, 1.14), 0.0, "concrete"),
        box_mesh((0.0, 9.5, -1.0), (160.0, 1.0, 16.0), 0.0, "concrete"),
        box_mesh((0.0, -9.5, -1.0), (160.0, 1.0, 16.0), 0.0, "concrete"),
    ]
    obstacles = [
        ((12.0, -4.5, 0.0), (4.2, 1.8, 1.5)),
        ((7.0, 2.5, 0.0), (0.5, 0.5, 1.75)),
        ((5.0, -1.0, 0.0), (0.4, 0.4, 0.3)),
    ]
    parts += [box_mesh(centre, size, 0.0, "metal") for centre, size in obstacles]
    mesh = Mesh.join(parts)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(mesh.vertices), o3d.core.Tensor(mesh.triangles))
    elevation = np.radians(np.array(LIDAR_MODELS["hdl64e"].elevations_deg()))
    azimuth = np.radians(np.arange(0.0, 360.0, 0.4))
    el, az = np.meshgrid(elevation, azimuth, indexing="ij")
    direction = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], -1).reshape(-1, 3)
    rays = np.hstack([np.tile([0.0, 0.0, sensor_height], (len(direction), 1)), direction]).astype(np.float32)
    hit = scene.cast_rays(o3d.core.Tensor(rays))
    distance = hit["t_hit"].numpy()
    seen = np.isfinite(distance) & (distance < 80.0) & (distance > 2.0)
    points = rays[seen, :3] + direction[seen] * distance[seen, None]
    noise = np.random.default_rng(7).normal(0.0, 0.01, len(points))[:, None] * direction[seen]
    first = sum(len(p.triangles) for p in parts[:5])  # one mesh: the obstacles are its last triangles
    obstacle = hit["primitive_ids"].numpy()[seen] >= first
    return (points + noise).astype(np.float32), obstacle
