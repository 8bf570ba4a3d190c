"""Extrinsic calibration of the shuttle's LiDARs against each other (ARES §3.4.1).

The paper calibrated its three LiDARs pairwise and checked the result in a warehouse with three
walls and a floor. Here, with the vehicle standing still on a flat floor:

1. Self-hits go first: every point that the first guess of its sensor's extrinsic puts inside
   the vehicle's body box, grown by a margin larger than the guess can be wrong by, is dropped.
   They would tie each sensor to the vehicle, not to the room, and no other sensor sees them.
2. The roof sensor is the reference. Its height, roll and pitch come from the floor: the vehicle
   frame's z = 0 is the ground the wheels stand on, so the floor plane seen by the roof sensor
   fixes exactly these three. Its x, y and yaw cannot be seen in a plane, nor in the room, which
   is not tied to the vehicle's axes, so they are kept from the profile (the mounting drawing).
   That is the usual choice of a known reference, less the three figures that are hardest to
   measure on the vehicle and matter most to ground removal.
3. Each other sensor is registered against the roof sensor's cloud in the vehicle frame:
   point-to-plane ICP, coarse to fine on voxel-downsampled clouds, with a Tukey kernel so that
   what only one sensor sees (the near floor, ghosts, shadows) does not pull the result. About
   half a front sensor's points find a partner (the fitness): the rest is floor inside the roof
   sensor's blind ring (~7 m) and faces only a low sensor sees. That thin shared floor makes
   height the front sensors' weakest direction; it is still good to a few millimetres.

Clouds are N × 3 arrays in metres; extrinsics are 4 × 4 sensor-to-vehicle transforms.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
import open3d as o3d
from scipy.spatial.transform import Rotation

from ares.core.config import LidarMount, VehicleProfile

REGISTRATION = o3d.pipelines.registration

# (voxel size, largest correspondence distance), coarse to fine. The first stage must reach
# across the first guess's error (3° is 0.5 m at 10 m); each later one halves the voxel and
# tightens the gate so that only points on the same surface pair up. The last voxel, 5 cm, is
# about twice the sensors' range noise: finer cells would hold single noisy points.
STAGES = ((0.40, 1.50), (0.20, 0.60), (0.10, 0.25), (0.05, 0.12))
# Radius of the neighbourhood a reference normal is fitted in, whatever the voxel. A spinning
# sensor's points lie on its rings: a few centimetres apart on a wall 10 m off, tens of
# centimetres on the floor. A neighbourhood holding one ring holds a line, whose normal is any
# direction across it; a wider one blends the floor with wall bases and box edges (in this
# warehouse 0.5 m and 0.8 m gave 1-2 cm of error in height, 0.3 m a few millimetres).
NORMAL_RADIUS_M = 0.3


# ---- extrinsics as matrices --------------------------------------------------------------------


def mount_matrix(mount: LidarMount) -> np.ndarray:
    """4 × 4 sensor-to-vehicle transform of a mount (R = Rz(yaw) Ry(pitch) Rx(roll))."""
    roll, pitch, yaw = mount.rpy_deg
    out = np.eye(4)
    out[:3, :3] = Rotation.from_euler("ZYX", [yaw, pitch, roll], degrees=True).as_matrix()
    out[:3, 3] = mount.xyz_m
    return out


def matrix_mount(model: str, transform: np.ndarray, decimals_m: int = 3, decimals_deg: int = 2) -> LidarMount:
    """The mount of a transform, rounded as a profile states it (1 mm, 0.01° by default)."""
    yaw, pitch, roll = Rotation.from_matrix(transform[:3, :3]).as_euler("ZYX", degrees=True)
    xyz = tuple(round(float(v), decimals_m) + 0.0 for v in transform[:3, 3])  # + 0.0: no "-0.0"
    rpy = tuple(round(float(v), decimals_deg) + 0.0 for v in (roll, pitch, yaw))
    return LidarMount(model=model, xyz_m=xyz, rpy_deg=rpy)


def transformed(points: np.ndarray, transform: np.ndarray) -> np.ndarray:
    return points @ transform[:3, :3].T + transform[:3, 3]


def pose_error(estimate: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """(position error in metres, rotation error in degrees: the angle of R_truthᵀ R_estimate)."""
    distance = float(np.linalg.norm(estimate[:3, 3] - truth[:3, 3]))
    relative = truth[:3, :3].T @ estimate[:3, :3]
    angle = math.degrees(math.acos(float(np.clip((np.trace(relative) - 1.0) / 2.0, -1.0, 1.0))))
    return distance, angle


# ---- 1. self-hits --------------------------------------------------------------------------------


def body_box(vehicle: VehicleProfile, margin_m: float = 0.3) -> tuple[np.ndarray, np.ndarray]:
    """(low, high) corners of a box in the vehicle frame holding the body (from the ground up),
    the roof mast and every sensor's housing, grown by `margin_m` on every side: more than a
    guess off by 10 cm and 3° misplaces a body point 3 m from its sensor (26 cm). The floor it
    cuts away near the body is seen by no other sensor: nothing is lost."""
    rear = (vehicle.wheelbase_m - vehicle.length_m) / 2
    corners = np.array(
        [
            [rear, -vehicle.width_m / 2, 0.0],
            [rear + vehicle.length_m, vehicle.width_m / 2, vehicle.height_m or 2.0],
            *(m.xyz_m for m in vehicle.lidars.values()),
        ]
    )
    return corners.min(axis=0) - margin_m, corners.max(axis=0) + margin_m


def without_self_hits(points: np.ndarray, guess: np.ndarray, box: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """The points (sensor frame) that the guessed extrinsic puts outside the body box."""
    in_vehicle = transformed(points, guess)
    inside = np.all((in_vehicle >= box[0]) & (in_vehicle <= box[1]), axis=1)
    return points[~inside]


# ---- 2. the reference from the floor ---------------------------------------------------------


def floor_plane(
    points: np.ndarray, guess: np.ndarray, max_tilt_deg: float = 15.0, tolerance_m: float = 0.06, seed: int = 0
) -> tuple[np.ndarray, float]:
    """(unit normal n, height h) of the floor in the sensor's frame, n pointing up to the sensor:
    n·p = −h on the floor. RANSAC finds the largest planes in turn; the first one that is level
    within `max_tilt_deg` by the guess and lies below the sensor is the floor (a wall or a box
    top is not). Its inliers are then fitted by least squares."""
    o3d.utility.random.seed(seed)  # RANSAC's sampling, for repeatable runs
    up = guess[:3, :3].T @ np.array([0.0, 0.0, 1.0])  # the vehicle's up in the sensor frame, by the guess
    remaining = points
    for _ in range(5):
        if len(remaining) < 100:
            break
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(remaining.astype(np.float64)))
        (a, b, c, d), inliers = cloud.segment_plane(tolerance_m, 3, 200)
        normal = np.array([a, b, c])
        if normal @ up < 0:
            normal, d = -normal, -d
        if normal @ up > math.cos(math.radians(max_tilt_deg)) and d > 0:
            return _refit(remaining[inliers])
        remaining = np.delete(remaining, inliers, axis=0)
    raise ValueError("no floor in the reference sensor's cloud: is the vehicle standing on a flat floor?")


def _refit(floor: np.ndarray) -> tuple[np.ndarray, float]:
    centre = floor.mean(axis=0)
    normal = np.linalg.svd(floor - centre, full_matrices=False)[2][2]  # least-variance direction
    if normal @ centre > 0:  # the sensor is above the floor
        normal = -normal
    return normal, float(-normal @ centre)


def reference_from_floor(points: np.ndarray, guess: np.ndarray) -> np.ndarray:
    """The reference sensor's extrinsic: height, roll and pitch from the floor, x, y and yaw from
    the guess. With R = Rz(yaw) Ry(pitch) Rx(roll), the floor's normal in the sensor frame must
    map to the vehicle's up: Ry(pitch) Rx(roll) n = e_z, whatever the yaw; hence
    roll = atan2(n_y, n_z) and pitch = −asin(n_x)."""
    normal, height = floor_plane(points, guess)
    roll = math.atan2(normal[1], normal[2])
    pitch = -math.asin(float(np.clip(normal[0], -1.0, 1.0)))
    yaw = Rotation.from_matrix(guess[:3, :3]).as_euler("ZYX")[0]
    out = np.eye(4)
    out[:3, :3] = Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_matrix()
    out[:3, 3] = [guess[0, 3], guess[1, 3], height]
    return out


# ---- 3. the others against the reference -------------------------------------------------------


@dataclass
class Registration:
    transform: np.ndarray  # sensor-to-vehicle
    fitness: float  # share of the sensor's points with a partner on the last stage
    rmse_m: float  # RMS distance of those pairs


def _cloud(points: np.ndarray, voxel_m: float, normals: bool) -> o3d.geometry.PointCloud:
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points.astype(np.float64))).voxel_down_sample(voxel_m)
    if normals:
        cloud.estimate_normals(o3d.geometry.KDTreeSearchParamRadius(max(3 * voxel_m, NORMAL_RADIUS_M)))
    return cloud


def register(
    points: np.ndarray, reference_vehicle: np.ndarray, guess: np.ndarray, stages=STAGES, max_iterations: int = 40
) -> Registration:
    """The extrinsic of a sensor whose cloud (sensor frame) overlaps the reference cloud (vehicle
    frame), starting from `guess`. Point-to-plane, since both sensors sample the same surfaces at
    different places: a point is drawn to its partner's plane, not to the partner itself. The
    Tukey kernel's width follows the gate, so pairs that straddle two surfaces weigh nothing."""
    transform = guess
    result = None
    for voxel, gate in stages:
        source = _cloud(points, voxel, normals=False)
        target = _cloud(reference_vehicle, voxel, normals=True)
        method = REGISTRATION.TransformationEstimationPointToPlane(REGISTRATION.TukeyLoss(k=gate / 2))
        criteria = REGISTRATION.ICPConvergenceCriteria(
            relative_fitness=1e-7, relative_rmse=1e-7, max_iteration=max_iterations
        )
        result = REGISTRATION.registration_icp(source, target, gate, transform, method, criteria)
        transform = np.asarray(result.transformation).copy()
    return Registration(transform, float(result.fitness), float(result.inlier_rmse))


# ---- all together --------------------------------------------------------------------------------


@dataclass
class Calibrated:
    transform: np.ndarray  # sensor-to-vehicle
    method: str  # "floor plane" (the reference) or "ICP to <reference>"
    points: int  # the sensor's points left after the self-hit filter
    seconds: float
    fitness: float | None = None
    rmse_m: float | None = None


def calibrate(
    clouds: dict[str, np.ndarray], guesses: dict[str, np.ndarray], vehicle: VehicleProfile, reference: str = "roof"
) -> dict[str, Calibrated]:
    """Every sensor's extrinsic from one still scan each (sensor frames) and first guesses."""
    box = body_box(vehicle)
    clean = {name: without_self_hits(points, guesses[name], box) for name, points in clouds.items()}
    started = time.perf_counter()
    found = reference_from_floor(clean[reference], guesses[reference])
    out = {reference: Calibrated(found, "floor plane", len(clean[reference]), time.perf_counter() - started)}
    target = transformed(clean[reference], found)
    for name, points in clean.items():
        if name != reference:
            started = time.perf_counter()
            fit = register(points, target, guesses[name])
            out[name] = Calibrated(
                fit.transform,
                f"ICP to {reference}",
                len(points),
                time.perf_counter() - started,
                fit.fitness,
                fit.rmse_m,
            )
    return out
