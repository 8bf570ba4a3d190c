"""`ares bench perception --reference` (ares/tools/bench/perception_reference.py): a scan file
labelled by our ground stage, Algorithm 2 and Patchwork++ side by side."""

from __future__ import annotations

import numpy as np
import pytest

from ares.cli import main
from ares.tools.bench.common import BenchError
from ares.tools.bench.perception_reference import compare, real_case, run_reference_bench
from tests.helpers.street_scan import simulated_street

pytest.importorskip("pypatchworkpp")


def test_a_kitti_file_of_a_street_is_labelled_by_each_and_compared_with_patchwork(tmp_path):
    points, _ = simulated_street(sensor_height=1.73)
    sensor_frame = points - np.array([0.0, 0.0, 1.73], dtype=np.float32)  # as KITTI's .bin stores it
    records = np.column_stack([sensor_frame, np.full(len(points), 0.3, np.float32)]).astype("<f4")
    path = tmp_path / "street.bin"
    records.tofile(path)

    row = compare(real_case(path), repeats=1)
    assert row["kind"] == "real" and row["scan"] == "street.bin" and row["sensor_height_m"] == 1.73
    assert 0.9 * len(points) < row["points"] <= len(points)  # less the self hits and ghosts
    assert row["iou"]["ours"] >= 0.9 > row["iou"]["algorithm2"]
    assert abs(row["share"]["ours"] - row["share"]["patchworkpp"]) < 0.05
    assert row["share"]["algorithm2"] < row["share"]["ours"]  # it calls nothing past the grid ground
    assert row["occupied"]["ours"] > 0 and row["occupied"]["patchworkpp"] > 0  # the car, the pedestrian, the box
    for figure in ("ms", "cpu_ms"):
        assert set(row[figure]) == {"ours", "algorithm2", "patchworkpp"}
        assert all(value > 0 for value in row[figure].values())


def test_a_missing_scan_is_an_error_before_anything_is_simulated(tmp_path):
    with pytest.raises(BenchError, match="no such file"):
        run_reference_bench(frames=1, repeats=1, scans=[str(tmp_path / "none.bin")])


def test_a_scan_needs_the_reference(capsys):
    assert main(["bench", "perception", "--scan", "street.bin"]) == 1
    assert "--scan goes with --reference" in capsys.readouterr().err
