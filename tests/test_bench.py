"""`ares bench bus`: a short run between real processes; figures are reported, not asserted."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from ares.tools.bench.common import percentile
from tests.helpers.stack import REPO

pytestmark = pytest.mark.timeout(180)


def test_percentile_is_numpys_linear_between_the_nearest_ranks():
    # by hand: the q-th percentile of n values lies at rank q/100 * (n - 1) (from 0) of the sorted
    # values, linearly between the two ranks around it
    values = [float(v) for v in range(100, 0, -1)]  # 100 ... 1: any order
    assert percentile(values, 50) == pytest.approx(50.5)  # rank 49.5: between 50 and 51, the median
    assert percentile(values, 99) == pytest.approx(99.01)  # rank 98.01
    assert percentile(values, 100) == 100.0 and percentile(values, 0) == 1.0
    assert percentile([1.0, 2.0, 3.0, 4.0], 25) == pytest.approx(1.75)  # rank 0.75
    assert percentile([0.0, 10.0], 95) == pytest.approx(9.5)
    assert percentile([7.0], 99) == 7.0
    assert percentile([1.0, 2.0, 4.0], 50, ndigits=0) == 2.0 and percentile([0.1234567], 50, ndigits=3) == 0.123
    assert percentile([], 50) is None  # no values, no figure (JSON null)


def test_bus_bench_json():
    result = subprocess.run(
        [sys.executable, "-m", "ares.cli", "bench", "bus", "--json", "--seconds", "1"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=150,
        stdin=subprocess.DEVNULL,
    )
    assert result.returncode == 0, result.stderr
    assert "[bench]" in result.stderr  # progress goes to stderr
    report = json.loads(result.stdout.strip().splitlines()[-1])
    for key in (
        "latency_p50_ms",
        "latency_p99_ms",
        "rate_msgs_per_s",
        "lost",
        "messages",
        "payload_bytes",
        "mode",
        "python",
        "zenoh",
        "latency_method",
        "throughput_sent",
        "throughput_received",
    ):
        assert key in report, key
    assert report["lost"] == 0
    assert report["latency_lost"] == 0
    assert report["throughput_sent"] == report["throughput_received"] > 0
    assert 0 < report["latency_p50_ms"] <= report["latency_p99_ms"] <= report["latency_max_ms"]
    assert report["rate_msgs_per_s"] > 0
    assert report["messages"] > 0 and report["payload_bytes"] > 0
    assert report["rejected"] == 0
    assert report["mode"] in ("peer", "client")


def test_perception_bench_json():
    result = subprocess.run(
        [sys.executable, "-m", "ares.cli", "bench", "perception", "--json", "--frames", "2", "--repeats", "1"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=150,
        stdin=subprocess.DEVNULL,
    )
    assert result.returncode == 0, result.stderr
    assert "[bench]" in result.stderr
    report = json.loads(result.stdout.strip().splitlines()[-1])
    for key in (
        "ground_ms_p50",
        "grid_ms_p50",
        "road_ms_p50",
        "pipeline_ms_p50",
        "raycast_ms_p50",
        "raycast_core_share_at_10hz",
        "filters_ms_p50",
        "transform_ms_p50",
        "pipeline_ground_ms_p50",
        "raycast_as_run_ms_p50",
        "raycast_cast_rays_ms_p50",
        "scan_pipeline_ms_p50",
        "scan_stage_ms_p50",
        "ground_scan_points_p50",
        "frame_points_p50",
        "load_avg_1m",
        "cpus",
        "method",
        "goals_met",
    ):
        assert key in report, key
    assert report["frames"] == 2 and len(report["places"]) == 2
    assert 100_000 < report["ground_scan_points_p50"] < 150_000  # a KITTI-dense 64-layer scan
    assert report["frame_points_p50"] > 50_000  # three sensors at full resolution
