"""The LiDAR extrinsic-calibration experiment (ARES §3.4.1): the shuttle in a simulated
warehouse, its three sensors scanning from their true mounts, calibrated from a wrong first guess
by perception/extrinsic_calibration.py, and the result compared with the truth.

    ares calibrate lidars [--vehicle NAME] [--seed S] [--offset-m 0.10] [--offset-deg 3]
                          [--write PATH] [--json]

The truth is the vehicle profile's `lidars` section. The first guess is each sensor off by
`offset_m` in a random direction and turned by `offset_deg` about a random axis. For the roof
sensor, the reference, only its height and tilt are put off (a random sign, a random horizontal
axis): its x, y and yaw define the reference and are kept, as the calibration keeps them.
"""

from __future__ import annotations

import datetime
import json
import math
import re
import time
from pathlib import Path

import numpy as np
import open3d as o3d
import yaml
from scipy.spatial.transform import Rotation

from ares.core.config import VehicleProfile, load_vehicle, load_yaml, named_file
from perception import extrinsic_calibration as ext
from simulator.lidar import LidarSimParams, SimulatedLidar
from simulator.world import Mesh, box_mesh, cylinder_mesh

REFERENCE = "roof"

# The warehouse, vehicle frame = warehouse frame (the rear axle's centre on the floor, facing the
# back wall). 20 × 14 m, walls 5 m high, open behind the vehicle like the paper's three walls.
#
# Why the boxes and pillars: registration pins a sensor only along the normals of the surfaces
# it shares with the reference. The floor fixes z, roll and pitch; a wall adds the translation
# across it and one rotation; translation *along* a wall is free unless another surface faces
# that way. With the floor and three walls every direction has one surface, but a thin one: the
# roof sensor sees the floor only beyond ~7 m, a 16-layer sensor tilted 15° sees each wall in a
# few rings, and a sensor that sees one side wall well leans on the back wall alone for x. Boxes
# at assorted yaws and round pillars add faces of other orientations and vertical edges in the
# near field both sensors share, so no degree of freedom rests on one surface. The weakest left
# is the front sensors' height (the floor they share with the roof sensor is far): a few mm.
HALL_X = (-8.0, 12.0)
HALL_Y = (-7.0, 7.0)
HALL_HEIGHT_M = 5.0
WALL_M = 0.3
PILLARS = ((7.0, 3.2), (7.0, -3.2), (-2.0, 4.5), (-2.0, -4.5))  # x, y; radius 0.25 m
BOXES = (
    ((6.0, 5.0), (1.2, 1.0, 1.5), 25.0),
    ((6.5, -4.5), (1.2, 0.8, 1.0), -15.0),  # (x, y), (l, w, h), yaw°
    ((10.0, 1.5), (2.0, 1.0, 2.0), 40.0),
    ((1.5, 5.2), (1.2, 1.0, 1.2), 0.0),
    ((1.0, -5.4), (1.0, 1.0, 1.8), 10.0),
    ((9.5, -2.5), (0.8, 0.8, 0.8), 60.0),
)


def warehouse() -> Mesh:
    (x0, x1), (y0, y1), h, t = HALL_X, HALL_Y, HALL_HEIGHT_M, WALL_M
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    parts = [
        box_mesh((cx, cy, -t), (x1 - x0, y1 - y0, t), 0.0, "concrete"),  # floor, top at z = 0
        box_mesh((x1 + t / 2, cy, 0.0), (t, y1 - y0 + 2 * t, h), 0.0, "concrete"),  # back wall
        box_mesh((cx, y1 + t / 2, 0.0), (x1 - x0, t, h), 0.0, "concrete"),  # left wall
        box_mesh((cx, y0 - t / 2, 0.0), (x1 - x0, t, h), 0.0, "concrete"),
    ]  # right wall
    parts += [cylinder_mesh((x, y, 0.0), 0.25, h, "concrete", resolution=24) for x, y in PILLARS]
    parts += [box_mesh((x, y, 0.0), size, math.radians(yaw), "metal") for (x, y), size, yaw in BOXES]
    return Mesh.join(parts)


def scan(vehicle: VehicleProfile, seed: int, azimuth_decimation: int = 1) -> dict[str, np.ndarray]:
    """One sweep of every sensor from its true mount, standing still: N × 3 points, sensor frame.
    Range noise, dropouts, ghosts and self-hits on, as the simulator makes them."""
    mesh = warehouse()
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(mesh.vertices), o3d.core.Tensor(mesh.triangles))
    params = LidarSimParams(seed=seed, azimuth_decimation=azimuth_decimation, roadside_objects=False)
    out = {}
    for i, (name, mount) in enumerate(vehicle.lidars.items()):
        sensor = SimulatedLidar(name, mount, vehicle, params, np.random.default_rng([seed, i]))
        sweep = sensor.sweep(scene, np.eye(3), np.zeros(3), None, lambda _g, prim: mesh.material[prim])
        out[name] = np.stack([sweep.x, sweep.y, sweep.z], axis=1).astype(np.float64)
    return out


def first_guess(
    name: str, truth: np.ndarray, rng: np.random.Generator, offset_m: float, offset_deg: float
) -> np.ndarray:
    """The truth put off by `offset_m` and `offset_deg`: in a random direction and about a random
    axis, or, for the reference, up or down and about a random horizontal axis."""
    if name == REFERENCE:
        shift = np.array([0.0, 0.0, rng.choice([-1.0, 1.0])])
        heading = rng.uniform(0.0, 2 * math.pi)
        axis = np.array([math.cos(heading), math.sin(heading), 0.0])
    else:
        shift, axis = (v / np.linalg.norm(v) for v in rng.standard_normal((2, 3)))
    turned = Rotation.from_rotvec(axis * math.radians(offset_deg)) * Rotation.from_matrix(truth[:3, :3])
    if name == REFERENCE:  # a tilt about a horizontal axis turns the yaw a little too: undo that
        _, pitch, roll = turned.as_euler("ZYX")
        turned = Rotation.from_euler("ZYX", [Rotation.from_matrix(truth[:3, :3]).as_euler("ZYX")[0], pitch, roll])
    out = truth.copy()
    out[:3, :3] = turned.as_matrix()  # turned about the sensor's own centre
    out[:3, 3] += offset_m * shift
    return out


def calibrate(
    vehicle_name: str = "ares_shuttle",
    seed: int = 0,
    offset_m: float = 0.10,
    offset_deg: float = 3.0,
    azimuth_decimation: int = 1,
) -> dict:
    """Run the experiment. The report holds, per sensor, the first guess and the calibrated mount
    (as the profile will state it, rounded), their errors against the truth, the fit and the time."""
    profile = named_file("vehicles", vehicle_name)
    vehicle = load_vehicle(vehicle_name)
    if REFERENCE not in vehicle.lidars or len(vehicle.lidars) < 2:
        raise ValueError(f"vehicle {vehicle.name!r} needs a {REFERENCE!r} LiDAR and at least one other to calibrate")
    started = time.perf_counter()
    clouds = scan(vehicle, seed, azimuth_decimation)
    scan_s = time.perf_counter() - started
    rng = np.random.default_rng([seed, 99])
    truth = {name: ext.mount_matrix(m) for name, m in vehicle.lidars.items()}
    guesses = {name: first_guess(name, t, rng, offset_m, offset_deg) for name, t in truth.items()}
    results = ext.calibrate(clouds, guesses, vehicle, REFERENCE)

    sensors = []
    for name, result in results.items():
        model = vehicle.lidars[name].model
        guess, found = ext.matrix_mount(model, guesses[name]), ext.matrix_mount(model, result.transform)
        guess_m, guess_deg = ext.pose_error(guesses[name], truth[name])
        error_m, error_deg = ext.pose_error(ext.mount_matrix(found), truth[name])
        sensors.append(
            {
                "sensor": name,
                "model": model,
                "method": result.method,
                "points": result.points,
                "guess_error_cm": round(guess_m * 100, 2),
                "guess_error_deg": round(guess_deg, 3),
                "error_cm": round(error_m * 100, 3),
                "error_deg": round(error_deg, 4),
                "fitness": None if result.fitness is None else round(result.fitness, 3),
                "rmse_cm": None if result.rmse_m is None else round(result.rmse_m * 100, 2),
                "seconds": round(result.seconds, 3),
                "guess": {"xyz_m": list(guess.xyz_m), "rpy_deg": list(guess.rpy_deg)},
                "xyz_m": list(found.xyz_m),
                "rpy_deg": list(found.rpy_deg),
            }
        )
    return {
        "vehicle": vehicle.name,
        "profile": str(profile),
        "seed": seed,
        "offset_m": offset_m,
        "offset_deg": offset_deg,
        "azimuth_decimation": azimuth_decimation,
        "sensors": sensors,
        "worst_error_cm": max(s["error_cm"] for s in sensors),
        "worst_error_deg": max(s["error_deg"] for s in sensors),
        "scan_s": round(scan_s, 3),
        "total_s": round(time.perf_counter() - started, 3),
    }


def table(report: dict) -> str:
    lines = [
        f"{report['vehicle']}: seed {report['seed']}, first guess off by {report['offset_m'] * 100:g} cm and "
        f"{report['offset_deg']:g}°",
        f"{'sensor':<12} {'method':<12} {'guess cm':>8} {'guess °':>8} {'error cm':>8} {'error °':>8} "
        f"{'fitness':>7} {'rmse cm':>7} {'time s':>6}   calibrated xyz m, rpy °",
    ]
    for s in report["sensors"]:
        fit = f"{s['fitness']:>7.3f} {s['rmse_cm']:>7.2f}" if s["fitness"] is not None else f"{'-':>7} {'-':>7}"
        lines.append(
            f"{s['sensor']:<12} {s['method']:<12} {s['guess_error_cm']:>8.2f} {s['guess_error_deg']:>8.3f} "
            f"{s['error_cm']:>8.3f} {s['error_deg']:>8.4f} {fit} {s['seconds']:>6.2f}   "
            f"{s['xyz_m']}, {s['rpy_deg']}"
        )
    lines.append(
        f"worst: {report['worst_error_cm']:.3f} cm, {report['worst_error_deg']:.4f}°; "
        f"scan {report['scan_s']:.2f} s, total {report['total_s']:.2f} s"
    )
    return "\n".join(lines)


# ---- the calibrated profile ------------------------------------------------------------------

HEADER_MARK = "# Calibrated by `ares calibrate lidars`"


def lidars_yaml(report: dict) -> str:
    rows = [
        f"  {s['sensor']}: {{model: {s['model']}, xyz_m: {json.dumps(s['xyz_m'])}, "
        f"rpy_deg: {json.dumps(s['rpy_deg'])}}}"
        for s in report["sensors"]
    ]
    return "lidars:\n" + "\n".join(rows) + "\n"


def write_profile(report: dict, path: str | Path) -> Path:
    """The profile the report came from with its `lidars:` section replaced by the calibrated
    mounts, under a comment saying when and how. The original's text is kept, comments and all,
    when its `lidars:` block can be cut out cleanly (checked by reading the result back);
    otherwise its data is written out afresh."""
    source = Path(report["profile"])
    block = lidars_yaml(report)
    expected = dict(load_yaml(source), lidars=yaml.safe_load(block)["lidars"])
    text = source.read_text().rstrip("\n") + "\n"
    if text.startswith(HEADER_MARK):  # calibrated before: that header goes
        text = text.split("\n\n", 1)[-1]
    # a top-level `lidars:` key and its indented lines, up to the next top-level line
    match = re.search(r"^lidars:.*\n(?:[ \t]+.*\n|[ \t]*\n)*", text, re.M)
    body = (text[: match.start()] + block + text[match.end() :]).rstrip("\n") + "\n" if match else ""
    if not body or yaml.safe_load(body) != expected:
        body = yaml.safe_dump({k: v for k, v in expected.items() if k != "lidars"}, sort_keys=False) + block
    header = (
        f"{HEADER_MARK} on {datetime.date.today().isoformat()} from {source.name}, its\n"
        f"# `lidars:` replaced: the shuttle in a simulated warehouse (ares/tools/harness/calibration_warehouse.py),\n"
        f"# seed {report['seed']}, first guess off by {report['offset_m'] * 100:g} cm and "
        f"{report['offset_deg']:g}°. Roof height, roll and pitch from the floor\n"
        f"# plane, its x, y, yaw kept; the others by point-to-plane ICP to the roof's cloud\n"
        f"# (perception/extrinsic_calibration.py). Worst error against the simulator's truth: "
        f"{report['worst_error_cm']:.2f} cm, {report['worst_error_deg']:.3f}°.\n\n"
    )
    path = Path(path)
    path.write_text(header + body)
    return path
