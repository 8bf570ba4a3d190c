"""`ares perception scan FILE` on files like a real car-roof 64-layer scan: the simulator's roof
HDL-64E 1.73 m above a kerbed straight of the built-in tour, in a street canyon (~127,000 returns,
as many as a KITTI scan), written as KITTI writes its .bin (float32 x, y, z, intensity; laser by
laser from the top one, each revolution from the front), and as .pcd and .ply through open3d."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import open3d as o3d
import pytest

from ares import cli
from ares.core.config import LIDAR_MODELS
from ares.tools.bench.perception import TourScene, street_roof_scan
from perception.rings import recover_rings, rings_from_elevation, rings_from_order
from perception.scan_file import ScanFileError, read_scan
from tests.helpers.stack import REPO

pytestmark = pytest.mark.timeout(180)

KERBED_STRAIGHT_S = 815.0  # the lakeside promenade: straight, flat, kerbs both sides, 6 m wide


@pytest.fixture(scope="module")
def sweep():
    scan, _, _ = street_roof_scan(TourScene(2.36), KERBED_STRAIGHT_S)
    return scan


def kitti_order(sweep) -> np.ndarray:
    """Indices of the sweep's points as KITTI stores them: the top laser first, each revolution
    from azimuth 0 round anticlockwise."""
    azimuth = np.mod(np.arctan2(sweep.y, sweep.x), 2 * np.pi)
    return np.lexsort((azimuth, -sweep.ring.astype(np.int64)))


def records(sweep, order=None) -> np.ndarray:
    out = np.column_stack([sweep.x, sweep.y, sweep.z, sweep.intensity]).astype("<f4")
    return out if order is None else out[order]


def write_cloud(path, xyz: np.ndarray, **fields) -> None:
    cloud = o3d.t.geometry.PointCloud(o3d.core.Tensor(np.ascontiguousarray(xyz, dtype=np.float32)))
    for name, values in fields.items():
        cloud.point[name] = o3d.core.Tensor(np.ascontiguousarray(values).reshape(-1, 1))
    assert o3d.t.io.write_point_cloud(str(path), cloud)


def scan(tmp_path, capsys, *argv) -> tuple[int, dict | None, str]:
    """The command in this process: (exit code, its JSON, stderr)."""
    code = cli.main(["perception", "scan", *map(str, argv)])
    out, err = capsys.readouterr()
    lines = out.strip().splitlines()
    return code, (json.loads(lines[-1]) if code == 0 else None), err


def check_kerbed_straight(report: dict, points: int) -> None:
    assert report["points"] == points
    assert 0.25 < report["ground_share"] < 0.75
    assert report["boundaries"]["left"] and report["boundaries"]["right"]
    assert report["road_found"] and report["confidence"] > 0.5
    assert abs(report["lateral_offset_m"]) < 0.5  # the sensor is over the centre line
    assert abs(report["heading_rad"]) < 0.1
    assert 5.0 < report["width_m"] < 7.0
    cells = report["cells"]
    assert cells["occupied"] > 0 and cells["free"] > cells["occupied"]
    assert sum(cells.values()) == 100 * 100


def test_a_kitti_bin_of_a_car_roof_scan(tmp_path, sweep):
    path = tmp_path / "000042.bin"
    records(sweep, kitti_order(sweep)).tofile(path)
    picture = tmp_path / "top.png"
    result = subprocess.run(
        [sys.executable, "-m", "ares.cli", "perception", "scan", str(path), "--out", str(picture)],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
        stdin=subprocess.DEVNULL,
    )
    assert result.returncode == 0, result.stderr
    lines = result.stdout.strip().splitlines()
    assert len(lines) == 1  # one JSON line, nothing else
    report = json.loads(lines[0])
    assert 115_000 < sweep.size < 140_000  # as dense as a KITTI scan
    check_kerbed_straight(report, sweep.size)
    assert report["rings"] == {"method": "order", "count": 64}
    assert report["sensor_xyz_m"][2] == pytest.approx(1.73)  # KITTI's height, the .bin default
    assert report["nan_points_dropped"] == 0
    assert set(report["stage_ms"]) >= {"transform", "filters", "ground", "grid", "road", "total"}
    assert report["picture"] == str(picture)
    assert picture.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_pcd_and_ply_load_and_run(tmp_path, capsys, sweep):
    order = kitti_order(sweep)
    xyz = records(sweep, order)[:, :3]
    holes = np.full((25, 3), np.nan, dtype=np.float32)  # an organised cloud's rays that saw nothing
    pcd = tmp_path / "street.pcd"
    write_cloud(pcd, np.vstack([xyz, holes]), intensity=np.r_[sweep.intensity[order], np.zeros(25)].astype(np.float32))
    code, report, err = scan(tmp_path, capsys, pcd, "--sensor-height", "1.73", "--out", tmp_path / "pcd.png")
    assert code == 0, err
    check_kerbed_straight(report, sweep.size)
    assert report["nan_points_dropped"] == 25
    assert report["rings"]["method"] == "order"

    # a .ply shuffled (as a voxel filter leaves it): no order to use, the elevation gives the rings
    shuffled = np.random.default_rng(3).permutation(sweep.size)
    ply = tmp_path / "street.ply"
    write_cloud(ply, xyz[shuffled])
    code, report, err = scan(tmp_path, capsys, ply, "--sensor-height", "1.73", "--out", tmp_path / "ply.png")
    assert code == 0, err
    check_kerbed_straight(report, sweep.size)
    assert report["rings"] == {"method": "elevation", "count": 64}

    # a driver's cloud says each point's ring itself
    ringed = tmp_path / "ringed.pcd"
    write_cloud(ringed, xyz[shuffled], ring=sweep.ring[order][shuffled].astype(np.int32))
    assert read_scan(ringed).ring is not None
    code, report, err = scan(tmp_path, capsys, ringed, "--sensor-height", "1.73", "--out", tmp_path / "r.png")
    assert code == 0, err
    assert report["rings"]["method"] == "file" and report["boundaries"]["left"] and report["boundaries"]["right"]


def test_a_profiles_roof_height_is_the_default_for_pcd(tmp_path, capsys, sweep):
    pcd = tmp_path / "low.pcd"
    write_cloud(pcd, records(sweep, kitti_order(sweep))[:, :3])
    code, report, err = scan(tmp_path, capsys, pcd, "--out", tmp_path / "low.png")
    assert code == 0, err
    assert report["sensor_xyz_m"] == [1.4, 0.0, 1.72]  # techs4agecar's roof mount


@pytest.mark.parametrize(
    "name, content, complaint",
    [
        ("missing.bin", None, "no such file"),
        ("scan.las", b"\0" * 32, "unknown extension"),
        ("cut.bin", b"\0" * 36, "not a whole number of KITTI points"),
        ("empty.bin", b"", "no points"),
        ("nan.bin", np.full((4, 4), np.nan, dtype="<f4").tobytes(), "4 with NaN"),
        ("empty.pcd", b"", "no points"),
    ],
)
def test_files_that_give_no_scan_exit_2(tmp_path, capsys, name, content, complaint):
    path = tmp_path / name
    if content is not None:
        path.write_bytes(content)
    code, _, err = scan(tmp_path, capsys, path, "--out", tmp_path / "x.png")
    assert code == 2
    assert complaint in err and str(path) in err
    assert not (tmp_path / "x.png").exists()


def test_an_unknown_vehicle_exits_2(tmp_path, capsys, sweep):
    path = tmp_path / "a.bin"
    records(sweep)[:1000].tofile(path)
    code, _, err = scan(tmp_path, capsys, path, "--vehicle", "no_such_car")
    assert code == 2 and "no_such_car" in err


def test_nan_points_are_dropped_and_counted(tmp_path):
    path = tmp_path / "holes.bin"
    data = np.arange(40, dtype="<f4").reshape(10, 4)
    data[[2, 5], 1] = np.nan
    data[7, 2] = np.inf
    data.tofile(path)
    read = read_scan(path)
    assert read.dropped == 3 and len(read.points) == 7
    assert np.array_equal(read.points[:, 0], data[[0, 1, 3, 4, 6, 8, 9], 0])  # the order is kept
    with pytest.raises(ScanFileError, match="no such file"):
        read_scan(tmp_path / "none.pcd")


# ---- rings ------------------------------------------------------------------------------------


def same_rings(found: np.ndarray, truth: np.ndarray) -> bool:
    """The same points share a ring in both (ids may differ: road detection needs rings apart only)."""
    return len(set(zip(found.tolist(), truth.tolist()))) == len(np.unique(found)) == len(np.unique(truth))


def test_rings_from_kitti_order_are_exact_where_elevations_drift(sweep):
    """A real HDL-64E's lasers sit at different heights on its head: seen from one origin, a
    point's elevation drifts with range (and the ranking of the lasers by median elevation may
    change). The point order still separates the lasers; the elevation bins mix them."""
    order = kitti_order(sweep)
    xyz = records(sweep, order)[:, :3].astype(np.float64)
    truth = sweep.ring[order].astype(np.int64)
    model = LIDAR_MODELS["hdl64e"]
    assert np.array_equal(rings_from_order(xyz, 64), truth)
    assert np.array_equal(rings_from_elevation(xyz, model), truth)  # the simulator fires from one point
    offset = np.where(truth >= 32, 0.20, 0.14)  # emitters above the origin
    lifted = xyz + np.c_[np.zeros((len(xyz), 2)), offset]
    assert same_rings(rings_from_order(lifted, 64), truth)
    assert not same_rings(rings_from_elevation(lifted, model), truth)


def test_rings_fall_back_to_the_elevation_when_the_order_is_not_ring_by_ring(sweep):
    xyz = np.column_stack([sweep.x, sweep.y, sweep.z])
    azimuth = np.mod(np.arctan2(sweep.y, sweep.x), 2 * np.pi)
    firing = np.lexsort((sweep.ring, azimuth))  # every laser at an azimuth, then the next
    model = LIDAR_MODELS["hdl64e"]
    assert rings_from_order(xyz[firing], 64) is None
    ring, method = recover_rings(xyz[firing], model)
    assert method == "elevation" and np.array_equal(ring, sweep.ring[firing])
    clockwise = np.lexsort((-azimuth, sweep.ring))  # bottom laser first, turning the other way
    assert np.array_equal(rings_from_order(xyz[clockwise], 64), sweep.ring[clockwise])
