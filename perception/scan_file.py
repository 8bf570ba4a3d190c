"""One LiDAR scan read from a file, for `ares perception scan FILE`.

    .bin   KITTI's Velodyne format: little-endian float32 records (x, y, z, intensity), 16 bytes
           a point, no header, no ring; x forward, y left, z up, metres, in the sensor's frame
    .pcd   Point Cloud Library files and .ply files, read by open3d's tensor reader
    .ply   (open3d.t.io.read_point_cloud), which keeps extra fields: an `intensity` and a
           `ring` field written by a sensor's driver come back with the points

    .pcap  a packet capture of a Velodyne (tcpdump's or Wireshark's, classic or pcapng): its data
    .pcapng packets cut into rotations and decoded by the sensor's model (ares/core/wire/velodyne.py,
           as the LiDAR driver does); one rotation, `frame`, is the scan, with its rings
           (`read_capture`; `capture_summary` tells the rotations, points and rate of the file)

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
CAPTURE_SUFFIXES = (".pcap", ".pcapng")
SUFFIXES = (".bin",) + OPEN3D_SUFFIXES + CAPTURE_SUFFIXES


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
            f"{path}: unknown extension {path.suffix or '(none)'!r}; expected a KITTI .bin, a .pcd, a .ply "
            "or a Velodyne capture (.pcap, .pcapng)"
        )
    if suffix in CAPTURE_SUFFIXES:
        return read_capture(path)[0]
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


@dataclass
class CaptureSummary:
    """What a Velodyne capture held, as the LiDAR driver would have cut it."""

    model: str
    model_from: str  # "given", or "factory byte" when it was read from the packets
    packets: int  # the datagrams to the data port
    rotations: int  # whole rotations (not truncated: start and end of the file are usually cut)
    truncated: int
    points_per_rotation: list[int]  # of the whole ones, in order
    points_total: int  # every return decoded, the truncated rotations' too
    rate_hz: float | None  # median over the whole rotations
    return_modes: list[str]
    factory_bytes: dict[str, int]  # factory bytes that disagree with the model: "0x21" -> packets
    malformed: dict[str, int]
    lost: int
    skipped_frames: dict[str, int]  # capture frames that were no UDP to the port, by cause
    frame: int  # the rotation the scan is (its index among the whole ones)


def read_capture(
    path: str | Path,
    model: str | None = None,
    frame: int = 0,
    calibration: str | None = None,
    port: int = 2368,
    fov_deg: tuple[float, float] | None = None,
) -> tuple[Scan, CaptureSummary]:
    """Rotation `frame` (0: the first whole one) of a Velodyne capture, and the capture's summary.
    `model` None: the model the first packet's factory byte names (an HDL-64E writes none: give it)."""
    from ares.core.wire.pcap import CaptureCounts, udp_datagrams
    from ares.core.wire.velodyne import MODELS, PRODUCT_NAMES, RotationAssembler, load_calibration

    path = Path(path)
    counts = CaptureCounts()
    try:
        datagrams = [d for d in udp_datagrams(path, counts) if d.port == port]
    except ValueError as exc:
        raise ScanFileError(str(exc)) from None
    if not datagrams:
        raise ScanFileError(f"{path}: no UDP datagram to port {port} (a Velodyne's data port; --port to change)")
    model_from = "given"
    if model is None:
        named = PRODUCT_NAMES.get(datagrams[0].payload[-1]) if len(datagrams[0].payload) == 1206 else None
        if named not in MODELS:
            raise ScanFileError(f"{path}: its packets do not say their model: give it (--model {'|'.join(MODELS)})")
        model, model_from = named, "factory byte"
    try:
        cal = load_calibration(model, calibration)
    except ValueError as exc:
        raise ScanFileError(str(exc)) from None
    # the rate only bounds the cut of a stalled azimuth: the slowest a Velodyne turns (5 Hz)
    assembler = RotationAssembler(cal, rate_hz=5.0, fov_deg=fov_deg)
    # only the rotation asked for keeps its points: a long capture's others are counted, not held
    sizes: list[int] = []
    rates: list[float] = []
    modes: set[str] = set()
    total = 0
    chosen = None
    for datagram in [*datagrams, None]:
        done = assembler.flush() if datagram is None else assembler.add(datagram.payload, datagram.time)
        for rotation in done:
            total += rotation.points.size
            if rotation.truncated:
                continue
            if len(sizes) == frame:
                chosen = rotation.points
            sizes.append(rotation.points.size)
            modes.add(rotation.return_mode)
            if rotation.rate_hz:
                rates.append(rotation.rate_hz)
    summary = CaptureSummary(
        model=model,
        model_from=model_from,
        packets=len(datagrams),
        rotations=len(sizes),
        truncated=assembler.truncated,
        points_per_rotation=sizes,
        points_total=total,
        rate_hz=round(float(np.median(rates)), 3) if rates else None,
        return_modes=sorted(modes),
        factory_bytes={f"0x{b:02x}": n for b, n in assembler.factory_bytes.items()},
        malformed=dict(assembler.malformed),
        lost=assembler.lost,
        skipped_frames=dict(counts.skipped),
        frame=frame,
    )
    if not sizes:
        raise ScanFileError(
            f"{path}: no whole rotation in {len(datagrams)} packets ({summary.malformed or 'none refused'})"
        )
    if chosen is None:
        raise ScanFileError(
            f"{path}: frame {frame} asked, the capture has {len(sizes)} whole rotations (0..{len(sizes) - 1})"
        )
    points = chosen
    xyz = np.stack([points.x, points.y, points.z], axis=1).astype(np.float32)
    scan = Scan(np.ascontiguousarray(xyz), points.intensity, points.ring.astype(np.int64), 0)
    return scan, summary
