"""Road detection from LiDAR rings (ARES paper §3.4.2: eqs. 7-10, Algorithm 1).

Input: one 10 Hz frame of the three LiDARs in the vehicle frame (origin at the rear-axle centre
on the road, x forward, y left, z up, metres), self-hits and ghosts filtered, ground NOT
removed: the road is recognised by the shape of the ground itself. Output: the left and right
road boundaries as polynomials y = f(x), the vehicle's lateral offset and heading relative to
the centre line between them, the road's width and a confidence. The Road Reactive Control
follows that centre line when the odometry cannot be trusted.

First iteration, ring by ring ("a window operator over the rings"):

  1. Region of interest: x_min <= x <= x_max, |y| <= half_width.
  2. Reference point of the ring, inside the road: its point ahead of its sensor nearest the
     guide centre line (the previous frame's centre; on a first frame, one fitted to the near
     field, where y = 0 is still on the road even in a bend). Its azimuth is θs, and every
     point's azimuth relative to it, Δθ from Algorithm 1, orders the ring outwards on both
     sides, even where the ring crosses its sensor's ±π.
  3. Each point is scored against its neighbours on the road side (towards θs):
         ∇ij = |z − z'| / horizontal distance to the neighbour at least
               gradient_span_m (and k points) away                           (slope, m/m)
         σij = |z − median z of the k nearest neighbours|                    (step, m)
         Δ̂ij = distance beyond the previous frame's boundary on that side   (m, + outwards)
         Pr  = 1 / (1 + exp(β0 (β1 + ∇ + σ + d̂)))                         (eqs. 7-10)
     A slope is what a grass verge shows, a step what a kerb, a wall or a drop shows; Δ̂
     leans towards where the boundary was (no previous frame: d̂ = 0). ∇ is taken over a
     span in metres, not in points: a ring's points lie 1 cm apart near the corner sensors and
     7 cm apart far from the roof one, and over a few cm the noise would be the gradient. Cost:
     a change of slope alone is found up to ~¾ span late (a kerb, a wall, a drop at once).
  4. Walking outwards from θs, the boundary of a side is the last point before `run` points in
     a row with Pr < 0.5 (one stray point is not an edge): at most one left and one right point
     per ring. `run` must not exceed k: past a step, the windows soon lie wholly on the verge,
     and a flat verge (the top of a kerb, a ravine's floor) scores as road again. The walk ends
     at a gap in the ring (the ROI cuts rings, obstacles shadow them): a ring whose returns
     stop (a ravine too deep to return anything) gives no boundary on that side.

Second iteration: the boundary points of each side, from all rings up to fit_x_max_m, are
fitted with y = c0 + c1·x + ... by least squares in two steps (the paper's "rough draft, then
filter"): a rough draft robust to a stretch of rings that stopped short at something on the
verge (see fit_boundary) → points whose residuals are far from the others' are dropped →
refit. The centre line is the mean of the two sides; with one side only, that side moved by
half the previous frame's width (confidence <= 0.5); with none, nothing is found. At x = 0,
across the road: lateral offset = −centre(0)·cos(heading), + when the vehicle is left of the
centre; heading = −atan(centre'(0)), + when the vehicle points left of the road.

The β of eqs. 7-10 are, as in the paper ("calculated individually based on slopes, curves and
smooth paths"), to be chosen from experiments: here from simulated runs over the verge types
of the route — a grass shoulder with only a gentle change of slope, a rock wall, a ravine's
drop, a 0.12 m kerb and an open area (which must give no boundary). The defaults below are a
first guess: a flat road scores ≈ 1, and a slope ∇ = 0.2 alone or a step σ ≈ 0.1 m alone
scores 0.5. On synthetic rings they find kerbs, walls and drops to within a ring's spacing with
up to ~1 cm of height noise; at 2 cm they fail (tune gradient_span_m, β7 and β8 together).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pydantic import model_validator
from scipy.ndimage import median_filter
from scipy.special import expit

from ares.config import Params, param

poly = np.polynomial.polynomial          # coefficients lowest order first: y = c0 + c1 x + c2 x² ...
GAP_M = 1.0                              # two points of a ring farther apart are not neighbours


class ScoreWeights(Params):
    """β of eqs. 7-10; Pr = 1/(1 + exp(β0·(β1 + ∇ + σ + d̂))): the bracket < 0 means road."""
    beta0: float = param(8.0, "eq. 7: sharpness of the sigmoid", gt=0)
    beta1: float = param(-1.0, "eq. 7: bias; a flat point scores 1/(1 + exp(β0·β1))")
    beta2: float = param(0.0, "eq. 8: constant of the gradient term")
    beta3: float = param(4.0, "eq. 8: per unit of height gradient ∇ij (m/m)")
    beta4: float = param(5.0, "eq. 8: per ∇ij²")
    beta5: float = param(0.0, "eq. 8: per ∇ij³")
    beta6: float = param(0.0, "eq. 9: constant of the relative-height term")
    beta7: float = param(5.0, "eq. 9: per metre of relative height σij", unit="1/m")
    beta8: float = param(1.5, "eq. 9: per √σij (weighs small steps up)", unit="1/sqrt(m)")
    beta9: float = param(0.0, "eq. 10: constant of the previous-boundary term (when there is one)")
    beta10: float = param(0.05, "eq. 10: per metre beyond the previous frame's boundary; small, so that on "
                                "its own it never makes flat ground in the ROI non-road (it tips borderline "
                                "points, it does not invent a boundary where the verge has gone)", unit="1/m")


class RoadDetectionParams(Params):
    """Road boundaries from LiDAR rings (ARES §3.4.2)."""
    x_min_m: float = param(0.0, "region of interest: nearest x", unit="m")
    x_max_m: float = param(25.0, "region of interest: farthest x", unit="m", gt=0)
    half_width_m: float = param(12.0, "region of interest: largest |y|", unit="m", gt=0)
    window: int = param(5, "k: σ is a point's height above the median of its k neighbours on the road side",
                        ge=1)
    gradient_span_m: float = param(0.3, "∇ is the slope towards the road-side neighbour at least this far (and k "
                                        "points) away", unit="m", gt=0)
    run: int = param(3, "m: points in a row scoring < 0.5 that end the road (<= k)", ge=1)
    reference_max_offset_m: float = param(1.0, "a ring is used only if it passes this close to the guide centre "
                                               "line ahead of its sensor", unit="m", gt=0)
    bootstrap_range_m: float = param(10.0, "no previous centre line: the first guess comes from boundaries up to "
                                           "this x, where y = 0 is still on the road", unit="m", gt=0)
    weights: ScoreWeights = param(doc="β of eqs. 7-10", factory=ScoreWeights)
    poly_order: int = param(2, "order of each boundary's polynomial y = f(x); x = 0 lies ~4 m behind the "
                               "nearest boundary point, and a cubic extrapolates the points' cm of scatter "
                               "into degrees of heading there", ge=1, le=4)
    fit_x_max_m: float = param(12.0, "boundary points up to this x are fitted: farther, a 30 m bend no longer "
                                     "looks like a parabola (its heading at x = 0 comes out ~2° off at 15 m)",
                               unit="m", gt=0)
    rough_blocks: int = param(6, "the rough draft may leave out one or two adjacent of this many stretches of x "
                                 "(equal counts of points)", ge=3)
    outlier_mad: float = param(2.5, "refit without points farther than this many MADs (scaled to σ) from the "
                                    "median residual of the rough fit", gt=0)
    outlier_floor_m: float = param(0.15, "... but never closer than this", unit="m", ge=0)
    min_points: int = param(5, "fewest boundary points (rings) a side's fit needs, after the outliers", ge=2)
    min_span_m: float = param(3.0, "... and the least x they must span: points bunched at one x give no "
                                   "direction, and a parabola through them swings wildly away from them",
                              unit="m", ge=0)
    full_support_points: int = param(10, "a side supported by this many rings has full support", ge=1)
    residual_scale_m: float = param(0.10, "confidence × exp(−rms residual / this)", unit="m", gt=0)
    min_width_m: float = param(2.5, "narrowest plausible road", unit="m", gt=0)
    max_width_m: float = param(12.0, "widest plausible road", unit="m", gt=0)
    width_tolerance_m: float = param(1.0, "confidence falls to 0 this far outside the plausible widths", unit="m",
                                     gt=0)

    @model_validator(mode="after")
    def _consistent(self):
        if self.run > self.window:
            raise ValueError("run must not exceed window: past a step the windows soon see a flat verge again")
        if self.min_points <= self.poly_order:
            raise ValueError("min_points must exceed poly_order")
        if self.x_max_m <= self.x_min_m or self.max_width_m <= self.min_width_m:
            raise ValueError("empty region of interest or range of widths")
        return self


@dataclass(frozen=True)
class LidarFrame:
    """One frame of all LiDARs in the vehicle frame."""
    points: np.ndarray          # (N, 3) x, y, z (m)
    ring_id: np.ndarray         # (N,) int >= 0, one per (sensor, laser), e.g. sensor·64 + laser
    azimuth: np.ndarray         # (N,) rad, atan2(y, x) in the point's own sensor's frame
    sensor_index: np.ndarray    # (N,) int, row of sensor_origins
    sensor_origins: np.ndarray  # (S, 3) each sensor's origin in the vehicle frame (m)


@dataclass(frozen=True)
class RoadModel:
    """The road in the vehicle frame: each boundary y = f(x) as polynomial coefficients, lowest
    order first (None: not seen), and the width (m, across the road at x = 0) that stands in
    for a missing side."""
    left: np.ndarray | None
    right: np.ndarray | None
    width_m: float | None

    def centre(self) -> np.ndarray | None:
        """Coefficients of the centre line: the mean of the two sides, or one side moved half
        the width across the road (along y, so / cos of its angle at x = 0)."""
        if self.left is not None and self.right is not None:
            return poly.polyadd(self.left, self.right) / 2
        side, sign = (self.left, -1.0) if self.left is not None else (self.right, 1.0)
        if side is None or self.width_m is None:
            return None
        shift = sign * self.width_m / 2 * math.hypot(1.0, _slope(side))
        return poly.polyadd(side, [shift])


@dataclass(frozen=True)
class BoundaryFit:
    """The two-step least-squares fit of one side."""
    coef: np.ndarray            # the refit, lowest order first
    rough: np.ndarray           # the rough draft
    inliers: np.ndarray         # (n,) bool: the points the refit used
    rms_m: float                # residual RMS of the refit over its points


@dataclass(frozen=True)
class RoadResult:
    found: bool                         # a centre line with confidence > 0
    confidence: float                   # [0, 1], see road_confidence
    lateral_offset_m: float             # vehicle from the centre line, across the road; + = vehicle left of it
    heading_rad: float                  # vehicle's heading relative to the road; + = turned left of it
    width_m: float                      # across the road at x = 0 (NaN if unknown)
    model: RoadModel                    # pass it back as `previous` with the next frame
    left_points: np.ndarray             # (n, 2) x, y of the left boundary, one per ring
    right_points: np.ndarray            # (n, 2) the same on the right
    left_fit: BoundaryFit | None
    right_fit: BoundaryFit | None
    road_points_per_sensor: np.ndarray  # (S,) points scored Pr >= 0.5, per sensor
    scores: np.ndarray                  # (N,) Pr of each point of the frame, NaN if not scored


# ---- Algorithm 1 -----------------------------------------------------------------------------

def ieee_remainder(x, y):
    """C's and IEEE 754's remainder (Python's math.remainder), vectorised: x − n·y with n = x/y
    rounded to the nearest integer, ties to even. numpy's np.remainder is the floored modulo."""
    return x - np.round(x / y) * y


def normalized_azimuth_subtraction(theta_ij, theta_s):
    """Algorithm 1, literally: Δ = θs − θij, then

        Δ < −3π/2        →  remainder(Δ, π)  = Δ + 2π
        −3π/2 <= Δ < −π  →  π + mod(Δ, π)    = Δ + 3π
        −π <= Δ <= π     →  Δ
        Δ > π            →  remainder(Δ, π)  = Δ − π below 3π/2, Δ − 2π above (a tie: even)

    with remainder the IEEE remainder and mod the floored modulo (np.mod, Python's %), as the
    names read. For every point within a quarter turn of θs (wrapped difference in (−π/2, π/2))
    all four branches give the wrapped difference, whichever side of ±π the two azimuths lie:
    that is all the detector uses. Farther away across ±π the middle branches fold by π instead
    of 2π (with C's truncating fmod for mod, the second branch would give Δ + 2π)."""
    d = np.asarray(np.subtract(theta_s, theta_ij, dtype=float))
    out = d.copy()                              # −π <= Δ <= π, most points: Δ itself
    b = d < -1.5 * np.pi
    out[b] = ieee_remainder(d[b], np.pi)
    b = (d >= -1.5 * np.pi) & (d < -np.pi)
    out[b] = np.pi + np.mod(d[b], np.pi)
    b = d > np.pi
    out[b] = ieee_remainder(d[b], np.pi)
    return out[()]                              # a scalar for scalars


# ---- eqs. 7-10 -------------------------------------------------------------------------------

def gradient_term(g, w: ScoreWeights):
    """Eq. 8: β2 + β3∇ + β4∇² + β5∇³ of the height gradient ∇ij (m/m)."""
    return w.beta2 + g * (w.beta3 + g * (w.beta4 + g * w.beta5))


def relative_height_term(s, w: ScoreWeights):
    """Eq. 9: β6 + β7σ + β8√σ of the relative height σij >= 0 (m)."""
    return w.beta6 + w.beta7 * s + w.beta8 * np.sqrt(s)


def boundary_distance_term(d, w: ScoreWeights):
    """Eq. 10: β9 + β10Δ̂ of the distance beyond the previous boundary (m); None or NaN (no
    previous boundary) gives 0, so the term is neutral."""
    if d is None:
        return 0.0
    d = np.asarray(d)
    return np.where(np.isnan(d), 0.0, w.beta9 + w.beta10 * np.nan_to_num(d))


def road_score(g, s, d, w: ScoreWeights):
    """Eq. 7: Pr = 1/(1 + exp(β0(β1 + ∇ + σ + d̂))), as the logistic expit(−x), which cannot
    overflow."""
    total = w.beta1 + gradient_term(g, w) + relative_height_term(s, w) + boundary_distance_term(d, w)
    return expit(-w.beta0 * total)


# ---- first iteration: score the rings, find one boundary point per ring and side -------------

@dataclass(frozen=True)
class _Scan:
    left: np.ndarray            # (n, 2) boundary points
    right: np.ndarray
    road_per_sensor: np.ndarray
    index: np.ndarray           # frame index of each scored point
    score: np.ndarray           # its Pr


def _scan(frame: LidarFrame, idx: np.ndarray, p: RoadDetectionParams, guide: np.ndarray | None,
          previous: RoadModel | None) -> _Scan:
    xyz = frame.points[idx].T.copy()                # (3, n): contiguous rows
    x, y = xyz[0], xyz[1]
    ring, az = frame.ring_id[idx], frame.azimuth[idx]

    # Reference of each ring: its point ahead of its sensor nearest the guide centre line.
    offset = np.abs(y - poly.polyval(x, guide)) if guide is not None else np.abs(y)
    offset[x <= frame.sensor_origins[frame.sensor_index[idx], 0]] = np.inf
    best = np.full(ring.max(initial=-1) + 1, np.inf)
    np.minimum.at(best, ring, offset)
    theta_s = np.full(best.shape, np.nan)
    is_ref = offset == best[ring]
    theta_s[ring[is_ref]] = az[is_ref]
    # Only the points within a quarter turn of the reference (|θs − θ| below π/2, or above 3π/2
    # across ±π), where Algorithm 1 is exact: farther across ±π it folds by π, and a point
    # behind the sensor would land among the points ahead. u: azimuth from the reference,
    # + to the left (Algorithm 1 gives θs − θ).
    ts = theta_s[ring]
    turn = np.abs(ts - az)
    keep = np.flatnonzero(((turn < np.pi / 2) | (turn > 1.5 * np.pi)) & (best[ring] <= p.reference_max_offset_m))
    u = -normalized_azimuth_subtraction(az[keep], ts[keep])
    idx, ring, xyz = idx[keep], ring[keep], xyz[:, keep]

    # Each ring from its right end to its left end, rings one after the other: rings first
    # (a radix sort for small integers), then by u, which is then almost sorted already for
    # points that arrive in scan order (a stable sort is a merge sort that exploits runs).
    order = np.argsort(ring.astype(np.int16 if len(best) < 2**15 else np.int64), kind="stable")
    order = order[np.argsort(ring[order] * 4.0 + u[order], kind="stable")]
    idx, ring, u = idx[order], ring[order], u[order]
    x, y, z = xyz[:, order]
    n, k, m = len(idx), p.window, p.run
    if n <= m:
        empty = np.zeros((0, 2))
        return _Scan(empty, empty, np.zeros(len(frame.sensor_origins), dtype=np.int64), idx, np.ones(n))
    left, right = u > 0, u < 0
    at = np.arange(n)

    # Steps between neighbours of a ring. Across a gap (the ROI cuts rings, obstacles shadow
    # them) two points are not neighbours: `piece` numbers the gapless pieces of the rings, and
    # the ring's spacing is the mean step within them.
    step = np.hypot(np.diff(x, prepend=x[0]), np.diff(y, prepend=y[0]))
    new_piece = np.r_[True, ring[1:] != ring[:-1]] | (step > GAP_M)
    piece = np.cumsum(new_piece)
    spacing = np.bincount(ring, np.where(new_piece, 0, step), len(best)) / np.maximum(
        np.bincount(ring[~new_piece], None, len(best)), 1)

    # Road-side neighbours: before a left point, after a right point. σ: the median of the k
    # nearest (scipy's median_filter centres a window of k on index c as c − k//2 .. c − k//2 +
    # k − 1, so `mid` is that window's c). ∇: towards the neighbour at least gradient_span_m
    # away (and k points): over a few centimetres, the sensor's noise would be the gradient.
    reach = np.maximum(k, np.ceil(p.gradient_span_m / np.maximum(spacing, 1e-3))).astype(np.int64)[ring]
    far = np.clip(np.where(left, at - reach, at + reach), 0, n - 1)
    mid = np.clip(np.where(left, at - k + k // 2, at + 1 + k // 2), 0, n - 1)
    valid = (piece[far] == piece) & (np.abs(far - at) == reach) & (u != 0)
    gradient = np.abs(z - z[far]) / np.maximum(np.hypot(x - x[far], y - y[far]), 1e-3)
    sigma = np.abs(z - median_filter(z, size=k, mode="nearest")[mid])
    beyond = None
    if previous is not None and (previous.left is not None or previous.right is not None):
        beyond = np.full(n, np.nan, dtype=np.float32)
        if previous.left is not None:
            beyond[left] = y[left] - poly.polyval(x[left], previous.left)
        if previous.right is not None:
            beyond[right] = poly.polyval(x[right], previous.right) - y[right]
    score = road_score(gradient, sigma, beyond, p.weights)
    score[~valid] = 1.0

    # Stops: the first point of a run of m non-road points, outwards.
    nonroad = np.r_[0, np.cumsum(score < 0.5)]
    start = np.clip(np.where(left, at, at - m + 1), 0, n - m)
    stop = (nonroad[start + m] - nonroad[start] == m) & (piece[start] == piece) & (piece[start + m - 1] == piece)

    # The boundary is the last point before the first stop outwards, in the reference's piece
    # (beyond a gap, nothing is known), and not the reference itself.
    stops = np.flatnonzero(stop & left)
    _, first = np.unique(ring[stops], return_index=True)
    b_left = stops[first] - 1
    stops = np.flatnonzero(stop & right)[::-1]
    _, first = np.unique(ring[stops], return_index=True)
    b_right = stops[first] + 1
    reference_piece = np.zeros(len(best), dtype=piece.dtype)
    reference_piece[ring[u == 0]] = piece[u == 0]
    b_left = b_left[(u[b_left] > 0) & (piece[b_left] == reference_piece[ring[b_left]])]
    b_right = b_right[(u[b_right] < 0) & (piece[b_right] == reference_piece[ring[b_right]])]

    per_sensor = np.bincount(frame.sensor_index[idx[score >= 0.5]], minlength=len(frame.sensor_origins))
    return _Scan(np.c_[x[b_left], y[b_left]].astype(float), np.c_[x[b_right], y[b_right]].astype(float),
                 per_sensor, idx, score)


# ---- second iteration: the road model --------------------------------------------------------

def fit_boundary(x: np.ndarray, y: np.ndarray, p: RoadDetectionParams) -> BoundaryFit | None:
    """y = f(x) in two steps (the paper's "rough draft", then "filter ... and extract the outliers").

    Rough draft: of the least-squares fits to all points and to all but one stretch of x (one or
    two adjacent of `rough_blocks` stretches of equal count), the one whose median absolute
    residual is least. A parked car or a bush on the verge hides the edge from a run of rings in
    a row; a plain least-squares draft is pulled towards them, most of all at the ends of the
    range, where it then flags good points instead (4 m off at x = 0 for a box at x = 4-5 m).
    Filter: the points whose residual lies farther from the median residual than
    max(outlier_mad·1.4826·MAD, outlier_floor_m) are dropped (1.4826·MAD estimates σ of the
    good ones); the rest are fitted again by least squares.
    None if fewer than min_points remain, or they span less than min_span_m in x."""
    n = len(x)
    if n < p.min_points or np.ptp(x) < p.min_span_m:
        return None
    block = np.argsort(np.argsort(x)) * p.rough_blocks // n          # stretch of x of each point
    keeps = np.array([np.ones(n, dtype=bool)] + [(block < a) | (block >= a + w)
                                                 for w in (1, 2) for a in range(p.rough_blocks - w + 1)])
    keeps = keeps[keeps.sum(axis=1) > p.poly_order].astype(float)
    # All drafts at once, by their normal equations (Vᵀ K V) c = Vᵀ K y, K = the points kept.
    V = np.vander(x, p.poly_order + 1, increasing=True)
    drafts = np.einsum("cij,cj->ci", np.linalg.pinv(np.einsum("cn,ni,nj->cij", keeps, V, V)),
                       np.einsum("cn,ni,n->ci", keeps, V, y))
    rough = drafts[np.argmin(np.median(np.abs(y[:, None] - V @ drafts.T), axis=0))]
    residual = y - V @ rough
    deviation = np.abs(residual - np.median(residual))
    inliers = deviation <= max(p.outlier_mad * 1.4826 * np.median(deviation), p.outlier_floor_m)
    if inliers.sum() < p.min_points or np.ptp(x[inliers]) < p.min_span_m:
        return None
    coef = poly.polyfit(x[inliers], y[inliers], p.poly_order)
    rms = float(np.sqrt(np.mean((y[inliers] - poly.polyval(x[inliers], coef)) ** 2)))
    return BoundaryFit(coef, rough, inliers, rms)


def road_confidence(left: BoundaryFit | None, right: BoundaryFit | None, width_m: float,
                    p: RoadDetectionParams) -> float:
    """support × fit × width, each in [0, 1]:
         support = mean over the two sides of min(1, rings used / full_support_points)
                   (a missing side counts 0, so one side alone gives at most 0.5);
         fit     = exp(−rms / residual_scale_m), rms of the refits' residuals over both sides;
         width   = 1 inside [min_width_m, max_width_m], falling linearly to 0 at
                   width_tolerance_m outside (0 if the width is unknown)."""
    fits = [f for f in (left, right) if f is not None]
    if not fits or not math.isfinite(width_m):
        return 0.0
    support = sum(min(1.0, f.inliers.sum() / p.full_support_points) for f in fits) / 2
    squares = sum(f.rms_m ** 2 * f.inliers.sum() for f in fits) / sum(f.inliers.sum() for f in fits)
    outside = max(p.min_width_m - width_m, width_m - p.max_width_m, 0.0)
    return support * math.exp(-math.sqrt(squares) / p.residual_scale_m) * max(0.0, 1 - outside / p.width_tolerance_m)


def _model(scan: _Scan, p: RoadDetectionParams, previous: RoadModel | None):
    left, right = (fit_boundary(*b[b[:, 0] <= p.fit_x_max_m].T, p) for b in (scan.left, scan.right))
    width = previous.width_m if previous is not None else None
    if left is not None and right is not None:
        centre_slope = (_slope(left.coef) + _slope(right.coef)) / 2
        width = float(left.coef[0] - right.coef[0]) / math.hypot(1.0, centre_slope)
    return RoadModel(left.coef if left is not None else None, right.coef if right is not None else None,
                     width), left, right


def detect_road(frame: LidarFrame, params: RoadDetectionParams | None = None,
                previous: RoadModel | None = None) -> RoadResult:
    """The road in one frame; `previous` is the last frame's model (its centre line guides the
    reference points and its boundaries give eq. 10's Δ̂)."""
    p = params or RoadDetectionParams()
    x, y = frame.points[:, 0], frame.points[:, 1]
    roi = np.flatnonzero((x >= p.x_min_m) & (x <= p.x_max_m) & (np.abs(y) <= p.half_width_m))

    guide = previous.centre() if previous is not None else None
    if guide is None:               # first frame: a centre line from the near field, where y = 0 is road
        near = _scan(frame, roi[x[roi] <= p.bootstrap_range_m], p, None, None)
        guide = _model(near, p, previous)[0].centre()
    scan = _scan(frame, roi, p, guide, previous)
    model, left, right = _model(scan, p, previous)

    centre = model.centre()
    width = model.width_m if model.width_m is not None else math.nan
    confidence = road_confidence(left, right, width, p) if centre is not None else 0.0
    heading = offset = math.nan
    if centre is not None:
        # Across the road, not along y: perpendicular to the centre line at x = 0.
        heading = -math.atan(_slope(centre))
        offset = -float(centre[0]) * math.cos(heading)
    scores = np.full(len(frame.points), np.nan, dtype=np.float32)
    scores[scan.index] = scan.score
    return RoadResult(confidence > 0, confidence, offset, heading, width, model, scan.left, scan.right,
                      left, right, scan.road_per_sensor, scores)


def _slope(coef: np.ndarray) -> float:
    """dy/dx at x = 0."""
    return float(coef[1]) if len(coef) > 1 else 0.0

