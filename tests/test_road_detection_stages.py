"""The stages of road detection's first iteration (perception/road_detection.py, `_scan`; ARES
§3.4.2, steps 1-5 of the module's docstring), each held to what a reader of the paper expects of
it, on generated inputs: the band and the rings' references (steps 1-2), the azimuth order of
Algorithm 1 (step 2), t, the windows and the features of eqs. 8-10 (step 3), the score of eq. 7,
the walks' stops and ends (step 4) and the hinge (step 5).

The rings here are circles on the ground about one sensor, as a spinning LiDAR's ring on flat
ground is; the heights are a profile across the road (y), with an edge at |y| = e.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from perception.road_detection import (
    BAND_MARGIN_M,
    DROP_M,
    GAP_M,
    HEIGHT_CUT_M,
    MIN_SLANT,
    LidarFrame,
    RoadDetectionParams,
    RoadModel,
    ScoreWeights,
    _Along,
    _along_ring,
    _azimuth_order,
    _beyond_previous,
    _fell_away,
    _first_stops,
    _gather_rings,
    _group_by_ring,
    _hinge,
    _last_road_points,
    _open_ends,
    _ring_references,
    _Rings,
    _road_rings,
    _road_side_windows,
    _scan,
    _search_band,
    _side_boundary,
    _stops,
    _window_features,
    _window_lengths,
    _within_band,
    road_score,
)

PI = math.pi
P = RoadDetectionParams()
# a few dozen examples each, the same ones every run: the whole file takes a few seconds
FAST = settings(max_examples=50, deadline=None, derandomize=True)
seeds = st.integers(0, 2**32 - 1)


# ---- helpers ------------------------------------------------------------------------------------


def circle_frame(profile, radii=(8.0,), step=0.004, height=2.0, origin=(0.0, 0.0), half_turn=1.2) -> LidarFrame:
    """One sensor at `origin`, `height` up, one ring per radius: the circle about its foot, from
    −half_turn to +half_turn (rad, symmetric about straight ahead), z = profile(y) (NaN: no return)."""
    parts = []
    k = np.arange(-round(half_turn / step), round(half_turn / step) + 1)
    for ring, radius in enumerate(radii):
        theta = k * step
        x, y = origin[0] + radius * np.cos(theta), origin[1] + radius * np.sin(theta)
        z = profile(y)
        seen = np.isfinite(z)
        parts.append((np.c_[x, y, z][seen], np.full(seen.sum(), ring), theta[seen]))
    points, ring_id, azimuth = (np.concatenate(a) for a in zip(*parts))
    return LidarFrame(
        points.astype(np.float32),
        ring_id,
        azimuth,
        np.zeros(len(points), dtype=np.int64),
        np.array([[origin[0], origin[1], height]]),
    )


def staged(frame: LidarFrame, p: RoadDetectionParams = P, guide=None, previous=None) -> dict:
    """The stages of _scan in its order, up to the walks' stops, every intermediate kept."""
    band = _search_band(p, previous)
    idx, across = _within_band(frame, np.arange(len(frame.points)), guide, band)
    idx, across, ring_first, ring = _group_by_ring(frame.ring_id, idx, across)
    theta_s, z_ref, reach, aim = _ring_references(frame, idx, across, ring_first, ring, p)
    road_ring, ring_below = _road_rings(reach, aim, frame.sensor_index[idx[ring_first]])
    keep, u = _azimuth_order(frame.azimuth[idx], frame.points[idx, 2], ring, theta_s, z_ref, road_ring)
    rings = _gather_rings(frame, idx, across, ring, keep, u, theta_s, ring_below)
    along = _along_ring(rings, frame.sensor_origins)
    reach_s, reach_w, run = _window_lengths(rings, along, p)
    lo, hi, valid = _road_side_windows(rings.u, rings.ring, along.piece, reach_s, reach_w)
    gradient, sigma, trend = _window_features(along.t, rings.z, lo, hi)
    score = road_score(gradient, sigma, _beyond_previous(rings, previous), p.weights)
    score[~valid] = 1.0
    stop = _stops(score, rings.u, along.piece, run)
    return dict(band=band, rings=rings, along=along, reach_s=reach_s, trend=trend, score=score, stop=stop, run=run)


def side_boundary(stages: dict, sign: int, p: RoadDetectionParams = P) -> np.ndarray:
    """_side_boundary on the stages of `staged`."""
    s = stages
    return _side_boundary(
        sign, s["stop"], s["score"], s["reach_s"], s["rings"], s["along"], s["trend"], s["band"], p, p.x_max_m
    )


def straight_rings(x: np.ndarray, u: np.ndarray, across=None, ring=None, y=None) -> _Rings:
    """_Rings of points at x (y = 0 unless given) on the ground of sensor 0, in rings `ring`
    (default: one); only what the stage under test reads needs to be real."""
    n = len(x)
    ring = np.zeros(n, dtype=np.int64) if ring is None else ring
    count = int(ring.max()) + 1 if n else 0
    return _Rings(
        idx=np.arange(n),
        ring=ring,
        x=x.astype(float),
        y=np.zeros(n) if y is None else y,
        z=np.zeros(n),
        u=u,
        across=(np.zeros(n) if across is None else across).astype(np.float32),
        sensor=np.zeros(n, dtype=np.int64),
        theta_s=np.zeros(count),
        lower=np.full(count, -1),
    )


def ring_pieces(spec: list[tuple[int, int, list[int]]]):
    """u (one 0 per ring, sorted within it), ring and piece of rings given as (points right of the
    reference, points left of it, positions within the ring where a gap opens)."""
    u, ring, new_piece = [], [], []
    for r, (right, left, gaps) in enumerate(spec):
        k = np.arange(-right, left + 1)
        u.append(k * 0.01)
        ring.append(np.full(len(k), r))
        fresh = np.zeros(len(k), dtype=bool)
        fresh[0] = True
        fresh[[g for g in gaps if 0 < g < len(k)]] = True
        new_piece.append(fresh)
    new_piece = np.concatenate(new_piece)
    return np.concatenate(u), np.concatenate(ring), np.cumsum(new_piece)


rings_with_gaps = st.lists(
    st.tuples(st.integers(0, 25), st.integers(0, 25), st.lists(st.integers(1, 50), max_size=3)), min_size=1, max_size=4
)


# ---- step 1: the band ---------------------------------------------------------------------------


@FAST
@given(st.floats(1.0, 20.0), st.floats(1.0, 20.0), st.sampled_from(["both", "left", "right", "none"]))
def test_the_band_reaches_past_the_previous_edges_and_a_stale_width_never_narrows_it(width, wider, sides):
    left = np.array([width / 2]) if sides in ("both", "left") else None
    right = np.array([-width / 2]) if sides in ("both", "right") else None
    band = _search_band(P, RoadModel(left, right, width))
    unguided = _search_band(P, None)
    assert band <= unguided
    assert band >= min(width, P.max_width_m) / 2 + BAND_MARGIN_M  # the walks see past the last edges
    if sides != "both":  # a width only one side saw narrows nothing
        assert band == unguided
    else:
        assert _search_band(P, RoadModel(left, right, max(width, wider))) >= band  # wider road, wider band


@FAST
@given(
    st.floats(-3.0, 3.0),
    st.one_of(st.none(), st.floats(-1.5, 1.5)),
    st.floats(0.5, 9.0),
    seeds,
)
def test_the_band_keeps_the_points_near_the_guide_measured_across_it(c0, c1, band, seed):
    """Points placed d metres off a straight guide, along its normal: kept iff |d| <= band, with
    d as their distance; in their order. No guide: the guide is y = 0."""
    rng = np.random.default_rng(seed)
    n = 200
    along, d = rng.uniform(0.0, 25.0, n), rng.uniform(-12.0, 12.0, n)
    d[np.abs(np.abs(d) - band) < 1e-3] += 2e-3  # not on the edge, where float32 decides
    slope = 0.0 if c1 is None else c1
    tangent, normal = np.array([1.0, slope]) / math.hypot(1, slope), np.array([-slope, 1.0]) / math.hypot(1, slope)
    xy = np.array([0.0, 0.0 if c1 is None else c0]) + along[:, None] * tangent + d[:, None] * normal
    frame = LidarFrame(
        np.c_[xy, np.zeros(n)].astype(np.float32), np.zeros(n, int), np.zeros(n), np.zeros(n, int), np.zeros((1, 3))
    )
    idx = np.sort(rng.choice(n, n // 2, replace=False))  # the ROI's points: a subset, in frame order
    guide = None if c1 is None else np.array([c0, c1])
    kept, across = _within_band(frame, idx, guide, band)
    assert np.array_equal(kept, idx[np.abs(d[idx]) <= band])
    assert np.allclose(across, np.abs(d[kept]), atol=1e-4 * (1 + 25 * abs(slope)))


# ---- step 2: the rings, their references and their order -----------------------------------------


@FAST
@given(st.lists(st.integers(0, 40), max_size=60), st.booleans(), seeds)
def test_grouping_by_ring_is_a_stable_sort_that_numbers_the_rings(ids, beyond_int16, seed):
    rng = np.random.default_rng(seed)
    n = len(ids)
    ring_id = np.r_[np.array(ids, dtype=np.int64), rng.integers(0, 40, 10)] + (40_000 if beyond_int16 else 0)
    idx = rng.permutation(n + 10)[:n]  # a subset of the frame, in any order
    across = rng.uniform(0.0, 5.0, n).astype(np.float32)
    got, got_across, ring_first, ring = _group_by_ring(ring_id, idx, across)
    position = {int(i): k for k, i in enumerate(idx)}
    at = np.array([position[int(i)] for i in got], dtype=np.int64)  # where each output point came from
    assert sorted(at.tolist()) == list(range(n))
    assert np.array_equal(got_across, across[at])  # each distance stays with its point
    ids_out = ring_id[got]
    assert np.all(np.diff(ids_out) >= 0)
    assert all(np.all(np.diff(at[ids_out == r]) > 0) for r in np.unique(ids_out))  # stable within a ring
    if n:
        assert np.array_equal(ring, np.unique(ids_out, return_inverse=True)[1])
        assert np.array_equal(ring_first, np.flatnonzero(np.r_[1, np.diff(ids_out)]))


@FAST
@given(st.integers(1, 6), st.integers(1, 40), seeds)
def test_each_ring_s_reference_is_its_point_ahead_of_the_sensor_nearest_the_guide(n_rings, per_ring, seed):
    """Rings of random returns around two sensors, shuffled; guide y = 0. Per ring: θs, height,
    range and elevation of the ring's point ahead of its sensor nearest y = 0; no reach (−inf) if
    it lies farther off than reference_max_offset_m or the ring has no point ahead."""
    rng = np.random.default_rng(seed)
    origins = np.array([[3.0, 0.0, 2.9], [3.3, 0.95, 0.9]])
    sensor = np.repeat(np.arange(n_rings) % 2, per_ring)
    azimuth = rng.uniform(-PI, PI, len(sensor))
    reach_m = rng.uniform(2.0, 25.0, len(sensor))
    xyz = (
        origins[sensor]
        + np.c_[reach_m * np.cos(azimuth), reach_m * np.sin(azimuth), rng.uniform(-3.5, 0.5, len(sensor))]
    )
    ring_id = 64 * sensor + np.repeat(rng.permutation(64)[:n_rings], per_ring)
    shuffle = rng.permutation(len(sensor))
    frame = LidarFrame(xyz[shuffle].astype(np.float32), ring_id[shuffle], azimuth[shuffle], sensor[shuffle], origins)
    idx = np.arange(len(sensor))
    idx, across, ring_first, ring = _group_by_ring(frame.ring_id, idx, np.abs(frame.points[:, 1]))
    theta_s, z_ref, reach, aim = _ring_references(frame, idx, across, ring_first, ring, P)
    x, y, z = frame.points.astype(float).T
    for r in range(len(ring_first)):
        members = idx[ring == r]
        origin = origins[frame.sensor_index[members[0]]]
        ahead = members[x[members] > origin[0]]
        if len(ahead) == 0:
            assert reach[r] == -np.inf
            continue
        ref = ahead[np.argmin(np.abs(y[ahead]))]
        assert theta_s[r] == frame.azimuth[ref] and z_ref[r] == z[ref]
        d = np.array([x[ref], y[ref], z[ref]]) - origin
        assert aim[r] == pytest.approx(math.asin(d[2] / np.linalg.norm(d)), abs=1e-6)
        if abs(y[ref]) > P.reference_max_offset_m:
            assert reach[r] == -np.inf
        else:
            assert reach[r] == pytest.approx(math.hypot(d[0], d[1]), rel=1e-6)


@FAST
@given(
    st.lists(
        st.tuples(
            st.integers(0, 2),
            st.floats(-0.45, 0.05),
            st.one_of(st.just(-math.inf), st.sampled_from([4.0, 8.0]), st.floats(2.0, 60.0)),  # with ties
        ),
        min_size=1,
        max_size=12,
        unique_by=lambda r: (r[0], r[1]),
    ),
    seeds,
)
def test_a_ring_is_the_road_s_only_if_it_lands_farther_than_every_ring_aimed_lower(rows, seed):
    sensor, aim, reach = (np.array(c) for c in zip(*rows))
    finite = reach[np.isfinite(reach)]
    gaps = np.abs(finite[:, None] - finite[None, :])
    assume(np.all((gaps == 0) | (gaps > 1e-6)))  # ranges a µm apart are alike (the rings are sorted with mm in mind)
    road, below = _road_rings(reach, aim, sensor)
    for r in range(len(rows)):
        lower = np.flatnonzero((sensor == sensor[r]) & (aim < aim[r]))
        assert below[r] == (lower[np.argmax(aim[lower])] if len(lower) else -1)  # the next one down
        assert road[r] == (np.isfinite(reach[r]) and bool(np.all(reach[r] > reach[lower])))
    relabel = np.random.default_rng(seed).permutation(len(rows))  # the rings' numbers do not matter
    road_relabelled, below_relabelled = _road_rings(reach[relabel], aim[relabel], sensor[relabel])
    assert np.array_equal(road_relabelled, road[relabel])
    back = np.argsort(relabel)
    assert np.array_equal(below_relabelled, np.where(below[relabel] >= 0, back[below[relabel]], -1))


def wrap(angle):
    return (np.asarray(angle) + PI) % (2 * PI) - PI


@FAST
@given(
    st.lists(
        st.tuples(st.floats(-PI, PI, exclude_max=True), st.integers(1, 30), st.booleans()), min_size=1, max_size=4
    ),
    st.floats(-PI, PI),
    seeds,
)
def test_each_ring_is_read_in_azimuth_order_from_its_reference_within_a_quarter_turn(spec, turn, seed):
    """Algorithm 1 as the walks use it: u is θ − θs wrapped (+ to the left), whichever side of ±π
    either lies; the points beyond a quarter turn or HEIGHT_CUT_M are left out; the rest come
    ring after ring by u. Turning the whole frame about the sensor changes nothing."""
    rng = np.random.default_rng(seed)
    theta_s = np.array([s[0] for s in spec])
    counts = [s[1] for s in spec]
    road_ring = np.array([s[2] for s in spec])
    ring = np.repeat(np.arange(len(spec)), counts)
    offset = rng.uniform(-PI, PI, len(ring))
    offset[np.abs(np.abs(offset) - PI / 2) < 1e-6] = 0.1  # not on the quarter turn itself
    az = wrap(theta_s[ring] + offset)
    z = rng.uniform(-1.5, 1.5, len(ring))
    z_ref = rng.uniform(-0.2, 0.2, len(spec))
    assume(np.all(np.abs(np.abs(z - z_ref[ring]) - HEIGHT_CUT_M) > 1e-9))
    keep, u = _azimuth_order(az, z, ring, theta_s, z_ref, road_ring)
    wrapped = np.array([math.remainder(a - s, 2 * PI) for a, s in zip(az, theta_s[ring])])
    expected = road_ring[ring] & (np.abs(wrapped) < PI / 2) & (np.abs(z - z_ref[ring]) <= HEIGHT_CUT_M)
    assert sorted(keep.tolist()) == np.flatnonzero(expected).tolist()
    assert np.allclose(u, wrapped[keep], atol=1e-12)
    assert np.all(np.diff(ring[keep]) >= 0)
    assert np.all(np.diff(u)[np.diff(ring[keep]) == 0] > 0)  # by u within each ring
    turned_keep, turned_u = _azimuth_order(wrap(az + turn), z, ring, wrap(theta_s + turn), z_ref, road_ring)
    assert np.array_equal(turned_keep, keep) and np.allclose(turned_u, u, atol=1e-9)


@FAST
@given(st.lists(st.booleans(), min_size=1, max_size=8), st.integers(1, 6), seeds)
def test_the_rings_left_are_numbered_again_and_keep_the_ring_aimed_below_them(kept, per_ring, seed):
    """Rings 0..k−1 of one sensor, each aimed above the one before; those not kept drop out."""
    assume(any(kept))  # (_scan stops before, with fewer than two points left)
    rng = np.random.default_rng(seed)
    n_rings = len(kept)
    ring = np.repeat(np.arange(n_rings), per_ring)
    frame = LidarFrame(
        rng.uniform(-10, 10, (len(ring), 3)).astype(np.float32),
        ring,
        rng.uniform(-1, 1, len(ring)),
        np.zeros(len(ring), dtype=np.int64),
        np.zeros((1, 3)),
    )
    idx = np.arange(len(ring))
    ring_below = np.arange(n_rings) - 1
    theta_s = rng.uniform(-PI, PI, n_rings)
    keep = np.flatnonzero(np.array(kept)[ring])
    u = np.tile(np.linspace(-0.5, 0.5, per_ring), n_rings)[keep]
    across = np.abs(frame.points[:, 1])
    rings = _gather_rings(frame, idx, across, ring, keep, u, theta_s, ring_below)
    old = np.flatnonzero(kept)  # the old number of each ring left
    assert np.array_equal(rings.ring, np.repeat(np.arange(len(old)), per_ring))
    assert np.array_equal(rings.theta_s, theta_s[old])
    for new, o in enumerate(old):
        below = ring_below[o]
        assert rings.lower[new] == (int(np.searchsorted(old, below)) if below in old else -1)
    assert rings.x.dtype == np.float64 and np.array_equal(rings.z, frame.points[keep, 2].astype(float))
    assert np.array_equal(rings.idx, keep) and np.array_equal(rings.across, across[keep]) and rings.u is u


# ---- step 3: along the rings, the windows, eqs. 8-10 ----------------------------------------------


@FAST
@given(
    st.floats(3.0, 30.0),
    st.floats(0.002, 0.02),
    st.integers(2, 60),
    st.integers(2, 60),
    st.lists(st.tuples(st.integers(1, 120), st.floats(0.2, 3.0)), max_size=2),
    st.floats(-10.0, 10.0),
    st.floats(-10.0, 10.0),
    st.floats(-PI, PI),
)
def test_t_is_the_arc_along_the_ring_and_its_pieces_end_at_the_gaps(radius, step, right, left, gaps, ox, oy, theta_s):
    """A circle of `radius` about the sensor (the ring on flat ground) at azimuth steps `step`,
    with gaps of some metres (a shadow) after some points, and a second, gapless ring."""
    arcs = np.full(right + left, radius * step)
    for at, size in gaps:
        arcs[at % len(arcs)] += size
    assume(np.all(np.abs(arcs - GAP_M) > 0.02))
    s = np.r_[0.0, np.cumsum(arcs)]  # metres along the first ring from its right end
    u1 = (s - s[right]) / radius  # its reference is point `right`
    assume(np.all(np.abs(u1) < 1.4))
    u2 = np.arange(-5, 6) * step
    u = np.r_[u1, u2]
    r = np.r_[np.full(len(u1), radius), np.full(len(u2), 1.5 * radius)]
    ring = np.r_[np.zeros(len(u1), int), np.ones(len(u2), int)]
    x, y = ox + r * np.cos(theta_s + u), oy + r * np.sin(theta_s + u)
    rings = straight_rings(x, u, ring=ring, y=y)  # (x, y: the circles')
    along = _along_ring(rings, np.array([[ox, oy, 2.0]]))
    assert np.allclose(along.t[: len(u1)], s, atol=1e-9 * (1 + s[-1]))  # the arc length
    assert np.allclose(along.t[len(u1) :], 1.5 * radius * (u2 - u2[0]), atol=1e-9 * radius)  # from 0 again
    starts = np.flatnonzero(np.diff(along.piece, prepend=0))
    assert starts.tolist() == [0, *(1 + np.flatnonzero(arcs > GAP_M)).tolist(), len(u1)]
    assert along.reference_piece.tolist() == [along.piece[right], along.piece[len(u1) + 5]]
    assert along.ring_start.tolist() == [0, len(u1)] and along.ring_end.tolist() == [len(u1) - 1, len(u) - 1]
    for k in range(len(starts)):
        assert along.piece_first[k] == starts[k] and along.piece_last[k] == (np.r_[starts, len(u)][k + 1] - 1)
    gapless = arcs[arcs <= GAP_M]
    if len(gapless):
        assert along.spacing[0] == pytest.approx(gapless.mean(), rel=1e-9)  # the steps within pieces
    assert along.spacing[1] == pytest.approx(1.5 * radius * step, rel=1e-9)


@FAST
@given(st.floats(0.005, 0.08), st.floats(0.0, 1.0), st.floats(0.1, 1.0), st.floats(0.1, 1.0), st.floats(0.05, 0.5))
def test_the_windows_span_s_and_w_across_the_road_and_the_run_along_the_ring(spacing, slant, span, window, run_m):
    """A straight ring crossing the guide line at `slant` metres across per metre along it: the
    span and window, counted in points, reach gradient_span_m and window_m across the road (at a
    slant under MIN_SLANT, as if it were MIN_SLANT); the run reaches run_m along the ring."""
    p = RoadDetectionParams(gradient_span_m=span, window_m=window, run_m=run_m)
    k = np.arange(-250, 251)
    t = (k + 250) * spacing
    rings = straight_rings(t, k * 1e-3, across=slant * np.abs(k) * spacing)
    one_piece = dict(piece=np.ones(len(k), int), piece_first=np.zeros(1, int), piece_last=np.full(1, len(k) - 1))
    along = _Along(
        t=t,
        **one_piece,
        ring_start=np.zeros(1, int),
        ring_end=np.full(1, len(k) - 1),
        spacing=np.array([spacing]),
        reference_piece=np.ones(1, int),
    )
    reach_s, reach_w, run = _window_lengths(rings, along, p)
    far = np.abs(k) >= 100  # the slant measured on the point's own side of the reference
    across_per_point = spacing * min(max(slant, MIN_SLANT), 1.0)
    tol = 1e-4
    assert np.all(reach_s[far] * across_per_point >= span * (1 - tol))
    assert np.all((reach_s[far] - 1) * across_per_point < span * (1 + tol))
    assert np.all(reach_w >= 2) and np.all(reach_w[far] * across_per_point >= window * (1 - tol))
    assert np.all((reach_w[far] == 2) | ((reach_w[far] - 1) * across_per_point < window * (1 + tol)))
    assert np.all(run >= 2) and np.all(run * spacing >= run_m * (1 - tol))
    assert np.all((run == 2) | ((run - 1) * spacing < run_m * (1 + tol)))
    for lengths in (reach_s, reach_w):  # left as right (but for rounding where S or W is a whole number of points)
        assert np.abs(lengths - lengths[::-1]).max() <= 1


@FAST
@given(rings_with_gaps, st.integers(1, 8), st.integers(2, 12))
def test_each_window_lies_on_the_road_side_between_the_reference_and_its_point(spec, span, width):
    u, ring, piece = ring_pieces(spec)
    n = len(u)
    lo, hi, valid = _road_side_windows(u, ring, piece, np.full(n, span), np.full(n, width))
    reference = {int(ring[i]): i for i in np.flatnonzero(u == 0)}
    for i in range(n):
        side = 1 if u[i] > 0 else -1
        near = i - side * span  # the window ends S points behind the point
        if u[i] == 0:
            assert not valid[i]  # the reference is road
        elif valid[i]:
            window = np.arange(lo[i], hi[i] + 1)
            assert (hi[i] if side > 0 else lo[i]) == near
            assert np.all(ring[window] == ring[i]) and np.all(piece[window] == piece[i])
            assert np.all(side * u[window] >= 0)  # on the point's side, at most back to the reference
            assert width // 2 + 1 <= len(window) <= width + 1
        whole = np.arange(near - side * width, near + side, side)  # W + 1 points back from the span
        if (
            u[i] != 0
            and whole.min() >= 0
            and whole.max() < n
            and np.all(piece[whole] == piece[i])
            and np.all(side * (whole - reference[int(ring[i])]) > 0)
        ):
            assert valid[i]  # room for the whole window: it has one


@FAST
@given(
    st.floats(-0.3, 0.3),
    st.floats(-2.0, 2.0),
    st.floats(0.01, 0.1),
    st.integers(2, 20),
    st.one_of(st.just(0.0), st.floats(1e-3, 0.5)),
    st.floats(-5.0, 5.0),
    seeds,
)
def test_on_a_straight_slope_the_gradient_is_the_slope_and_sigma_the_height_above_it(
    slope, height, spacing, width, step, shift, seed
):
    """Eqs. 8-9's features against windows that end two points behind each point, on z = a + b·t
    with uneven steps along t; the last point raised by `step`."""
    rng = np.random.default_rng(seed)
    n = 60
    t = np.r_[0.0, np.cumsum(rng.uniform(0.5, 1.5, n - 1) * spacing)]
    z = height + slope * t
    z[-1] += step
    at = np.arange(n)
    lo, hi = np.maximum(at - 2 - width, 0), np.maximum(at - 2, 0)
    gradient, sigma, trend = _window_features(t, z, lo, hi)
    body = at[width + 2 : -1]
    assert np.allclose(gradient[body], slope, atol=1e-6) and np.allclose(sigma[body], 0.0, atol=1e-9)
    assert np.allclose(trend.slope[body], slope, atol=1e-6)
    assert sigma[-1] == pytest.approx(step, abs=1e-9)  # the height of a step above the road's trend
    assert gradient[-1] >= slope - 1e-6 and (step == 0 or gradient[-1] > gradient[-2])  # rises with it
    # the trend is the least-squares line of the window, through its mean
    noisy = z + rng.normal(0.0, 0.02, n)
    _, _, fit = _window_features(t, noisy, lo, hi)
    for i in body[::7]:
        b, a = np.polyfit(t[lo[i] : hi[i] + 1], noisy[lo[i] : hi[i] + 1], 1)
        assert fit.slope[i] == pytest.approx(b, abs=1e-6)
        assert fit.mean_z[i] == pytest.approx(a + b * fit.mean_t[i], abs=1e-9)
    # the heights' level and where t starts do not matter
    moved_gradient, moved_sigma, _ = _window_features(t + 3.0, z + shift, lo, hi)
    assert np.allclose(moved_gradient, gradient, atol=1e-6) and np.allclose(moved_sigma, sigma, atol=1e-8)


@FAST
@given(
    st.one_of(st.none(), st.floats(1.0, 5.0)),
    st.one_of(st.none(), st.floats(-5.0, -1.0)),
    st.floats(-0.04, 0.04),
    st.floats(0.01, 2.0),
    seeds,
)
def test_beyond_the_previous_boundary_grows_outwards_from_zero_on_it(left_c0, right_c0, slope, out, seed):
    """Eq. 10's Δ̂: + beyond the last frame's boundary on the point's side, − inside it, growing
    by what the point moves outwards; NaN on a side the last frame did not see."""
    rng = np.random.default_rng(seed)
    x, y = rng.uniform(0.0, 20.0, 50), rng.uniform(-8.0, 8.0, 50)
    y[0], y[1] = 1e-3, -1e-3  # one each side at least

    def rings_at(yy):
        return straight_rings(x, np.sign(yy) * 0.1, y=yy)

    left = None if left_c0 is None else np.array([left_c0, slope])
    right = None if right_c0 is None else np.array([right_c0, slope])
    previous = RoadModel(left, right, 6.0)
    assert _beyond_previous(rings_at(y), None) is None
    d = _beyond_previous(rings_at(y), previous)
    if left is None and right is None:
        assert d is None
        return
    moved = _beyond_previous(rings_at(y + np.sign(y) * out), previous)
    for side, sign, coef in ((y > 0, 1, left), (y < 0, -1, right)):
        if coef is None:
            assert np.isnan(d[side]).all()
            continue
        edge = np.polynomial.polynomial.polyval(x, coef)
        assert np.allclose(moved[side] - d[side], out)
        assert np.array_equal(d[side] > 0, sign * y[side] > sign * edge[side])
        on = _beyond_previous(rings_at(np.where(side, edge, y)), previous)  # the points moved onto it
        assert np.allclose(on[side], 0.0, atol=1e-12)


@FAST
@given(
    st.floats(0.0, 2.0),
    st.floats(0.0, 1.0),
    st.one_of(st.none(), st.floats(-5.0, 5.0)),
    st.floats(1e-3, 1.0),
    st.tuples(*(st.floats(0.0, 10.0) for _ in range(4))),
)
def test_the_score_is_a_probability_that_falls_as_the_verge_rises(gradient, sigma, beyond, more, betas):
    """Eq. 7 with weights that count a rise against the road (β3-β5, β7-β8, β10 >= 0): Pr in [0, 1],
    never higher for a steeper rise, a taller step or a point farther beyond the last boundary."""
    w = ScoreWeights(beta3=betas[0], beta4=betas[1], beta7=betas[2], beta8=betas[3])
    pr = road_score(gradient, sigma, beyond, w)
    assert 0.0 <= pr <= 1.0
    assert road_score(gradient + more, sigma, beyond, w) <= pr
    assert road_score(gradient, sigma + more, beyond, w) <= pr
    if beyond is not None:
        assert road_score(gradient, sigma, beyond + more, w) <= pr
    else:
        assert road_score(gradient, sigma, math.nan, w) == pr  # no boundary seen: eq. 10 weighs nothing


# ---- step 4: the walks ----------------------------------------------------------------------------


@FAST
@given(rings_with_gaps, st.integers(2, 5), st.floats(0.1, 0.9), seeds)
def test_a_walk_may_stop_at_the_first_of_a_run_of_non_road_points_in_its_piece(spec, run, share, seed):
    rng = np.random.default_rng(seed)
    u, ring, piece = ring_pieces(spec)
    n = len(u)
    score = np.where(rng.random(n) < share, rng.uniform(0.0, 0.49, n), rng.uniform(0.5, 1.0, n))
    stop = _stops(score, u, piece, np.full(n, run))
    for i in range(n):
        outward = 1 if u[i] > 0 else -1
        stretch = i + outward * np.arange(run)
        if stretch.min() < 0 or stretch.max() >= n:
            continue  # at the frame's first or last ring's end: the run is cut there
        assert stop[i] == bool(np.all(score[stretch] < 0.5) and np.all(piece[stretch] == piece[i]))
    # only which side of 0.5 each score lies on matters
    rescored = np.where(score >= 0.5, rng.uniform(0.5, 1.0, n), rng.uniform(0.0, 0.49, n))
    assert np.array_equal(_stops(rescored, u, piece, np.full(n, run)), stop)


def pieces_along(u, ring, piece) -> _Along:
    """_Along with the pieces of ring_pieces (t and spacing are not read)."""
    n = len(u)
    first = np.flatnonzero(np.diff(piece, prepend=0))
    ring_start = np.flatnonzero(np.diff(ring, prepend=-1))
    reference_piece = np.zeros(ring.max() + 1, dtype=piece.dtype)
    reference_piece[ring[u == 0]] = piece[u == 0]
    return _Along(
        t=np.zeros(n),
        piece=piece,
        piece_first=first,
        piece_last=np.r_[first[1:] - 1, n - 1],
        ring_start=ring_start,
        ring_end=np.r_[ring_start[1:] - 1, n - 1],
        spacing=np.ones(len(ring_start)),
        reference_piece=reference_piece,
    )


@FAST
@given(rings_with_gaps, st.sampled_from([1, -1]), st.floats(0.05, 0.5), seeds)
def test_each_walk_takes_the_stop_nearest_its_reference_in_the_reference_s_piece(spec, sign, share, seed):
    u, ring, piece = ring_pieces(spec)
    along = pieces_along(u, ring, piece)
    stop = np.random.default_rng(seed).random(len(u)) < share
    stops = _first_stops(stop & (u * sign > 0), sign, ring, along)
    assert len(np.unique(ring[stops])) == len(stops)  # at most one per ring
    for r in range(ring.max() + 1):
        candidates = np.flatnonzero(stop & (ring == r) & (u * sign > 0) & (piece == along.reference_piece[r]))
        chosen = stops[ring[stops] == r]
        if len(candidates) == 0:
            assert len(chosen) == 0  # beyond a gap, or no stop at all: the walk found none
        else:
            assert chosen.tolist() == [candidates[np.argmin(np.abs(u[candidates]))]]


@FAST
@given(
    st.floats(6.0, 10.0),
    st.floats(1.2, 1.6),
    st.floats(2.0, 4.0),
    st.sampled_from(["ravine", "floor", "shallow", "body"]),
    st.sampled_from([1, -1]),
    st.booleans(),
)
def test_a_walk_that_ends_where_the_ground_falls_away_ends_at_its_last_road_point(radius, ratio, edge, case, sign, lip):
    """Two rings of one sensor on a flat road (the one aimed lower lands nearer) whose returns end
    at |y| = edge on one side. "ravine": nothing returns beyond; "floor" / "shallow": after a
    1.5 m gap, the ground beyond lies DROP_M + 0.15 / DROP_M − 0.15 lower; "body": both rings'
    returns end at one azimuth, the lower ring's no farther than the upper's (the view ended).
    lip: the last point before the edge lies 0.1 m higher (a stone: no road, and shorter than a run)."""
    upper = ratio * radius
    last_theta = math.asin(edge / upper)

    def profile(y):
        s = sign * y
        beyond = {"floor": -(DROP_M + 0.15), "shallow": -(DROP_M - 0.15)}.get(case, math.nan)
        road = np.where(lip & (s == s[s < edge].max()), 0.1, 0.0)
        return np.where(s < edge, road, np.where(s > edge + 1.5, beyond, math.nan))

    frame = circle_frame(profile, radii=(radius, upper), step=0.004)
    if case == "body":
        seen = sign * frame.azimuth <= last_theta
        frame = LidarFrame(
            frame.points[seen], frame.ring_id[seen], frame.azimuth[seen], frame.sensor_index[seen], frame.sensor_origins
        )
    s = staged(frame)
    rings, along = s["rings"], s["along"]
    assert np.array_equal(np.unique(rings.ring), [0, 1]) and rings.lower.tolist() == [-1, 0]
    stops = _first_stops(s["stop"] & (rings.u * sign > 0), sign, rings.ring, along)
    assert not np.any(rings.ring[stops] == 1)  # the flat road never stops the walk
    ends = _open_ends(stops, sign, rings, along)
    end = ends[rings.ring[ends] == 1]
    on_road = np.flatnonzero((rings.ring == 1) & (sign * rings.y < edge) & (rings.u * sign > 0))
    assert end.tolist() == [on_road[np.argmax(sign * rings.u[on_road])]]  # the last point before the edge
    fell = _fell_away(ends, sign, rings, along, s["band"], P, P.x_max_m)
    assert fell[rings.ring[ends] == 1].tolist() == [case in ("ravine", "floor")]
    last = _last_road_points(ends[fell], sign, s["score"], rings)
    assert np.all(s["score"][last] >= 0.5) and np.all(rings.u[last] * sign > 0)
    assert np.array_equal(rings.ring[last], rings.ring[ends[fell]])  # one per walk that fell away, in its ring
    road = on_road[(s["score"][on_road] >= 0.5)]
    expected = [road[np.argmax(sign * rings.u[road])]] if case in ("ravine", "floor") else []
    assert last[rings.ring[last] == 1].tolist() == expected  # the last point scored road, short of the stone
    if expected:
        assert (expected[0] != end[0]) == lip  # the stone is no road: the boundary stops short of it
    boundary = side_boundary(s, sign)
    assert boundary[rings.ring[boundary] == 1].tolist() == expected


# ---- step 5: the hinge ------------------------------------------------------------------------------


@FAST
@given(
    st.floats(6.0, 12.0),
    st.floats(1.5, 4.0),
    st.sampled_from(["step", "kink"]),
    st.floats(0.05, 0.6),
    st.sampled_from([1, -1]),
    st.floats(0.002, 0.006),
)
def test_the_hinge_places_a_step_at_the_point_before_it_and_a_change_of_slope_at_the_kink(
    radius, edge, kind, size, sign, step
):
    """A flat road, and beyond |y| = edge on one side a step `size` high, or a verge rising at
    1/10 + 1.5·size: the walk's stop, some way up a grass slope, is moved back to where the road
    ends; on the other side nothing stops the walk."""

    def profile(y):
        s = sign * y - edge
        return np.where(s < 0, 0.0, size if kind == "step" else (0.1 + 1.5 * size) * s)

    stages = staged(circle_frame(profile, radii=(radius,), step=step))
    rings, along = stages["rings"], stages["along"]
    side = rings.u * sign > 0
    stops = _first_stops(stages["stop"] & side, sign, rings.ring, along)
    assert len(stops) == 1
    (b,) = _hinge(stops, sign, stages["reach_s"], along.t, rings.z, stages["trend"], along)
    road = np.flatnonzero(side & (sign * rings.y < edge))
    before = road[np.argmax(sign * rings.u[road])]  # the last road point
    if kind == "step":
        assert b == before
    else:
        assert b in (before, before + sign)  # within a point of the kink
    assert sign * (stops[0] - b) >= 1  # back from the stop, towards the road ...
    assert sign * (stops[0] - b) <= stages["reach_s"][stops[0]]  # ... no farther than the stop's window
    assert side_boundary(stages, sign).tolist() == [b]
    assert len(side_boundary(stages, -sign)) == 0


@FAST
@given(st.floats(6.0, 12.0), st.floats(1.0, 3.0), st.sampled_from([1, -1]), seeds)
def test_a_stop_on_flat_ground_stays_where_the_walk_stopped(radius, previous_edge, sign, seed):
    """Eq. 10 alone stops a walk on a flat road with 3 mm of noise (a previous boundary at
    |y| = previous_edge and a heavy β10): there is no kink to find, the boundary is the stop's
    predecessor."""
    noise = np.random.default_rng(seed).normal(0.0, 0.003, 1000)
    w = ScoreWeights(beta7=0.0, beta8=0.0, beta9=0.0, beta10=2.0)
    p = RoadDetectionParams(weights=w)
    previous = RoadModel(np.array([previous_edge]), np.array([-previous_edge]), 2 * previous_edge)
    stages = staged(circle_frame(lambda y: noise[: len(y)], radii=(radius,)), p, previous=previous)
    rings, along = stages["rings"], stages["along"]
    stops = _first_stops(stages["stop"] & (rings.u * sign > 0), sign, rings.ring, along)
    assert len(stops) == 1 and sign * rings.y[stops[0]] > previous_edge  # beyond the last boundary
    hinge = _hinge(stops, sign, stages["reach_s"], along.t, rings.z, stages["trend"], along)
    assert hinge.tolist() == [stops[0] - sign]


# ---- the stages in order ----------------------------------------------------------------------------


@pytest.mark.parametrize("verge", ["kerb", "grass", "ravine"])
@pytest.mark.parametrize("tracked", [False, True])
def test_scan_is_its_stages_in_order(verge, tracked):
    """What `staged` and `side_boundary` above run is what _scan gives."""

    def profile(y):
        s = np.abs(y) - 3.0
        return {"kerb": np.where(s < 0, 0.0, 0.12), "grass": 0.25 * np.maximum(s, 0.0)}.get(
            verge, np.where(s < 0, 0.0, np.nan)
        ) - 0.025 * np.minimum(np.abs(y), 3.0)

    frame = circle_frame(profile, radii=(6.0, 7.5, 9.0, 11.0))
    previous = RoadModel(np.array([2.9, 0.01]), np.array([-3.1, 0.01]), 6.0) if tracked else None
    s = staged(frame, previous=previous)
    scan = _scan(frame, np.arange(len(frame.points)), P, None, previous, P.x_max_m)
    rings = s["rings"]
    assert np.array_equal(scan.index, rings.idx) and np.array_equal(scan.score, s["score"])
    for sign, points in ((1, scan.left), (-1, scan.right)):
        b = side_boundary(s, sign)
        # one per ring; at a ravine, none from the lowest ring: no ring below it tells a drop from the view's end
        assert len(b) == (3 if verge == "ravine" else 4)
        assert np.array_equal(points, np.c_[rings.x[b], rings.y[b]])
