"""`ares perception scan FILE`: one LiDAR scan from a file through the perception pipeline.

The scan is taken as the roof 64-layer sensor's (an HDL-64E, like KITTI's) on the chosen
vehicle: at the profile's roof mount in x and y, at --sensor-height above the road, and goes
through what a frame of the stack goes through (perception/lidar_perception.py: self-hit and ghost
filters, heightmap ground removal, occupancy grid, road detection). Rings come from the file
when it has them, else from the point order or the elevation (perception/rings.py). Prints one
JSON line and draws the frame from above (ares/tools/figures/scan.py).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

from .args import CliError, Command, positive_float

DEFAULT_VEHICLE = "techs4agecar"  # a car, as KITTI's is
VELODYNE_MODELS = ("VLP-16", "HDL-32E", "VLP-32C", "HDL-64E", "VLS-128")  # ares.core.wire.velodyne.MODELS


def add_parser(subparsers: argparse._SubParsersAction) -> dict[str, Command]:
    perception = subparsers.add_parser(
        "perception", help="run perception on recorded data", description="The perception pipeline outside the stack."
    )
    sub = perception.add_subparsers(dest="perception", metavar="ACTION")
    scan = sub.add_parser(
        "scan",
        help="one LiDAR scan from a file (KITTI .bin, .pcd, .ply) through filters, ground, grid and road",
        description="Run one scan through the self-hit and ghost filters, heightmap ground removal, the "
        "occupancy grid and road detection, as if the vehicle's roof 64-layer sensor had taken it. "
        "Prints one JSON line (points, stage times, ground share, cells, boundaries, offset, "
        "heading, confidence) and writes a top view. Exit 2 when the file gives no usable scan.",
    )
    scan.add_argument(
        "file",
        metavar="FILE",
        help="KITTI Velodyne .bin (float32 x, y, z, intensity), .pcd or .ply (sensor frame, x forward, "
        "y left, z up, metres), or a Velodyne capture .pcap/.pcapng (one rotation of it: --frame)",
    )
    scan.add_argument(
        "--sensor-height",
        type=positive_float,
        metavar="M",
        help="sensor above the road (default: KITTI's, 1.73, for .bin; else the profile's roof mount)",
    )
    scan.add_argument(
        "--vehicle",
        default=DEFAULT_VEHICLE,
        metavar="NAME",
        help=f"vehicle profile: a name in ares/core/config/vehicles/ or a YAML file (default: {DEFAULT_VEHICLE})",
    )
    scan.add_argument("--json", action="store_true", help="the report as one JSON line (what it prints in any case)")
    scan.add_argument("--out", metavar="PNG", help="top view to write (default: FILE's name + .scan.png, here)")
    scan.add_argument(
        "--model",
        choices=VELODYNE_MODELS,
        help="a capture's sensor model: it decides the decoding (default: the one its factory byte names)",
    )
    scan.add_argument(
        "--frame", type=int, default=0, metavar="N", help="a capture's rotation to run: N-th whole one (default 0)"
    )
    scan.add_argument("--calibration", metavar="YAML", help="a capture's unit calibration (ROS velodyne_pointcloud)")
    scan.add_argument("--port", type=int, default=2368, metavar="PORT", help="a capture's data port (default 2368)")
    scan.add_argument(
        "--fov",
        type=float,
        nargs=2,
        metavar=("START", "END"),
        help="a capture's field of view as the sensor was set (azimuths, degrees, clockwise): cut at START",
    )
    return {"perception": cmd_perception}


def cmd_perception(args: argparse.Namespace) -> int:
    from ares.core.config import ConfigError
    from perception.scan_file import ScanFileError

    if args.perception != "scan":
        raise CliError("which action? try `ares perception scan FILE`")
    try:
        report = scan_report(
            args.file,
            args.vehicle,
            args.sensor_height,
            args.out,
            capture=CaptureOptions(
                args.model, args.frame, args.calibration, args.port, tuple(args.fov) if args.fov else None
            ),
        )
    except (ScanFileError, ConfigError) as exc:
        print(f"ares perception scan: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(report))
    return 0


@dataclass(frozen=True)
class CaptureOptions:
    """How a Velodyne capture is read (`read_capture`)."""

    model: str | None = None
    frame: int = 0
    calibration: str | None = None
    port: int = 2368
    fov_deg: tuple[float, float] | None = None


def scan_report(
    file: str,
    vehicle_name: str = DEFAULT_VEHICLE,
    sensor_height_m: float | None = None,
    out: str | None = None,
    capture: CaptureOptions = CaptureOptions(),
) -> dict:
    """Run the scan in `file` through the pipeline; the JSON-ready report."""
    import numpy as np

    from ares.core.config import LIDAR_MODELS, ConfigError, LidarMount, load_vehicle
    from ares.tools.figures.scan import write_scan_png
    from perception.lidar_perception import LidarPipeline, SensorSweep
    from perception.occupancy import FREE, OCCUPIED, UNKNOWN
    from perception.rings import recover_rings
    from perception.scan_file import CAPTURE_SUFFIXES, KITTI_SENSOR_HEIGHT_M, read_capture, read_scan

    clock = time.perf_counter()

    def lap() -> float:
        nonlocal clock
        now, start = time.perf_counter(), clock
        clock = now
        return round((now - start) * 1e3, 3)

    path = Path(file)
    summary = None
    if path.suffix.lower() in CAPTURE_SUFFIXES and path.is_file():
        scan, summary = read_capture(
            path, capture.model, capture.frame, capture.calibration, capture.port, capture.fov_deg
        )
    else:
        scan = read_scan(path)
    read_ms = lap()
    vehicle = load_vehicle(vehicle_name)
    roof = vehicle.lidars.get("roof")
    if roof is None:
        raise ConfigError(f"vehicle {vehicle.name} has no roof LiDAR to take the scan's place")
    if sensor_height_m is None:
        sensor_height_m = KITTI_SENSOR_HEIGHT_M if path.suffix.lower() == ".bin" else roof.xyz_m[2]
    # the sensor class only sets the closest range kept: a 16- or 32-layer puck's, or a 64-layer's
    sensor_class = "vlp16" if summary is not None and summary.model in ("VLP-16", "HDL-32E", "VLP-32C") else "hdl64e"
    mount = LidarMount(model=sensor_class, xyz_m=(roof.xyz_m[0], roof.xyz_m[1], sensor_height_m), rpy_deg=roof.rpy_deg)
    if summary is not None:
        ring, ring_method = scan.ring, "decoder"
    elif scan.ring is not None:
        ring, ring_method = scan.ring, "file"
    else:
        ring, ring_method = recover_rings(scan.points, LIDAR_MODELS["hdl64e"])
    rings_ms = lap()
    pipeline = LidarPipeline(vehicle, mounts={"roof": mount})
    setup_ms = lap()
    frame = pipeline.process([SensorSweep("roof", scan.points, ring)])
    lap()
    road = frame.road
    picture = Path(out) if out else Path.cwd() / f"{path.stem}.scan.png"
    title = (
        f"{path.name}: {len(scan.points)} points, sensor {sensor_height_m:g} m up on {vehicle.name}; "
        f"road {'found' if road.found else 'not found'} (confidence {road.confidence:.2f})"
    )
    write_scan_png(
        picture, frame, pipeline.mapper.grid, pipeline.body, pipeline.origins[:, :2], pipeline.params.road, title
    )
    picture_ms = lap()

    cells = np.bincount(frame.grid.ravel(), minlength=256)
    return {
        "file": str(path),
        "points": len(scan.points),
        "nan_points_dropped": scan.dropped,
        "rings": {"method": ring_method, "count": int(len(np.unique(ring)))},
        "vehicle": vehicle.name,
        "sensor_xyz_m": list(mount.xyz_m),
        "points_after_filters": len(frame.points),
        "removed": frame.removed,
        "stage_ms": frame.stage_ms,
        "read_ms": read_ms,
        "rings_ms": rings_ms,
        "setup_ms": setup_ms,
        "picture_ms": picture_ms,
        "ground_share": round(float(frame.ground.mean()), 4) if len(frame.ground) else 0.0,
        "cells": {"occupied": int(cells[OCCUPIED]), "free": int(cells[FREE]), "unknown": int(cells[UNKNOWN])},
        "boundaries": {
            "left": road.model.left is not None,
            "right": road.model.right is not None,
            "left_points": len(road.left_points),
            "right_points": len(road.right_points),
        },
        "road_found": bool(road.found),
        "lateral_offset_m": _number(road.lateral_offset_m),
        "heading_rad": _number(road.heading_rad),
        "width_m": _number(road.width_m),
        "confidence": round(float(road.confidence), 4),
        "picture": str(picture),
    } | ({"capture": _capture_figures(summary)} if summary is not None else {})


def _capture_figures(summary) -> dict:
    import numpy as np

    figures = asdict(summary)
    per_rotation = figures.pop("points_per_rotation")
    figures["points_per_rotation"] = {
        "median": int(np.median(per_rotation)),
        "min": int(min(per_rotation)),
        "max": int(max(per_rotation)),
        "each": per_rotation,
    }
    return figures


def _number(value: float) -> float | None:
    """JSON has no NaN: an unknown value is null."""
    return round(float(value), 4) if math.isfinite(value) else None
