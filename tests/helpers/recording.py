"""What the recording tests feed a recorder: a pose along a straight line and a sweep as a
spinning sensor reports it, on the roof LiDAR's grid (ares/core/cloud_grid.py)."""

from __future__ import annotations

import numpy as np

from ares.core import cloud_grid, schema
from ares.core.config import load_vehicle
from ares.core.messages import PointCloud, Pose

ROOF_GRID = cloud_grid.SensorGrid(tuple(load_vehicle("ares_shuttle").lidars["roof"].datasheet().elevations_deg()))


def pose(t: float) -> Pose:
    return Pose(
        t=t, x=t, y=0.0, z=0.0, yaw=0.0, v=2.0, yaw_rate=0.0, cov_xx=0.01, cov_xy=0.0, cov_yy=0.01,
        var_yaw=1e-4, var_v=0.01, position_std_m=0.1, rtk=True, gnss_age_s=0.1,
    )  # fmt: skip


def on_grid_cloud(t: float, n: int = 2000, grid: cloud_grid.SensorGrid = ROOF_GRID) -> PointCloud:
    """A sweep as a sensor reports it: rings in order, azimuths rising, ranges and intensity bytes."""
    rng = np.random.default_rng(int(t * 100))
    ring = np.tile(np.arange(grid.rings, dtype=np.uint8), n // grid.rings + 1)[:n]
    azimuth = np.sort(rng.integers(0, cloud_grid.AZIMUTH_STEPS, n)).astype(np.uint16)
    range_ = rng.integers(300, 40000, n).astype(np.uint16)
    x, y, z = cloud_grid.place(grid, ring, azimuth, range_)
    intensity = cloud_grid.intensity_of(rng.integers(0, 256, n).astype(np.uint8))
    return PointCloud(t=t, sensor="roof", frame="lidar/roof", x=x, y=y, z=z, intensity=intensity, ring=ring)


def payload_of(msg: PointCloud) -> bytes:
    return bytes(schema.encode(msg))
