"""Road detection (perception/road_detection.py, ARES §3.4.2): Algorithm 1 branch by branch,
eqs. 7-10 by hand, the window features against a point-by-point reading, and synthetic scans
of analytic roads.

A synthetic ring is the footprint of a cone of laser beams on flat ground, a circle of radius
h / tan(−elevation) about the sensor's foot, with the sensor's azimuth steps; each point is
raised to the terrain's height there (a road with a 2.5 % crown and a verge beyond |s| = 3 m).
A pitched corner sensor's rings are not circles and a beam hitting a kerb lands on its face,
not beyond it; the detector relies on neither.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import statistics

import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st

from perception.lidar_perception import GUIDE_FROM_M
from perception.road_detection import (
    BAND_MARGIN_M,
    GAP_M,
    HEIGHT_CUT_M,
    MIN_SLANT,
    SLANT_M,
    LidarFrame,
    RoadDetectionParams,
    RoadModel,
    ScoreWeights,
    boundary_distance_term,
    detect_road,
    fit_boundary,
    gradient_term,
    normalized_azimuth_subtraction,
    relative_height_term,
    road_score,
)

PI = math.pi
poly = np.polynomial.polynomial

# ---- Algorithm 1 ------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "theta_ij, theta_s, expected",
    [
        (7 * PI / 8, -7 * PI / 8, PI / 4),  # Δ = −7π/4 < −3π/2: remainder(Δ, π) = Δ + 2π
        (5 * PI / 8, -5 * PI / 8, 7 * PI / 4),  # Δ = −5π/4 in [−3π/2, −π): π + mod(Δ, π) = π + 3π/4
        (PI / 6, PI / 2, PI / 3),  # Δ = π/3: itself
        (-PI / 2, PI / 2, PI),  # Δ = π: itself (Δ <= π)
        (PI / 2, -PI / 2, -PI),  # Δ = −π: itself (not < −π)
        (-5 * PI / 8, 5 * PI / 8, PI / 4),  # Δ = 5π/4 > π: remainder(Δ, π) = Δ − π (5/4 rounds to 1)
        (-7 * PI / 8, 7 * PI / 8, -PI / 4),  # Δ = 7π/4 > π: remainder(Δ, π) = Δ − 2π (7/4 rounds to 2)
    ],
)
def test_algorithm_1_on_each_branch(theta_ij, theta_s, expected):
    assert normalized_azimuth_subtraction(theta_ij, theta_s) == pytest.approx(expected, abs=1e-12)


def literal(theta_ij: float, theta_s: float) -> float:
    """Algorithm 1 line by line with Python's own remainder (IEEE) and % (floored mod)."""
    d = theta_s - theta_ij
    if -3 * PI / 2 > d:
        return math.remainder(d, PI)
    elif d < -PI:
        return PI + d % PI
    elif d <= PI:
        return d
    return math.remainder(d, PI)


angles = st.floats(-PI, PI, allow_nan=False)


@given(st.lists(st.tuples(angles, angles), min_size=1, max_size=20))
def test_algorithm_1_properties(pairs):
    theta_ij, theta_s = np.array(pairs).T
    got = normalized_azimuth_subtraction(theta_ij, theta_s)
    for t, s, g in zip(theta_ij, theta_s, got):
        d = s - t
        assume(abs(abs(d) - 1.5 * PI) > 1e-9)  # remainder's tie at ±3π/2 goes to the even n
        assert g == pytest.approx(literal(t, s), abs=1e-12)
        assert -PI <= g < 2 * PI
        turns = (g - d) / PI  # always Δ plus a whole number of π
        assert turns == pytest.approx(round(turns), abs=1e-9)
        if -1.5 * PI <= d < -PI or PI < d <= 1.5 * PI:
            assert round(turns) in (3, -1)  # the two middle ranges fold by π
        else:
            assert round(turns) % 2 == 0  # elsewhere by 2π: the wrapped difference ...
            assert -PI <= g <= PI
        if abs(math.remainder(d, 2 * PI)) < PI / 2:
            assert g == pytest.approx(math.remainder(d, 2 * PI), abs=1e-12)  # ... always within a quarter turn


# ---- eqs. 7-10 --------------------------------------------------------------------------------

W = ScoreWeights(
    beta0=2, beta1=-1, beta2=0.1, beta3=2, beta4=3, beta5=4, beta6=0.2, beta7=3, beta8=2, beta9=0.3, beta10=0.5
)


def test_eqs_7_to_10_by_hand():
    assert gradient_term(0.5, W) == pytest.approx(0.1 + 2 * 0.5 + 3 * 0.25 + 4 * 0.125)  # 2.35
    assert relative_height_term(0.04, W) == pytest.approx(0.2 + 3 * 0.04 + 2 * 0.2)  # 0.72
    assert boundary_distance_term(-2.0, W) == pytest.approx(0.3 + 0.5 * -2.0)  # −0.7
    # β1 + ∇ + σ + d̂ = −1 + 2.35 + 0.72 − 0.7 = 1.37; β0 · 1.37 = 2.74
    assert road_score(0.5, 0.04, -2.0, W) == pytest.approx(1 / (1 + math.exp(2.74)))
    # no previous boundary (NaN or None): d̂ = 0, so 2 · (−1 + 2.35 + 0.72) = 4.14
    assert road_score(0.5, 0.04, math.nan, W) == pytest.approx(1 / (1 + math.exp(4.14)))
    assert road_score(0.5, 0.04, None, W) == pytest.approx(1 / (1 + math.exp(4.14)))
    assert road_score(np.array([0.5, 0.5]), np.array([0.04, 0.04]), np.array([-2.0, np.nan]), W) == pytest.approx(
        [1 / (1 + math.exp(2.74)), 1 / (1 + math.exp(4.14))]
    )


def test_default_weights_score_a_flat_road_as_road_and_a_kerb_not():
    w = ScoreWeights()
    assert road_score(0.03, 0.005, None, w) > 0.95
    assert road_score(0.0, 0.12, None, w) < 0.5 and road_score(0.3, 0.0, None, w) < 0.5
    assert road_score(1000.0, 1000.0, 1000.0, w) == 0.0 and road_score(0.0, 0.0, -1e6, w) == 1.0  # no overflow


# ---- synthetic scans --------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Sensor:
    origin: tuple[float, float, float]  # vehicle frame, m
    yaw_deg: float
    elevations_deg: tuple[float, ...]
    step_deg: float
    max_radius_m: float  # rings reaching farther are left out (never on the ROI's ground)


ROOF = Sensor(
    (3.0, 0.0, 2.94), 0.0, tuple(np.r_[np.linspace(2.0, -8.33, 32), np.linspace(-8.83, -24.8, 32)]), 0.17, 40.0
)
# 16 lasers ±15°, pitched 15° down: −30° .. 0°; the near field only
CORNER_L = Sensor((3.3, 0.95, 0.9), 45.0, tuple(np.arange(-30.0, 0.0, 2.0)), 0.2, 8.0)
CORNER_R = dataclasses.replace(CORNER_L, origin=(3.3, -0.95, 0.9), yaw_deg=-45.0)
SENSORS = (ROOF, CORNER_L, CORNER_R)
HALF_WIDTH, CROWN = 3.0, 0.025


def verge(kind: str, t: np.ndarray) -> np.ndarray:
    """Height of the verge t metres beyond the road's edge, relative to the edge."""
    return {
        "kerb": np.full_like(t, 0.12),
        "grass": 0.25 * t,
        "wall": np.full_like(t, 2.0),
        "drop": np.full_like(t, -2.0),
        "open": np.zeros_like(t),
    }[kind]


def lateral(X, Y, radius):
    """s: signed distance from the road's centre line, + to its left. A bend of `radius` (+ left)
    turns about (0, radius)."""
    return Y if radius is None else radius - np.sign(radius) * np.hypot(X, Y - radius)


def to_world(pose, x, y):
    X0, Y0, yaw = pose[0], pose[1], math.radians(pose[2])
    return X0 + math.cos(yaw) * x - math.sin(yaw) * y, Y0 + math.sin(yaw) * x + math.cos(yaw) * y


def terrain(X, Y, left, right, radius, box):
    s = lateral(X, Y, radius)
    z = -CROWN * np.minimum(np.abs(s), HALF_WIDTH)
    z = np.where(s > HALF_WIDTH, z + verge(left, s - HALF_WIDTH), z)
    z = np.where(s < -HALF_WIDTH, z + verge(right, -s - HALF_WIDTH), z)
    if box is not None:  # (X0, X1, Y0, Y1, height): something standing on the road
        X0, X1, Y0, Y1, h = box
        z = np.where((X >= X0) & (X <= X1) & (Y >= Y0) & (Y <= Y1), z + h, z)
    return z


@functools.cache
def scan(
    pose=(0.0, 0.0, 0.0), left="kerb", right="kerb", radius=None, box=None, sensors=SENSORS, far_rings=False
) -> LidarFrame:
    """A frame of the sensors, the vehicle at `pose` = (X, Y, yaw°) on the road. far_rings: the
    rings that miss the ground nearby hit something 60 m away (a full-size frame)."""
    parts = []
    for index, sensor in enumerate(sensors):
        theta = np.arange(-PI, PI, math.radians(sensor.step_deg))
        for laser, elevation in enumerate(sensor.elevations_deg):
            radius_m = sensor.origin[2] / math.tan(math.radians(-elevation)) if elevation < 0 else math.inf
            if radius_m > sensor.max_radius_m and not far_rings:
                continue
            phi = theta + math.radians(sensor.yaw_deg)
            r = min(radius_m, 60.0) if radius_m <= sensor.max_radius_m else 60.0
            x, y = sensor.origin[0] + r * np.cos(phi), sensor.origin[1] + r * np.sin(phi)
            z = terrain(*to_world(pose, x, y), left, right, radius, box) if r < 60.0 else np.full_like(x, 5.0)
            seen = ~((x > -1.0) & (x < 4.0) & (np.abs(y) < 1.1))  # the vehicle's own body: filtered
            parts.append(
                (np.c_[x, y, z][seen], np.full(seen.sum(), 64 * index + laser), theta[seen], np.full(seen.sum(), index))
            )
    if not parts:
        return empty_frame(len(sensors))
    points, ring, azimuth, sensor_index = (np.concatenate(a) for a in zip(*parts))
    return LidarFrame(points.astype(np.float32), ring, azimuth, sensor_index, np.array([s.origin for s in sensors]))


def empty_frame(sensors=3) -> LidarFrame:
    return LidarFrame(
        np.zeros((0, 3), np.float32), np.zeros(0, int), np.zeros(0), np.zeros(0, int), np.zeros((sensors, 3))
    )


def edge_errors(points, pose=(0.0, 0.0, 0.0), radius=None, side=1):
    """How far each boundary point lies beyond the road's true edge on its side (m, + outwards)."""
    return side * lateral(*to_world(pose, points[:, 0], points[:, 1]), radius) - HALF_WIDTH


def true_edge(x, pose, radius, side):
    """y of the true edge at each x, in the vehicle frame (by bisection on y)."""
    lo, hi = np.full_like(x, -15.0), np.full_like(x, 15.0)
    for _ in range(60):
        mid = (lo + hi) / 2
        beyond = side * lateral(*to_world(pose, x, mid), radius) - HALF_WIDTH > 0
        lo, hi = np.where(beyond == (side < 0), mid, lo), np.where(beyond == (side < 0), hi, mid)
    return (lo + hi) / 2


# ---- the window features against a point-by-point reading ------------------------------------


def brute_force_scores(frame: LidarFrame, p: RoadDetectionParams, width_m: float = 6.0) -> np.ndarray:
    """Steps 1-3 of the module's docstring for one point at a time: the previous model's centre
    line on y = 0 and its width `width_m` (so the reference is the point nearest y = 0 and the
    band reaches width_m / 2 + BAND_MARGIN_M + gradient_span_m + run_m), eq. 10 weighing nothing.
    The span and the window are taken across the guide line: along the ring they are longer by
    1 / slant."""
    scores = np.full(len(frame.points), np.nan)
    x, y, z = frame.points.astype(float).T
    band = width_m / 2 + BAND_MARGIN_M + p.gradient_span_m + p.run_m
    roi = (x >= p.x_min_m) & (x <= p.x_max_m) & (np.abs(y) <= p.half_width_m) & (np.abs(y) <= band)
    for ring in np.unique(frame.ring_id):
        members = np.flatnonzero(roi & (frame.ring_id == ring))
        ox, oy, _ = frame.sensor_origins[frame.sensor_index[members[0]]]
        ahead = [i for i in members if x[i] > ox]
        reference = min(ahead, key=lambda i: abs(y[i]))
        assert abs(y[reference]) <= p.reference_max_offset_m
        turn = {i: math.remainder(frame.azimuth[i] - frame.azimuth[reference], 2 * PI) for i in members}
        ring_pts = sorted(
            (i for i in members if abs(turn[i]) < PI / 2 and abs(z[i] - z[reference]) <= HEIGHT_CUT_M), key=turn.get
        )
        # t: along the ring, the azimuth step times the horizontal range from the sensor
        t, gap = [0.0], [True]
        for a, b in zip(ring_pts, ring_pts[1:]):
            dt = abs(turn[b] - turn[a]) * math.hypot(x[b] - ox, y[b] - oy)
            t.append(t[-1] + dt)
            gap.append(dt > GAP_M or math.hypot(x[b] - x[a], y[b] - y[a]) > GAP_M)
        spacing = statistics.mean(t[k] - t[k - 1] for k in range(1, len(t)) if not gap[k])
        behind = max(1, math.ceil(SLANT_M / spacing))
        at_reference = ring_pts.index(reference)
        for at, i in enumerate(ring_pts):
            inward = -1 if turn[i] > 0 else 1
            # the slant: metres across the guide line (y = 0) per metre along the ring, over `behind` points
            j = min(max(at + inward * behind, 0), len(ring_pts) - 1)
            slant = abs(abs(y[i]) - abs(y[ring_pts[j]])) / max(abs(t[at] - t[j]), 1e-6)
            slant = min(max(slant, MIN_SLANT), 1.0)
            reach_s = math.ceil(p.gradient_span_m / (spacing * slant))
            reach_w = max(2, math.ceil(p.window_m / (spacing * slant)))
            near = at + inward * reach_s
            far = near + inward * reach_w
            far = max(far, at_reference) if inward < 0 else min(far, at_reference)  # not across θs
            span = range(min(far, at), max(far, at) + 1)
            if (
                turn[i] == 0
                or -inward * (near - far) < reach_w // 2
                or min(span) < 0
                or max(span) >= len(ring_pts)
                or any(gap[k] for k in span if k != min(span))
            ):
                scores[i] = 1.0
                continue
            window = [ring_pts[k] for k in range(min(near, far), max(near, far) + 1)]
            tw, zw = np.array([t[ring_pts.index(k)] for k in window]), z[window]
            slope, intercept = np.polyfit(tw, zw, 1)
            gradient = (z[i] - zw.mean()) / abs(t[at] - tw.mean())  # + rising away from the road
            sigma = max(z[i] - (intercept + slope * t[at]), 0.0)  # above the road's trend
            scores[i] = road_score(gradient, sigma, None, p.weights)
    return scores


@pytest.mark.parametrize("span, window", [(0.4, 0.4), (0.6, 0.3)])
def test_window_features_match_a_point_by_point_reading(span, window):
    rng = np.random.default_rng(7)
    sensor = Sensor((1.0, 0.0, 2.0), 30.0, (-12.0, -16.0, -21.0), 0.5, 40.0)
    frame = scan(left="kerb", right="wall", sensors=(sensor,))
    noisy = frame.points + np.c_[np.zeros((len(frame.points), 2)), rng.normal(0, 0.02, len(frame.points))]
    shuffle = rng.permutation(len(frame.points))  # the order of the points does not matter
    frame = dataclasses.replace(
        frame,
        points=noisy.astype(np.float32)[shuffle],
        ring_id=frame.ring_id[shuffle],
        azimuth=frame.azimuth[shuffle],
        sensor_index=frame.sensor_index[shuffle],
    )
    # the reference on y = 0 as in the brute force, through a previous model whose eq. 10 weighs nothing
    p = RoadDetectionParams(gradient_span_m=span, window_m=window, weights=ScoreWeights(beta9=0.0, beta10=0.0))
    got = detect_road(frame, p, previous=RoadModel(np.array([3.0]), np.array([-3.0]), 6.0)).scores
    expected = brute_force_scores(frame, p)
    assert np.array_equal(np.isnan(got), np.isnan(expected))
    assert np.nanmax(np.abs(got - expected)) < 1e-4
    assert np.sum(got < 0.5) >= 5 and np.sum(got >= 0.5) >= 100  # both kinds of point are there


# ---- boundaries and the road model ------------------------------------------------------------


@pytest.mark.parametrize("verge_kind", ["kerb", "wall", "drop"])
def test_a_straight_road_between_steps(verge_kind):
    result = detect_road(scan(left=verge_kind, right=verge_kind))
    for points, side in ((result.left_points, 1), (result.right_points, -1)):
        assert len(points) >= 30
        errors = edge_errors(points, side=side)
        assert errors.max() <= 0.001 and errors.min() >= -0.06  # the last road point: within a spacing
    x = np.linspace(0.0, 12.0, 25)
    assert np.abs(poly.polyval(x, result.model.left) - 3.0).max() < 0.03
    assert np.abs(poly.polyval(x, result.model.right) + 3.0).max() < 0.03
    assert result.found and result.confidence > 0.9
    assert abs(result.lateral_offset_m) < 0.02 and abs(result.heading_rad) < math.radians(0.3)
    assert result.width_m == pytest.approx(6.0, abs=0.05)


def test_a_gentle_change_of_slope_is_found_at_the_kink():
    """From −2.5 % to +25 %: ∇ and σ notice it only some way up the slope (σ grows with the
    distance past the kink); the stop is then placed back where the road's line and the verge's
    line meet (_hinge), within a ring's spacing of the edge, whatever the span and window."""
    frame = scan(left="grass", right="grass")
    for p in (RoadDetectionParams(), RoadDetectionParams(gradient_span_m=0.3, window_m=0.3)):
        result = detect_road(frame, p)
        for points, side in ((result.left_points, 1), (result.right_points, -1)):
            errors = edge_errors(points, side=side)
            assert len(points) >= 30 and errors.max() <= 0.02
            assert errors.min() >= -0.10 and np.sum(errors < -0.06) <= 1  # a ring at a slant: a little early
        assert result.found and result.confidence > 0.8


@pytest.mark.parametrize("radius", [30.0, -30.0])
def test_a_bend_of_30_m(radius):
    first = detect_road(scan(left="kerb", right="kerb", radius=radius))
    again = detect_road(scan(left="kerb", right="kerb", radius=radius), previous=first.model)
    for result in (first, again):
        for points, side in ((result.left_points, 1), (result.right_points, -1)):
            errors = edge_errors(points, radius=radius, side=side)
            assert len(points) >= 30 and errors.max() <= 0.001 and errors.min() >= -0.07
        x = np.linspace(0.0, 12.0, 25)
        for coef, side in ((result.model.left, 1), (result.model.right, -1)):
            assert np.abs(poly.polyval(x, coef) - true_edge(x, (0, 0, 0), radius, side)).max() < 0.1
        # a parabola is not an arc: at x = 0, ~4 m behind the nearest boundary point, it is off by some cm and 1-2°
        assert abs(result.lateral_offset_m) < 0.1 and abs(result.heading_rad) < math.radians(2.0)
        assert result.width_m == pytest.approx(6.0, abs=0.1) and result.confidence > 0.9


@pytest.mark.parametrize("offset, yaw", [(0.5, 5.0), (-0.5, -5.0)])
def test_lateral_offset_and_heading(offset, yaw):
    result = detect_road(scan(pose=(0.0, offset, yaw)))
    assert result.lateral_offset_m == pytest.approx(offset, abs=0.02)  # + : the vehicle is left of the centre
    assert math.degrees(result.heading_rad) == pytest.approx(yaw, abs=0.3)  # + : it points left of the road
    assert result.width_m == pytest.approx(6.0, abs=0.05)
    assert edge_errors(result.left_points, (0.0, offset, yaw)).min() >= -0.06


@pytest.mark.parametrize(
    "x0, x1, offset_tolerance",
    [
        (4.0, 5.0, 0.07),  # it hides the near field: x = 0 is extrapolated from x = 5 m on
        (10.0, 10.6, 0.02),
        (11.0, 11.4, 0.02),
    ],
)
def test_the_refit_drops_the_rings_that_stop_at_something_on_the_verge(x0, x1, offset_tolerance):
    """A 0.5 m box whose face stands 1.4 m inside the left edge: the rings that meet it stop
    short. A plain least-squares fit through all boundary points is pulled towards them (most
    at the ends of the range); the two-step fit drops exactly them."""
    result = detect_road(scan(box=(x0, x1, 1.6, 5.0, 0.5)))
    fit, points = result.left_fit, result.left_points[result.left_points[:, 0] <= 12.0]
    short = edge_errors(points) < -0.1
    assert 2 <= short.sum() < len(points) / 3
    assert np.array_equal(~fit.inliers, short)
    x = np.linspace(points[fit.inliers, 0].min(), 12.0, 25)
    plain = poly.polyfit(points[:, 0], points[:, 1], 2)
    assert np.abs(poly.polyval(x, plain) - 3.0).max() > 0.2
    assert np.abs(poly.polyval(x, fit.coef) - 3.0).max() < 0.03
    assert result.lateral_offset_m == pytest.approx(0.0, abs=offset_tolerance)


def test_fit_boundary_rejects_outliers_in_two_steps():
    x = np.linspace(4.0, 12.0, 17)
    y = 3.0 + 0.02 * x + 0.005 * np.sin(5 * x)
    y[[3, 4, 5, 11]] -= [1.2, 1.3, 1.1, 0.8]  # two runs of rings that stopped short
    p = RoadDetectionParams(poly_order=2)
    fit = fit_boundary(x, y, p)
    assert fit.inliers.tolist() == [i not in (3, 4, 5, 11) for i in range(17)]
    error = {
        name: np.abs(poly.polyval(x, c) - 3.0 - 0.02 * x).max()
        for name, c in (("plain", poly.polyfit(x, y, 2)), ("rough", fit.rough), ("refit", fit.coef))
    }
    assert error["plain"] > 0.3 and error["rough"] < 0.2 and error["refit"] < 0.01
    assert fit.rms_m < 0.005
    assert fit_boundary(x[:4], y[:4], p) is None  # fewer than min_points
    assert fit_boundary(x[:6], y[:6], p) is None  # bunched within 2.5 m of x


def test_an_open_area_gives_no_boundary_on_its_side():
    frame = scan(left="open", right="kerb")
    alone = detect_road(frame)
    assert len(alone.left_points) == 0 and alone.left_fit is None and alone.model.left is None
    assert len(alone.right_points) >= 30
    assert not alone.found and alone.confidence == 0.0  # one side, no width known
    tracked = detect_road(frame, previous=detect_road(scan()).model)  # the width from the last frame
    assert tracked.found and 0.4 < tracked.confidence <= 0.5  # one side: at most half
    assert tracked.lateral_offset_m == pytest.approx(0.0, abs=0.03)
    assert tracked.width_m == pytest.approx(6.0, abs=0.05)


def test_nothing_to_see():
    for frame in (empty_frame(), scan(sensors=(dataclasses.replace(ROOF, elevations_deg=(-6.0, -5.0)),))):
        result = detect_road(frame)  # nothing / only beyond the ROI
        assert not result.found and result.confidence == 0.0
        assert math.isnan(result.lateral_offset_m) and math.isnan(result.width_m)
        assert len(result.left_points) == len(result.right_points) == 0
        assert result.road_points_per_sensor.tolist() == [0] * len(frame.sensor_origins)
        assert np.isnan(result.scores).all()


def test_a_ring_across_its_sensors_azimuth_wrap():
    """The roof sensor alone, mounted backwards: the road ahead lies across its ±π."""
    p = RoadDetectionParams(fit_x_max_m=25.0)  # the roof sees the ground from x = 9.3 m only
    normal = detect_road(scan(sensors=(ROOF,)), p)
    turned = detect_road(scan(sensors=(dataclasses.replace(ROOF, yaw_deg=180.0),)), p)
    for result in (normal, turned):
        for points, side in ((result.left_points, 1), (result.right_points, -1)):
            errors = edge_errors(points, side=side)
            assert len(points) >= 30 and errors.max() <= 0.001 and errors.min() >= -0.06
        assert result.found and abs(result.lateral_offset_m) < 0.02 and abs(result.heading_rad) < 0.005
    assert len(normal.left_points) == len(turned.left_points)


def test_road_points_per_sensor():
    frame = scan()
    result = detect_road(frame)
    counts = [np.sum(result.scores[frame.sensor_index == s] >= 0.5) for s in range(3)]
    assert result.road_points_per_sensor.tolist() == counts and min(counts) > 1000
    blind = scan(sensors=(ROOF, dataclasses.replace(CORNER_L, elevations_deg=()), CORNER_R))
    assert detect_road(blind).road_points_per_sensor[1] == 0


def test_the_previous_boundary_pulls_the_new_one_in_proportion_to_beta10():
    """Eq. 10: with a previous left boundary at y = 2 (the edge is at 3), a point Δ̂ metres
    beyond it adds β10·Δ̂ to the bracket. On the flat road ∇ is the crown's fall, −2.5 % (less
    along a ring that crosses the road at a slant), and with eq. 9 weighing nothing the road stops
    at Δ̂ = (−β1 + 0.025·β3 − 0.025²·β4 − β9) / β10 at most. The default β10 leaves the kerb in
    charge; β10 = 2 stops just short of y ≈ 2.55."""
    frame, wrong = scan(), RoadModel(np.array([2.0]), np.array([-3.0]), 5.0)
    assert edge_errors(detect_road(frame, previous=wrong).left_points).min() >= -0.06
    w = ScoreWeights(beta1=-1.0, beta3=4.0, beta4=5.0, beta7=0.0, beta8=0.0, beta9=0.0, beta10=2.0)
    stop = 2.0 + (1.0 + 0.025 * w.beta3 - 0.025**2 * w.beta4) / w.beta10
    y = detect_road(frame, RoadDetectionParams(weights=w), previous=wrong).left_points[:, 1]
    assert len(y) >= 30 and stop - 0.1 < y.min() and y.max() < stop


def test_a_width_only_one_side_saw_does_not_narrow_the_search():
    """After a narrow lane (3.2 m) seen on one side only, the road widens to 6 m: the stale width
    would keep the walks within 1.6 m + a margin of the guide and the far edge unseen for good;
    a one-sided previous model searches the whole band, so both sides are found again."""
    stale = RoadModel(np.array([3.0]), None, 3.2)
    result = detect_road(scan(), previous=stale)
    assert result.found and result.model.left is not None and result.model.right is not None
    assert result.width_m == pytest.approx(2 * HALF_WIDTH, abs=0.1)


def test_boundaries_that_leave_the_vehicle_off_the_road_are_not_a_road():
    """The vehicle is on the road: a guide 4.5 m to the left puts the references on the verge,
    and whatever the walks find there is rejected; the near field then finds the road."""
    off = RoadModel(np.array([7.5]), np.array([1.5]), 6.0)
    result = detect_road(scan(), previous=off)
    assert result.found and result.model.left[0] > 0 > result.model.right[0]
    assert abs(result.lateral_offset_m) < 0.1


def test_road_model_centre():
    left, right = np.array([3.0, 0.1]), np.array([-3.0, 0.1])
    assert RoadModel(left, right, None).centre() == pytest.approx([0.0, 0.1])
    assert RoadModel(left, None, 6.0).centre() == pytest.approx([3.0 - 3.0 * math.hypot(1, 0.1), 0.1])
    assert RoadModel(None, right, 6.0).centre() == pytest.approx([-3.0 + 3.0 * math.hypot(1, 0.1), 0.1])
    assert RoadModel(left, None, None).centre() is None and RoadModel(None, None, 6.0).centre() is None


def test_a_road_model_seen_from_a_moved_vehicle():
    slope = 0.1
    model = RoadModel(np.array([3.0, slope]), np.array([-3.0, slope]), 6.0)
    # 5 m on, 0.5 m left, turned along the road: the boundaries run straight ahead, 2.5 m / 3.5 m off
    # along the road's normal (the vehicle is 0.5 − 5·0.1 = 0 m left of the centre, measured along y)
    moved = model.seen_from(5.0, 0.5, math.atan(slope), (0.0, 12.0))
    assert moved.left == pytest.approx([3.0 * math.cos(math.atan(slope)), 0.0], abs=1e-9)
    assert moved.right == pytest.approx([-3.0 * math.cos(math.atan(slope)), 0.0], abs=1e-9)
    assert moved.width_m == 6.0
    assert RoadModel(np.array([3.0, 0.0]), None, 6.0).seen_from(1.0, 0.0, 0.0, (0.0, 12.0)).right is None


@given(st.floats(-0.08, 0.08), st.floats(0.0, 4.0), st.floats(-0.3, 0.3), st.floats(-0.1, 0.1))
def test_a_bent_road_moved_keeps_its_points(kappa, ahead, across, off_turn):
    """A 12.5 m bend or gentler, the vehicle moved up to 4 m along it, 0.3 m aside and turned up to
    6° off the road's turn: the boundary's points from 4 m ahead of the vehicle lie on the moved
    boundary (a polynomial of the same order again, fitted where the old one had points, as the
    pipeline moves it) to within 3 cm (2 cm at worst on a grid), plenty for a guide."""
    left = np.array([2.0, 0.0, kappa / 2])
    turn = math.atan(kappa * ahead) + off_turn
    moved = RoadModel(left, None, 4.0).seen_from(ahead, across, turn, (GUIDE_FROM_M, 12.0))
    xs = np.linspace(ahead + 4.0, 12.0, 9)
    c, s = math.cos(turn), math.sin(turn)
    dx, dy = xs - ahead, poly.polyval(xs, left) - across
    xv, yv = c * dx + s * dy, -s * dx + c * dy
    assert np.abs(poly.polyval(xv, moved.left) - yv).max() < 0.03


def test_parameters_are_checked():
    with pytest.raises(ValueError):
        RoadDetectionParams(window_m=0.0)
    with pytest.raises(ValueError, match="min_points"):
        RoadDetectionParams(poly_order=3, min_points=3)
    with pytest.raises(ValueError):
        RoadDetectionParams(x_min_m=30.0)


def test_a_frame_of_a_few_points_gives_no_road_and_no_error():
    """A sensor nearly covered, or the first sweep after a restart: a handful of points, fewer
    than one run of the stop rule, with a model from the frame before (the bootstrap path)."""
    full = scan()
    previous = detect_road(full).model
    near = np.flatnonzero(np.hypot(full.points[:, 0], full.points[:, 1]) < 8.0)[:3]
    few = LidarFrame(
        full.points[near], full.ring_id[near], full.azimuth[near], full.sensor_index[near], full.sensor_origins
    )
    for prior in (None, previous):
        result = detect_road(few, previous=prior)
        assert not result.found and result.confidence == 0.0


# ---- the pipeline's guide after a loss ----------------------------------------------------------


def test_a_lost_road_guides_the_next_frames_moved_by_what_was_driven():
    from ares.core.config import load_vehicle
    from perception.lidar_perception import LidarPipeline, LidarPipelineParams

    pipeline = LidarPipeline(load_vehicle("ares_shuttle"), LidarPipelineParams(lost_guide_m=5.0))
    road = detect_road(scan(pose=(0.0, 0.5, 10.0)))  # turned 10° left of the road
    xs = np.linspace(4.0, 10.0, 7)

    def left_at(model, x):
        return poly.polyval(x, model.left)

    assert road.found and pipeline.guide((0.0, 0.0)) is None  # nothing seen yet: the near field
    pipeline.remember(road)
    assert pipeline.guide((0.3, 0.0)) is road.model  # found: the last frame's model, as it is
    pipeline.remember(detect_road(empty_frame()))  # lost
    guide = pipeline.guide((2.0, 0.0))  # 2 m on, straight (+0.3 before)
    assert np.abs(left_at(guide, xs) - left_at(road.model, xs + 2.3)).max() < 0.02  # the road slants by
    assert guide.right is not None  # 0.8 m over 4.6 m
    for _ in range(600):  # standing: it keeps guiding
        guide = pipeline.guide((0.0, 0.0))
    assert np.abs(left_at(guide, xs) - left_at(road.model, xs + 2.3)).max() < 0.02
    turned = pipeline.guide((1.0, 0.1))  # 1 m on a left 10 m arc
    assert turned.left[1] < guide.left[1] - 0.05  # ... the road points more right
    assert pipeline.guide((1.5, 0.0)) is not None  # 4.8 m since the road was found
    assert pipeline.guide((0.5, 0.0)) is None  # 5.3 m > lost_guide_m
    assert pipeline.guide((0.0, 0.0)) is None  # ... for good, until a road is found
    off = LidarPipeline(load_vehicle("ares_shuttle"), LidarPipelineParams(lost_guide_m=0.0))
    off.remember(road)
    off.remember(detect_road(empty_frame()))
    assert off.guide((0.0, 0.0)) is None  # 0: never, not even standing


def test_a_lost_road_is_not_moved_without_a_measured_motion():
    from ares.core.config import load_vehicle
    from perception.lidar_perception import LidarPipeline

    pipeline = LidarPipeline(load_vehicle("ares_shuttle"))
    pipeline.remember(detect_road(scan()))
    pipeline.remember(detect_road(empty_frame()))
    assert pipeline.guide((0.5, 0.0)) is not None
    assert pipeline.guide(None) is None and pipeline.guide((0.0, 0.0)) is None
    pipeline.remember(detect_road(scan()))  # found again
    assert pipeline.guide(None) is not None  # the last frame's model needs no move
