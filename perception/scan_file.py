"""One LiDAR scan read from a file, for `ares perception scan FILE`.

    .bin   KITTI's Velodyne format: little-endian float32 records (x, y, z, intensity), 16 bytes
           a point, no header, no ring; x forward, y left, z up, metres, in the sensor's frame
    .pcd   Point Cloud Library files and .ply files, read by open3d's tensor reader
    .ply   (open3d.t.io.read_point_cloud), which keeps extra fields: an `intensity` and a
           `ring` field written by a sensor's driver come back with the points

Points with a NaN or an infinite coordinate (a PCD of an organised cloud marks the rays that
returned nothing so) are dropped and counted. The order of the other points is kept: it is the
order the sensor fired them in, which perception/rings.py can use.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

KITTI_RECORD_BYTES = 16  # 4 × float32
KITTI_SENSOR_HEIGHT_M = 1.73  # KITTI's Velodyne above the road (its recording platform's set-up)
OPEN3D_SUFFIXES = (".pcd", ".ply")
SUFFIXES = (".bin",) + OPEN3D_SUFFIXES


class ScanFileError(ValueError):
    """A file that gives no usable scan; the message says which and why."""


@dataclass
class Scan:
    points: np.ndarray  # (n, 3) float32, sensor frame, in the file's order
    intensity: np.ndarray | None  # (n,) as stored (KITTI: 0..1), None if the file has none
    ring: np.ndarray | None  # (n,) the file's own ring field, None if it has none
    dropped: int  # points with a NaN or infinite coordinate, left out


def read_scan(path: str | Path) -> Scan:
    path = Path(path)
    suffix = path.suffix.lower()
    if not path.exists():
        raise ScanFileError(f"{path}: no such file")
    if not path.is_file():
        raise ScanFileError(f"{path}: not a file")
    if suffix not in SUFFIXES:
        raise ScanFileError(
            f"{path}: unknown extension {path.suffix or '(none)'!r}; expected a KITTI .bin, a .pcd or a .ply"
        )
    points, intensity, ring = _read_kitti(path) if suffix == ".bin" else _read_open3d(path)
    finite = np.isfinite(points).all(axis=1)
    dropped = int(len(points) - finite.sum())
    if dropped:
        points = points[finite]
        intensity = intensity[finite] if intensity is not None else None
        ring = ring[finite] if ring is not None else None
    if len(points) == 0:
        why = f" ({dropped} with NaN or infinite coordinates dropped)" if dropped else ""
        raise ScanFileError(f"{path}: no points{why}")
    return Scan(np.ascontiguousarray(points, dtype=np.float32), intensity, ring, dropped)


def _read_kitti(path: Path):
    size = path.stat().st_size
    if size % KITTI_RECORD_BYTES:
        raise ScanFileError(
            f"{path}: {size} bytes is not a whole number of KITTI points (16 bytes each: "
            f"float32 x, y, z, intensity); truncated, or not a KITTI Velodyne file"
        )
    records = np.fromfile(path, dtype="<f4").reshape(-1, 4)
    return records[:, :3], records[:, 3].copy(), None


def _read_open3d(path: Path):
    import open3d as o3d

    # open3d reports an unreadable file as a warning on stdout and an empty cloud: silence it
    # (stdout carries the command's JSON) and say so ourselves.
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        cloud = o3d.t.io.read_point_cloud(str(path), remove_nan_points=False, remove_infinite_points=False)
    if "positions" not in cloud.point or len(cloud.point.positions) == 0:
        raise ScanFileError(f"{path}: no points (an empty cloud, or a file open3d cannot read)")
    points = cloud.point.positions.numpy().astype(np.float32, copy=False)
    fields = {
        name: cloud.point[name].numpy().reshape(len(points), -1)[:, 0] for name in cloud.point if name != "positions"
    }
    intensity = fields.get("intensity")
    ring = fields.get("ring")
    if ring is not None:
        finite_ring = np.isfinite(ring.astype(np.float64))
        ring = ring.astype(np.int64) if finite_ring.all() and (ring >= 0).all() else None
    return points, intensity, ring
