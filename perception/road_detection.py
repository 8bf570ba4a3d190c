"""Road detection from LiDAR rings (ARES paper §3.4.2: eqs. 7-10, Algorithm 1).

Input: one 10 Hz frame of the three LiDARs in the vehicle frame (origin at the rear-axle centre
on the road, x forward, y left, z up, metres), self-hits and ghosts filtered, ground NOT
removed: the road is recognised by the shape of the ground itself. Output: the left and right
road boundaries as polynomials y = f(x), the vehicle's lateral offset and heading relative to
the centre line between them, the road's width and a confidence. The Road Reactive Control
follows that centre line when the odometry cannot be trusted.

First iteration, ring by ring ("a window operator over the rings"):

  1. Region of interest: x_min <= x <= x_max, |y| <= half_width, and no farther across the
     guide centre line than the widest road's edge (the previous frame's, when it saw both) and
     a margin: the walks of step 4 stop before.
  2. Reference point of the ring, inside the road: its point ahead of its sensor nearest the
     guide centre line, measured across it (the previous frame's centre; on a first frame, or
     where the previous one led to no road, one grown from the near field, where y = 0 is still
     road even in the tour's tightest bend: _bootstrap_guide). Its azimuth is θs, and every
     point's azimuth relative to it, Δθ from Algorithm 1, orders the ring outwards on both
     sides, even where the ring crosses its sensor's ±π. A ring whose reference lies nearer its
     sensor than that of a ring aimed lower has met a wall or an obstacle before the ground and
     is left out; so are the points more than HEIGHT_CUT_M above or below the reference.
  3. Each point is scored against its neighbours on the road side (towards θs), along the ring
     (t: the azimuth step times the range, which the firing azimuths give better than the
     ranges do): the road-side window holds the points from S = gradient_span_m to S +
     W (window_m) behind the point, and the straight line fitted to their heights along t is
     the road's trend there ("the relative height based on the medium deviation of the
     previous data for the same ring, taking into account the displacement"):
         ∇ij = (z − mean z of the window) / distance from the window's mean t    (slope, m/m,
               signed: + rising away from the road)
         σij = max(0, z − the window's line extended to the point)              (height, m)
         Δ̂ij = distance beyond the previous frame's boundary on that side       (m, + outwards)
         Pr  = 1 / (1 + exp(β0 (β1 + ∇ + σ + d̂)))                             (eqs. 7-10)
     A step (a kerb, a wall) is a large σ at once, a drop a steep negative ∇, a change of slope
     (grass) a σ growing by the change of slope per metre past it, up to about S; the crown's
     fall and a flat open verge (−2.5 % to 0) stay below the threshold. Δ̂ leans towards where
     the boundary was (no previous frame: d̂ = 0).
  4. Walking outwards from θs, the first stop is the first of points in a row over run_m along
     the ring (at least two) with Pr < 0.5: one stray point is not an edge. The walk ends at a
     gap in the ring (the ROI cuts rings, obstacles shadow them); where the ring's returns end
     there, or its next return lies DROP_M lower, though the ring below it still returns beyond
     that azimuth, the ground fell away (a ravine too deep to return anything) and the last
     point scored road is the boundary.
  5. The stop is placed back where the road's line (the stop's window) and the verge's line (a
     straight line through the points from there to a span beyond the stop) meet: of the points
     between the window and the stop, the one after which the heights are best explained by a
     line of their own (_hinge). A step gives the point before it, a change of slope the kink
     itself rather than the point σ noticed up to a span later. At most one left and one right
     point per ring.

Second iteration: the boundary points of each side, from all rings up to fit_x_max_m, are
fitted with y = c0 + c1·x + ... by least squares in two steps (the paper's "rough draft, then
filter"): a rough draft robust to a stretch of rings that stopped short at something on the
verge (see fit_boundary) → points whose residuals are far from the others' are dropped →
refit, a line unless a higher order (up to poly_order) lowers the residuals significantly (an F
test). With both sides, they are refitted at once with one slope at x = 0 (fit_parallel). The
centre line is the mean of the two sides; with one side only, that side moved by half the
previous frame's width (confidence <= 0.5); with none, nothing is found. The vehicle is on the
road: a model whose left boundary passes right of it at x = 0, or whose right one passes left of
it, was drawn on the verge and is no road (a guide that drifted off the road would otherwise keep
the next frames there). At x = 0, across the
road: lateral offset = −centre(0)·cos(heading), + when the vehicle is left of the centre;
heading = −atan(centre'(0)), + when the vehicle points left of the road.

The β of eqs. 7-10 are, as in the paper ("calculated individually based on slopes, curves and
smooth paths"), chosen from experiments: simulated frames over every verge of the tour — a
grass shoulder with only a gentle change of slope, a rock wall, a ravine's drop, a 0.12 m kerb
and an open area (which must give no boundary), on straights and bends, the vehicle off the
centre line and turned. docs/road_detection.md tells how (`ares calibrate road`), with the
figures, and why each β has its value.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from pydantic import model_validator
from scipy.special import expit

from ares.core.config import Params, param
from ares.core.geometry import local_to_vehicle

poly = np.polynomial.polynomial  # coefficients lowest order first: y = c0 + c1 x + c2 x² ...
GAP_M = 1.0  # two points of a ring farther apart are not neighbours
DROP_M = 0.3  # a ring's next return this much lower: the ground falls away
ROI_MARGIN_M = 0.5  # a ring ending this close to the ROI's border was cut by it
TURN_MARGIN = 0.05  # ... or this close (rad) to a quarter turn from its reference
LOWER_RING_MARGIN = 0.005  # rad: where a ring's returns stop, the ring below returns this far beyond
HINGE_MIN_M = 0.02  # a stop this far off the road's line is a kink or a step to place
SLANT_M = 0.3  # a ring's slant across the road is taken over this much of it
MIN_SLANT = 0.3  # ... and a span along it is at most 1 / this times the span across
TIE_M2 = 1e-6  # squared errors closer than this are equal (1 mm on one point)
HEIGHT_CUT_M = 1.0  # points this far above or below a ring's reference are not scanned
MOVED_SAMPLES = 21  # a boundary moved into another frame is fitted again to this many points
BAND_MARGIN_M = 1.0  # the walks see this far (+ a span and a run) beyond the last edges


class ScoreWeights(Params):
    """β of eqs. 7-10; Pr = 1/(1 + exp(β0·(β1 + ∇ + σ + d̂))): the bracket < 0 means road."""

    beta0: float = param(8.0, "eq. 7: sharpness of the sigmoid (moves no boundary: only the bracket's sign does)", gt=0)
    beta1: float = param(-1.0, "eq. 7: bias; a flat point scores 1/(1 + exp(β0·β1)); −1 sets the scale of the other β")
    beta2: float = param(0.0, "eq. 8: constant of the gradient term (adds to β1)")
    beta3: float = param(8.0, "eq. 8: per unit of height gradient ∇ij (m/m, + rising away from the road)")
    beta4: float = param(5.0, "eq. 8: per ∇ij²")
    beta5: float = param(0.0, "eq. 8: per ∇ij³ (odd: would score a wall or a drop as road at large |∇|)")
    beta6: float = param(0.0, "eq. 9: constant of the relative-height term (adds to β1)")
    beta7: float = param(15.0, "eq. 9: per metre of relative height σij (above the road's trend)", unit="1/m")
    beta8: float = param(3.0, "eq. 9: per √σij (weighs small steps up)", unit="1/sqrt(m)")
    beta9: float = param(
        0.1, "eq. 10: constant of the previous-boundary term (when there is one): a tracked frame stops a little sooner"
    )
    beta10: float = param(
        0.05,
        "eq. 10: per metre beyond the previous frame's boundary; small, so that on "
        "its own it never makes flat ground in the ROI non-road (it tips borderline "
        "points, it does not invent a boundary where the verge has gone)",
        unit="1/m",
    )


class RoadDetectionParams(Params):
    """Road boundaries from LiDAR rings (ARES §3.4.2)."""

    x_min_m: float = param(0.0, "region of interest: nearest x", unit="m")
    x_max_m: float = param(25.0, "region of interest: farthest x", unit="m", gt=0)
    half_width_m: float = param(12.0, "region of interest: largest |y|", unit="m", gt=0)
    gradient_span_m: float = param(
        0.4,
        "S: a point is compared with the road-side window that ends this far behind it along its ring",
        unit="m",
        gt=0,
    )
    window_m: float = param(
        0.6, "W: that window's length along the ring (its straight line is the road's trend)", unit="m", gt=0
    )
    run_m: float = param(
        0.15,
        "points in a row scoring < 0.5 over this length along the ring (at least two) end the road",
        unit="m",
        gt=0,
    )
    reference_max_offset_m: float = param(
        1.0, "a ring is used only if it passes this close to the guide centre line ahead of its sensor", unit="m", gt=0
    )
    bootstrap_range_m: float = param(
        7.0,
        "no previous centre line: the first guess comes from boundaries up to "
        "this x, where y = 0 is still on the road, the next from twice as far",
        unit="m",
        gt=0,
    )
    weights: ScoreWeights = param(doc="β of eqs. 7-10", factory=ScoreWeights)
    poly_order: int = param(
        2,
        "highest order of each boundary's polynomial y = f(x); x = 0 lies ~4 m behind "
        "the nearest boundary point, and a cubic extrapolates the points' cm of scatter "
        "into degrees of heading there",
        ge=1,
        le=4,
    )
    order_f: float = param(
        8.0,
        "a boundary's polynomial takes the next order only if that lowers the residual "
        "sum of squares by more than this F statistic (on straight roads the quadratic "
        "term would fit the points' scatter)",
        gt=0,
    )
    fit_x_max_m: float = param(
        12.0,
        "boundary points up to this x are fitted: farther, a 30 m bend no longer "
        "looks like a parabola (its heading at x = 0 comes out ~2° off at 15 m)",
        unit="m",
        gt=0,
    )
    rough_blocks: int = param(
        6,
        "the rough draft may leave out one or two adjacent of this many stretches of x (equal counts of points)",
        ge=3,
    )
    outlier_mad: float = param(
        2.5,
        "refit without points farther than this many MADs (scaled to σ) from the median residual of the rough fit",
        gt=0,
    )
    outlier_floor_m: float = param(0.15, "... but never closer than this", unit="m", ge=0)
    min_points: int = param(5, "fewest boundary points (rings) a side's fit needs, after the outliers", ge=2)
    min_span_m: float = param(
        3.0,
        "... and the least x they must span: points bunched at one x give no "
        "direction, and a parabola through them swings wildly away from them",
        unit="m",
        ge=0,
    )
    full_support_points: int = param(10, "a side supported by this many rings has full support", ge=1)
    residual_scale_m: float = param(0.10, "confidence × exp(−rms residual / this)", unit="m", gt=0)
    min_width_m: float = param(2.5, "narrowest plausible road", unit="m", gt=0)
    max_width_m: float = param(12.0, "widest plausible road", unit="m", gt=0)
    width_tolerance_m: float = param(1.0, "confidence falls to 0 this far outside the plausible widths", unit="m", gt=0)

    @model_validator(mode="after")
    def _consistent(self):
        if self.min_points <= self.poly_order:
            raise ValueError("min_points must exceed poly_order")
        if self.x_max_m <= self.x_min_m or self.max_width_m <= self.min_width_m:
            raise ValueError("empty region of interest or range of widths")
        return self


@dataclass(frozen=True)
class LidarFrame:
    """One frame of all LiDARs in the vehicle frame."""

    points: np.ndarray  # (N, 3) x, y, z (m)
    ring_id: np.ndarray  # (N,) int >= 0, one per (sensor, laser), e.g. sensor·64 + laser
    azimuth: np.ndarray  # (N,) rad, atan2(y, x) in the point's own sensor's frame
    sensor_index: np.ndarray  # (N,) int, row of sensor_origins
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

    def seen_from(self, x: float, y: float, yaw: float, x_range: tuple[float, float]) -> RoadModel:
        """The same road in the frame of a vehicle that stands at (x, y) heading yaw in this
        model's frame: each boundary, sampled over x_range of this frame, moved into that one
        and fitted again with its own order."""

        def moved(coef: np.ndarray | None) -> np.ndarray | None:
            if coef is None:
                return None
            xs = np.linspace(*x_range, MOVED_SAMPLES)
            xv, yv = local_to_vehicle(x, y, yaw, xs, poly.polyval(xs, coef))
            return poly.polyfit(xv, yv, len(coef) - 1)

        return RoadModel(moved(self.left), moved(self.right), self.width_m)


@dataclass(frozen=True)
class BoundaryFit:
    """The two-step least-squares fit of one side."""

    coef: np.ndarray  # the refit, lowest order first
    rough: np.ndarray  # the rough draft
    inliers: np.ndarray  # (n,) bool: the points the refit used
    rms_m: float  # residual RMS of the refit over its points


@dataclass(frozen=True)
class RoadResult:
    found: bool  # a centre line with confidence > 0
    confidence: float  # [0, 1], see road_confidence
    lateral_offset_m: float  # vehicle from the centre line, across the road; + = vehicle left of it
    heading_rad: float  # vehicle's heading relative to the road; + = turned left of it
    width_m: float  # across the road at x = 0 (NaN if unknown)
    model: RoadModel  # pass it back as `previous` with the next frame
    left_points: np.ndarray  # (n, 2) x, y of the left boundary, one per ring
    right_points: np.ndarray  # (n, 2) the same on the right
    left_fit: BoundaryFit | None
    right_fit: BoundaryFit | None
    road_points_per_sensor: np.ndarray  # (S,) points scored Pr >= 0.5, per sensor
    scores: np.ndarray  # (N,) Pr of each point of the frame, NaN if not scored


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
    out = d.copy()  # −π <= Δ <= π, most points: Δ itself
    b = d < -1.5 * np.pi
    out[b] = ieee_remainder(d[b], np.pi)
    b = (d >= -1.5 * np.pi) & (d < -np.pi)
    out[b] = np.pi + np.mod(d[b], np.pi)
    b = d > np.pi
    out[b] = ieee_remainder(d[b], np.pi)
    return out[()]  # a scalar for scalars


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
    left: np.ndarray  # (n, 2) boundary points
    right: np.ndarray
    road_per_sensor: np.ndarray
    index: np.ndarray  # frame index of each scored point
    score: np.ndarray  # its Pr

    @staticmethod
    def unscored(index: np.ndarray, n_sensors: int) -> _Scan:
        """Too few points for a window: no boundary, every point taken as road."""
        return _Scan(
            np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(n_sensors, dtype=np.int64), index, np.ones(len(index))
        )


@dataclass(frozen=True)
class _Rings:
    """The points the walks read, ring after ring, each ring from its right end to its left end."""

    idx: np.ndarray  # (n,) frame index of each point
    ring: np.ndarray  # (n,) its ring, numbered 0, 1, ... in that order
    x: np.ndarray  # (n,) float64, vehicle frame (m)
    y: np.ndarray
    z: np.ndarray
    u: np.ndarray  # (n,) azimuth from the ring's reference, −Δθ of Algorithm 1: + to the left, 0 at it
    across: np.ndarray  # (n,) distance across the guide line (m)
    sensor: np.ndarray  # (n,)
    theta_s: np.ndarray  # (rings,) each ring's reference azimuth θs, in its sensor's frame
    lower: np.ndarray  # (rings,) the ring of the same sensor aimed next lower (−1: none, or not scanned)


@dataclass(frozen=True)
class _Along:
    """Where each point lies along its ring, and the ring's gapless pieces."""

    t: np.ndarray  # (n,) metres along the ring from its right end
    piece: np.ndarray  # (n,) gapless piece of each point, numbered from 1 across all rings
    piece_first: np.ndarray  # piece k runs from piece_first[k − 1] ...
    piece_last: np.ndarray  # ... to piece_last[k − 1]
    ring_start: np.ndarray  # (rings,) each ring's first point (its right end)
    ring_end: np.ndarray  # (rings,) and its last (its left end)
    spacing: np.ndarray  # (rings,) mean step between neighbours along the ring (m, at least 1 mm)
    reference_piece: np.ndarray  # (rings,) the piece of the ring's reference: beyond a gap nothing is known


@dataclass(frozen=True)
class _Trend:
    """The straight line fitted to the heights of each point's road-side window along t: the
    road's trend there, z = mean_z + slope·(t − mean_t)."""

    prefix: np.ndarray  # (5, n + 1) prefix sums of t, t², z, tz, z² with a leading 0 (for any window's sums)
    mean_t: np.ndarray  # (n,)
    mean_z: np.ndarray
    slope: np.ndarray


def _scan(
    frame: LidarFrame,
    idx: np.ndarray,
    p: RoadDetectionParams,
    guide: np.ndarray | None,
    previous: RoadModel | None,
    x_max: float,
) -> _Scan:
    """The first iteration (steps 1-5 of the module's docstring) over the points `idx` of the ROI,
    which ends at x_max: every point the walks read scored by eqs. 7-10, and at most one boundary
    point per ring and side. The references are taken nearest the `guide` centre line (None: y = 0)."""
    n_sensors = len(frame.sensor_origins)
    # step 1
    band = _search_band(p, previous)
    idx, across = _within_band(frame, idx, guide, band)
    # step 2, Algorithm 1
    idx, across, ring_first, ring = _group_by_ring(frame.ring_id, idx, across)
    if len(idx) == 0:
        return _Scan.unscored(idx, n_sensors)
    theta_s, z_ref, reach, aim = _ring_references(frame, idx, across, ring_first, ring, p)
    road_ring, ring_below = _road_rings(reach, aim, frame.sensor_index[idx[ring_first]])
    keep, u = _azimuth_order(frame.azimuth[idx], frame.points[idx, 2], ring, theta_s, z_ref, road_ring)
    if len(keep) < 2:
        return _Scan.unscored(idx[keep], n_sensors)
    rings = _gather_rings(frame, idx, across, ring, keep, u, theta_s, ring_below)
    # step 3, eqs. 7-10
    along = _along_ring(rings, frame.sensor_origins)
    reach_s, reach_w, run = _window_lengths(rings, along, p)
    lo, hi, valid = _road_side_windows(rings.u, rings.ring, along.piece, reach_s, reach_w)
    gradient, sigma, trend = _window_features(along.t, rings.z, lo, hi)
    score = road_score(gradient, sigma, _beyond_previous(rings, previous), p.weights)
    score[~valid] = 1.0  # too near the reference, or a gap, for a window: nothing to tell it from
    # steps 4-5
    stop = _stops(score, rings.u, along.piece, run)
    left, right = (_side_boundary(sign, stop, score, reach_s, rings, along, trend, band, p, x_max) for sign in (1, -1))
    per_sensor = np.bincount(frame.sensor_index[rings.idx[score >= 0.5]], minlength=n_sensors)
    x, y = rings.x, rings.y
    return _Scan(np.c_[x[left], y[left]], np.c_[x[right], y[right]], per_sensor, rings.idx, score)


def _search_band(p: RoadDetectionParams, previous: RoadModel | None) -> float:
    """Step 1: how far across the guide line the walks of step 4 can go: to the widest road's
    edge (the previous frame's, when it saw both), then a margin, a span and a run beyond."""
    band = 0.5 * p.max_width_m
    if previous is not None and previous.left is not None and previous.right is not None:
        band = min(band, 0.5 * previous.width_m)  # a width only one side saw may be stale
    return band + (BAND_MARGIN_M + p.gradient_span_m + p.run_m)


def _within_band(frame: LidarFrame, idx: np.ndarray, guide: np.ndarray | None, band: float):
    """Step 1: the points of `idx` within `band` of the guide line (y = 0 without one), and their
    distance from it, measured across it: in a bend it runs steeply across the x axis."""
    x, y = frame.points[idx, 0], frame.points[idx, 1]
    if guide is None:
        across = np.abs(y)
    else:
        g = guide.astype(np.float32)  # in the points' float32: mm do not matter here
        across = np.abs(y - poly.polyval(x, g)) / np.hypot(np.float32(1.0), poly.polyval(x, poly.polyder(g)))
    inside = across <= band
    return idx[inside], across[inside]


def _starts(ids: np.ndarray) -> np.ndarray:
    """True where a run of equal ids starts (np.r_[True, ids[1:] != ids[:-1]], without r_'s overhead)."""
    out = np.empty(len(ids), dtype=bool)
    out[:1] = True
    np.not_equal(ids[1:], ids[:-1], out=out[1:])
    return out


def _group_by_ring(ring_id: np.ndarray, idx: np.ndarray, across: np.ndarray):
    """The points ring after ring, in their order within each ring (a stable radix sort of small
    integers), then where each ring starts and the ring of each point, numbered 0, 1, ..."""
    ids = ring_id[idx]
    if np.any(ids[1:] < ids[:-1]):  # (from _roi_frame they come sorted)
        order = np.argsort(ids.astype(np.int16 if ids.max(initial=0) < 2**15 else np.int64), kind="stable")
        idx, ids, across = idx[order], ids[order], across[order]
    ring_first = np.flatnonzero(_starts(ids))
    return idx, across, ring_first, np.repeat(np.arange(len(ring_first)), np.diff(ring_first, append=len(idx)))


def _ring_references(frame: LidarFrame, idx, across, ring_first, ring, p: RoadDetectionParams):
    """Step 2: each ring's reference point, its point ahead of its sensor nearest the guide line.
    Per ring: θs (its azimuth, Algorithm 1's), its height, its horizontal range from the sensor
    (−inf: it lies more than reference_max_offset_m off the guide, the ring is not the road's) and
    the elevation of the ray that hit it."""
    x, y, z = np.take(frame.points, idx, axis=0).T
    sensor = frame.sensor_index[idx]
    offset = across.copy()
    offset[x <= np.take(frame.sensor_origins[:, 0], sensor)] = np.inf
    best = np.minimum.reduceat(offset, ring_first)
    theta_s = np.full(len(ring_first), np.nan)
    z_ref = np.zeros(len(ring_first))
    is_ref = offset == best[ring]
    theta_s[ring[is_ref]] = frame.azimuth[idx][is_ref]
    z_ref[ring[is_ref]] = z[is_ref]
    origin = frame.sensor_origins[sensor[is_ref]]
    reach = np.full(len(ring_first), -np.inf)
    reach[ring[is_ref]] = np.hypot(x[is_ref] - origin[:, 0], y[is_ref] - origin[:, 1])
    aim = np.full(len(ring_first), np.inf)
    aim[ring[is_ref]] = np.arctan2(z[is_ref] - origin[:, 2], reach[ring[is_ref]])
    reach[best > p.reference_max_offset_m] = -np.inf
    return theta_s, z_ref, reach, aim


def _road_rings(reach: np.ndarray, aim: np.ndarray, ring_sensor: np.ndarray):
    """Step 2: the rings of the road, those whose reference lies farther from their sensor than
    those of all the rings of their sensor aimed lower: a ray aimed higher that lands nearer has
    met something standing on or beside the road (a wall ahead in a bend, an obstacle) before the
    ground. Also each ring's ring of the same sensor aimed next lower (−1: none)."""
    lowest_first = np.lexsort((aim, ring_sensor))
    ring_below = np.full(len(reach), -1)
    same = ring_sensor[lowest_first[1:]] == ring_sensor[lowest_first[:-1]]
    ring_below[lowest_first[1:]] = np.where(same, lowest_first[:-1], -1)
    by_sensor = reach[lowest_first] + 1e4 * ring_sensor[lowest_first]  # the running maximum restarts per sensor
    road_ring = np.zeros(len(reach), dtype=bool)
    road_ring[lowest_first] = np.isfinite(by_sensor) & (
        by_sensor > np.concatenate(([-np.inf], np.maximum.accumulate(by_sensor)[:-1]))
    )
    return road_ring, ring_below


def _azimuth_order(az, z, ring, theta_s, z_ref, road_ring):
    """Step 2 (Algorithm 1): which points of the road rings the walks read, in what order, and
    their azimuth u from their ring's reference (u = θ − θs = −Δθ, + to the left). Only the points
    within a quarter turn of the reference (|θs − θ| below π/2, or above 3π/2 across ±π), where
    Algorithm 1 is exact: farther across ±π it folds by π, and a point behind the sensor would land
    among the points ahead. And only those within HEIGHT_CUT_M of the reference's height: no road
    lies higher or lower across one ring, and the walks stop at the foot of a wall or the lip of a
    drop before them. Returns (positions in the input, u), ring after ring, each by u."""
    ts = theta_s[ring]
    turn = np.abs(ts - az)
    keep = np.flatnonzero(
        ((turn < np.pi / 2) | (turn > 1.5 * np.pi)) & road_ring[ring] & (np.abs(z - z_ref[ring]) <= HEIGHT_CUT_M)
    )
    u = -normalized_azimuth_subtraction(az[keep], ts[keep])
    # the rings are already grouped, so the keys come in runs a stable merge sort takes as they are
    order = np.argsort(ring[keep] * 4.0 + u, kind="stable")
    return keep[order], u[order]


def _gather_rings(frame: LidarFrame, idx, across, ring, keep, u, theta_s, ring_below) -> _Rings:
    """The kept points of _azimuth_order as _Rings, the rings left numbered again from 0."""
    old = ring[keep]
    new_ring = _starts(old)
    renumbered = np.full(len(ring_below) + 1, -1)  # old ring numbers to new (−1: gone, or none)
    renumbered[old[new_ring]] = np.arange(new_ring.sum())
    idx = idx[keep]
    x, y, z = np.ascontiguousarray(np.take(frame.points, idx, axis=0).T, dtype=np.float64)
    return _Rings(
        idx,
        np.cumsum(new_ring) - 1,
        x,
        y,
        z,
        u,
        across[keep],
        frame.sensor_index[idx],
        theta_s[old[new_ring]],
        renumbered[ring_below[old[new_ring]]],
    )


def _along_ring(rings: _Rings, sensor_origins: np.ndarray) -> _Along:
    """Step 3's t: the distance along the ring, its horizontal range from the sensor times the
    azimuth step: the firing azimuths are exact, the ranges are not (a corner sensor's points lie
    1 cm apart along its ring and scatter 3 cm across it). Across a gap (the ROI cuts rings,
    obstacles shadow them, a drop returns nothing) two points are not neighbours: the rings' gapless
    pieces."""
    x, y, u, ring = rings.x, rings.y, rings.u, rings.ring
    n = len(u)
    rho = np.hypot(x - np.take(sensor_origins[:, 0], rings.sensor), y - np.take(sensor_origins[:, 1], rings.sensor))
    new_ring = _starts(ring)
    dt = np.abs(np.diff(u, prepend=u[0])) * rho
    dt[new_ring] = 0.0
    step = np.hypot(np.diff(x, prepend=x[0]), np.diff(y, prepend=y[0]))
    new_piece = new_ring | (step > GAP_M) | (dt > GAP_M)
    piece = np.cumsum(new_piece)
    T = np.cumsum(dt)
    ring_start = np.flatnonzero(new_ring)
    t = T - np.repeat(T[ring_start], np.diff(ring_start, append=n))  # from the ring's right end
    count = len(ring_start)
    steps = np.maximum(np.bincount(ring, ~new_piece, count), 1)
    spacing = np.bincount(ring, np.where(new_piece, 0.0, dt), count) / steps
    reference_piece = np.zeros(count, dtype=piece.dtype)
    reference_piece[ring[u == 0]] = piece[u == 0]
    piece_first = np.flatnonzero(new_piece)
    return _Along(
        t,
        piece,
        piece_first,
        np.append(piece_first[1:] - 1, n - 1),
        ring_start,
        np.append(ring_start[1:] - 1, n - 1),
        np.maximum(spacing, 1e-3),
        reference_piece,
    )


def _window_lengths(rings: _Rings, along: _Along, p: RoadDetectionParams):
    """Step 3's S (gradient_span_m) and W (window_m) and step 4's run (run_m), in points of each
    point's ring: (S, W, run). A verge is a profile across the road: where a ring crosses the edge
    at a slant (the corner sensors' rings near the vehicle run almost along it), a span across the
    road is a longer stretch of ring. The slant: how fast the ring moves across the guide line per
    metre along it, over the last SLANT_M of ring on the road side (the ranges' scatter allows no
    shorter), at least MIN_SLANT; the run is taken along the ring."""
    u, ring, t, across, spacing = rings.u, rings.ring, along.t, rings.across, along.spacing
    n = len(u)
    k = np.maximum(1, np.ceil(SLANT_M / spacing)).astype(np.int64)[ring]
    behind = np.clip(np.arange(n) - np.where(u > 0, k, -k), 0, n - 1)
    same = ring[behind] == ring
    slant = np.where(same, np.abs(across - across[behind]) / np.maximum(np.abs(t - t[behind]), 1e-6), 1.0)
    slant = np.clip(slant, MIN_SLANT, 1.0)
    reach_s = np.ceil(p.gradient_span_m / (spacing[ring] * slant)).astype(np.int64)
    reach_w = np.maximum(2, np.ceil(p.window_m / (spacing[ring] * slant))).astype(np.int64)
    run = np.maximum(2, np.ceil(p.run_m / spacing)).astype(np.int64)[ring]
    return reach_s, reach_w, run


def _road_side_windows(u, ring, piece, reach_s, reach_w):
    """Step 3: each point's road-side window, the points from S to S + W behind it (towards θs),
    as the inclusive index range lo..hi, and whether the point has one (else it is taken as
    road). The window stays on the point's side of the reference and in its piece: near the
    reference it is shorter, down to half its length; closer in, or across a gap, there is none."""
    n = len(u)
    left = u > 0
    outward = np.where(left, 1, -1)
    reference = np.flatnonzero(u == 0)[ring]  # one per ring (θs is one of its azimuths)
    near = np.arange(n) - outward * reach_s
    far = near - outward * reach_w
    far = np.where(left, np.maximum(far, reference), np.minimum(far, reference))
    lo, hi = np.clip(np.minimum(near, far), 0, n - 1), np.clip(np.maximum(near, far), 0, n - 1)
    valid = (outward * (near - far) >= reach_w // 2) & (piece[lo] == piece) & (piece[hi] == piece) & (u != 0)
    return lo, hi, valid


def _window_features(t, z, lo, hi):
    """Eqs. 8 and 9's ∇ij and σij of each point against its window lo..hi ("the relative height
    based on the medium deviation of the previous data for the same ring, taking into account the
    displacement"): ∇ = (z − the window's mean z) / the distance from its mean t, + rising away from
    the road; σ = the height above the window's straight line (the road's trend) extended to the
    point, >= 0. Also that line, which _hinge reads again."""
    n = len(t)
    prefix = np.zeros((5, n + 1))
    for row, values in enumerate((t, t * t, z, t * z, z * z)):
        np.cumsum(values, out=prefix[row, 1:])
    count = hi - lo + 1
    st, stt, sz, stz = (prefix[row, hi + 1] - prefix[row, lo] for row in range(4))
    mean_t, mean_z = st / count, sz / count
    slope = (stz / count - mean_t * mean_z) / np.maximum(stt / count - mean_t**2, 1e-9)
    distance = np.maximum(np.abs(t - mean_t), 1e-3)
    gradient = (z - mean_z) / distance
    sigma = np.maximum(z - mean_z - slope * (t - mean_t), 0.0)
    return gradient, sigma, _Trend(prefix, mean_t, mean_z, slope)


def _beyond_previous(rings: _Rings, previous: RoadModel | None) -> np.ndarray | None:
    """Eq. 10's Δ̂ij: how far each point lies beyond the previous frame's boundary on its side
    (m, + outwards; NaN where that side was not seen). None without a previous boundary."""
    if previous is None or (previous.left is None and previous.right is None):
        return None
    x, y = rings.x, rings.y
    left, right = rings.u > 0, rings.u < 0
    beyond = np.full(len(x), np.nan)
    if previous.left is not None:
        beyond[left] = y[left] - poly.polyval(x[left], previous.left)
    if previous.right is not None:
        beyond[right] = poly.polyval(x[right], previous.right) - y[right]
    return beyond


def _stops(score, u, piece, run):
    """Step 4: where a walk outwards from θs may stop: the first point, outwards, of `run` points
    in a row scoring < 0.5 within one piece (one stray point is not an edge)."""
    n = len(score)
    at = np.arange(n)
    nonroad = np.concatenate(([0], np.cumsum(~(score >= 0.5))))
    # (fewer points than a run, run > n: the window is cut at the end and cannot hold run non-road points)
    start = np.clip(np.where(u > 0, at, at - run + 1), 0, np.maximum(n - run, 0))
    end = np.minimum(start + run, n)
    return (nonroad[end] - nonroad[start] == run) & (piece[start] == piece) & (piece[end - 1] == piece)


def _side_boundary(sign, stop, score, reach_s, rings: _Rings, along: _Along, trend: _Trend, band, p, x_max):
    """Steps 4-5 on one side (sign +1: the left, −1: the right): the frame's boundary points there
    as positions in `rings`, at most one per ring: where its walk outwards from θs stopped, placed
    back at the hinge, or where the ground fell away, its last road point."""
    stops = _first_stops(stop & (rings.u * sign > 0), sign, rings.ring, along)
    ends = _open_ends(stops, sign, rings, along)
    last = _last_road_points(ends[_fell_away(ends, sign, rings, along, band, p, x_max)], sign, score, rings)
    b = _hinge(stops, sign, reach_s, along.t, rings.z, trend, along)
    b = b[rings.u[b] * sign > 0]
    return np.concatenate([b, last]).astype(np.int64)


def _first_stops(stop, sign, ring, along: _Along):
    """Step 4: per ring, the first of its `stop`s outwards (sign +1: leftwards) in the reference's
    piece (beyond a gap nothing is known); rings without one have none."""
    stops = np.flatnonzero(stop & (along.piece == along.reference_piece[ring]))
    stops = stops if sign > 0 else stops[::-1]
    _, first_stop = np.unique(ring[stops], return_index=True)
    return stops[first_stop]


def _open_ends(stops, sign, rings: _Rings, along: _Along):
    """Step 4: where the walks of the rings without a stop end on this side: the last point of the
    reference's piece outwards (rings whose reference's piece ends at the reference have none)."""
    found = np.zeros(len(along.ring_start), dtype=bool)
    found[rings.ring[stops]] = True
    rp = along.reference_piece
    ends = (along.piece_last if sign > 0 else along.piece_first)[rp[~found & (rp > 0)] - 1]
    return ends[rings.u[ends] * sign > 0]


def _fell_away(ends, sign, rings: _Rings, along: _Along, band, p: RoadDetectionParams, x_max):
    """Step 4: whether the ground fell away beyond each walk's end: the ring's next return lies
    DROP_M lower, or it has none though the ROI, the band and the quarter turn go on and the ring
    below it (same sensor, nearer ground) still returns beyond that azimuth (a ravine too deep to
    return anything). Where the lowest rings all stop at one azimuth, the vehicle's own body blocks
    them (the roof sensor's, at about 60° to each side): the view ended, not the ground."""
    x, y, z, u, ring, n = rings.x, rings.y, rings.z, rings.u, rings.ring, len(rings.u)
    nxt = ends + sign
    in_ring = (nxt >= 0) & (nxt < n)
    in_ring[in_ring] = ring[nxt[in_ring]] == ring[ends[in_ring]]
    inside = (
        (x[ends] > p.x_min_m + ROI_MARGIN_M)
        & (x[ends] < x_max - ROI_MARGIN_M)
        & (np.abs(y[ends]) < p.half_width_m - ROI_MARGIN_M)
        & (np.abs(u[ends]) < np.pi / 2 - TURN_MARGIN)
        & (rings.across[ends] < band - ROI_MARGIN_M)
    )
    k = ring[ends]
    j = rings.lower[k]
    extent = (u[along.ring_end] if sign > 0 else u[along.ring_start])[np.maximum(j, 0)]
    farther = (
        sign * ieee_remainder(rings.theta_s[np.maximum(j, 0)] + extent - rings.theta_s[k] - u[ends], 2 * np.pi)
        > LOWER_RING_MARGIN
    )
    inside &= (j >= 0) & farther
    nxt = np.clip(nxt, 0, n - 1)
    return np.where(in_ring, z[nxt] < z[ends] - DROP_M, inside)


def _last_road_points(ends, sign, score, rings: _Rings):
    """Step 4: the boundary of each walk that ended where the ground fell away: the last point of
    its ring scored road up to its end, on its side (fewer than a run of its last points can score
    lower: no stop there)."""
    n, at = len(score), np.arange(len(score))
    road = score >= 0.5
    if sign > 0:
        last_road = np.maximum.accumulate(np.where(road, at, -1))  # the nearest road point at or before
    else:
        last_road = np.minimum.accumulate(np.where(road, at, n)[::-1])[::-1]  # ... at or after
    last = np.clip(last_road[ends], 0, n - 1)
    return last[(rings.ring[last] == rings.ring[ends]) & (rings.u[last] * sign > 0) & (score[last] >= 0.5)]


def _sums(prefix: np.ndarray, lo, hi):
    """Sums over the index ranges lo..hi (inclusive) from a prefix-sum table with a leading 0."""
    return prefix[..., hi + 1] - prefix[..., lo]


def _hinge(stops, sign, reach_s, t, z, trend: _Trend, along: _Along):
    """Step 5: the last road point of each ring whose walk stopped at `stops` (first points of runs
    of m non-road points; sign + outwards to the left): where the road's line (the trend of the
    stop's road-side window) and the verge's line meet. Candidates c: the stop's predecessor and
    the points back to its window. For each, the heights relative to the road's line, ρ, are
    taken as 0 up to c (road) and as a straight line of their own beyond it, over the points up
    to a span past the stop (the verge); the c of least squared error wins. A step (kerb, wall)
    gives the point before it; a change of slope (grass) the kink, not the point ∇ and σ
    noticed, which comes up to a span later."""
    if len(stops) == 0:
        return stops
    piece, piece_first, piece_last = along.piece, along.piece_first, along.piece_last
    reach = reach_s[stops]
    k = np.arange(1, reach.max() + 1)
    c = stops[:, None] - sign * k[None, :]  # candidates, (b, K)
    window_end = stops - sign * reach  # the road's line reaches here
    segment_end = np.where(
        sign > 0,
        np.minimum(stops + reach, piece_last[piece[stops] - 1]),
        np.maximum(stops - reach, piece_first[piece[stops] - 1]),
    )
    ok = (k[None, :] <= reach[:, None]) & (sign * (c - window_end[:, None]) >= 0)
    c = np.where(ok, c, stops[:, None] - sign)
    # ρ = z − a − b·t with the stop's line; sums of ρ, ρ², ρt, t, t² over index ranges from the
    # prefix sums of t, t², z, tz, z²
    a = (trend.mean_z[stops] - trend.slope[stops] * trend.mean_t[stops])[:, None]
    b = trend.slope[stops][:, None]

    def sums(lo, hi):
        s_t, s_tt, s_z, s_tz, s_zz = _sums(trend.prefix, lo, hi)
        count = hi - lo + 1
        s_r = s_z - a * count - b * s_t
        s_rr = s_zz - 2 * a * s_z - 2 * b * s_tz + a * a * count + 2 * a * b * s_t + b * b * s_tt
        s_rt = s_tz - a * s_t - b * s_tt
        return count, s_r, s_rr, s_rt, s_t, s_tt

    w = window_end[:, None]
    e = segment_end[:, None]
    # road part: window end (exclusive) .. c; verge part: after c .. segment end
    road_lo, road_hi = (np.minimum(w + sign, c), np.maximum(w + sign, c))
    _, _, road_rr, _, _, _ = sums(road_lo, road_hi)
    road_rr = np.where(sign * (c - w) >= 1, road_rr, 0.0)
    verge_lo, verge_hi = np.minimum(c + sign, e), np.maximum(c + sign, e)
    n_v, s_r, s_rr, s_rt, s_t, s_tt = sums(verge_lo, verge_hi)
    var_t = np.maximum(s_tt - s_t**2 / n_v, 1e-12)
    verge_rr = s_rr - s_r**2 / n_v - (s_rt - s_r * s_t / n_v) ** 2 / var_t
    error = np.where(ok & (n_v >= 2), road_rr + np.maximum(verge_rr, 0.0), np.inf)
    # The least error; of equal ones (no kink: a stop eq. 10 made on flat ground) the candidate
    # nearest the stop, which then stays where it was.
    near_best = error <= error.min(axis=1, keepdims=True) + TIE_M2
    best = np.argmax(near_best, axis=1)
    chosen = c[np.arange(len(stops)), best]
    # Only where the stop itself stands off the road's line (a stop eq. 10 made on flat ground
    # has no kink to find).
    off_line = np.abs(z[stops] - a[:, 0] - b[:, 0] * t[stops]) >= HINGE_MIN_M
    return np.where(np.isfinite(error.min(axis=1)) & off_line, chosen, stops - sign)


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
    block = np.argsort(np.argsort(x)) * p.rough_blocks // n  # stretch of x of each point
    keeps = np.array(
        [np.ones(n, dtype=bool)]
        + [(block < a) | (block >= a + w) for w in (1, 2) for a in range(p.rough_blocks - w + 1)]
    )
    keeps = keeps[keeps.sum(axis=1) > p.poly_order].astype(float)
    # All drafts at once, by their normal equations (Vᵀ K V) c = Vᵀ K y, K = the points kept.
    V = np.vander(x, p.poly_order + 1, increasing=True)
    drafts = np.einsum(
        "cij,cj->ci", np.linalg.pinv(np.einsum("cn,ni,nj->cij", keeps, V, V)), np.einsum("cn,ni,n->ci", keeps, V, y)
    )
    cap = (2 * p.outlier_floor_m) ** 2  # a point far off costs the same however far
    rough = drafts[np.argmin(np.minimum((y[:, None] - V @ drafts.T) ** 2, cap).sum(axis=0))]
    residual = y - V @ rough
    deviation = np.abs(residual - np.median(residual))
    inliers = deviation <= max(p.outlier_mad * 1.4826 * np.median(deviation), p.outlier_floor_m)
    if inliers.sum() < p.min_points or np.ptp(x[inliers]) < p.min_span_m:
        return None
    xi, yi = x[inliers], y[inliers]
    coef = poly.polyfit(xi, yi, 1)
    rss = float(np.sum((yi - poly.polyval(xi, coef)) ** 2))
    for order in range(2, p.poly_order + 1):  # a higher order only where the points call for it
        higher = poly.polyfit(xi, yi, order)
        rss_higher = float(np.sum((yi - poly.polyval(xi, higher)) ** 2))
        dof = len(xi) - order - 1
        if dof <= 0 or (rss - rss_higher) * dof <= p.order_f * max(rss_higher, 1e-12):
            break
        coef, rss = higher, rss_higher
    rms = float(np.sqrt(rss / len(xi)))
    return BoundaryFit(coef, rough, inliers, rms)


def road_confidence(
    left: BoundaryFit | None, right: BoundaryFit | None, width_m: float, p: RoadDetectionParams
) -> float:
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
    squares = sum(f.rms_m**2 * f.inliers.sum() for f in fits) / sum(f.inliers.sum() for f in fits)
    outside = max(p.min_width_m - width_m, width_m - p.max_width_m, 0.0)
    return support * math.exp(-math.sqrt(squares) / p.residual_scale_m) * max(0.0, 1 - outside / p.width_tolerance_m)


def fit_parallel(
    left_xy: np.ndarray, left: BoundaryFit, right_xy: np.ndarray, right: BoundaryFit, p: RoadDetectionParams
) -> tuple[BoundaryFit, BoundaryFit]:
    """Both sides refitted at once with one slope at x = 0, each keeping its own offset and higher
    terms: a road's two edges run parallel beside the vehicle (in a bend too: concentric arcs
    have one tangent direction there), so a side with sharp edges steadies the heading of a
    side with soft ones. Kept only if the residual sum of squares does not grow by more than
    order_f (an F test, one parameter fewer) over the separate fits."""
    xl, yl = left_xy[left.inliers].T
    xr, yr = right_xy[right.inliers].T
    nl, nr, ol, orr = len(xl), len(xr), len(left.coef) - 1, len(right.coef) - 1
    design = np.zeros((nl + nr, 3 + (ol - 1) + (orr - 1)))
    design[:nl, 0], design[nl:, 1], design[:, 2] = 1.0, 1.0, np.r_[xl, xr]
    for k in range(2, ol + 1):
        design[:nl, 3 + k - 2] = xl**k
    for k in range(2, orr + 1):
        design[nl:, 3 + ol - 1 + k - 2] = xr**k
    solution = np.linalg.lstsq(design, np.r_[yl, yr], rcond=None)[0]
    coef_l = np.r_[solution[0], solution[2], solution[3 : 3 + ol - 1]]
    coef_r = np.r_[solution[1], solution[2], solution[3 + ol - 1 :]]
    rss_l = float(np.sum((yl - poly.polyval(xl, coef_l)) ** 2))
    rss_r = float(np.sum((yr - poly.polyval(xr, coef_r)) ** 2))
    separate = left.rms_m**2 * nl + right.rms_m**2 * nr
    dof = nl + nr - (ol + 1) - (orr + 1)
    if dof <= 0 or (rss_l + rss_r - separate) * dof > p.order_f * max(separate, 1e-12):
        return left, right
    return (
        BoundaryFit(coef_l, left.rough, left.inliers, math.sqrt(rss_l / nl)),
        BoundaryFit(coef_r, right.rough, right.inliers, math.sqrt(rss_r / nr)),
    )


def _model(scan: _Scan, p: RoadDetectionParams, previous: RoadModel | None):
    points = [b[b[:, 0] <= p.fit_x_max_m] for b in (scan.left, scan.right)]
    left, right = (fit_boundary(*b.T, p) for b in points)
    if left is not None and right is not None:
        left, right = fit_parallel(points[0], left, points[1], right, p)
    width = previous.width_m if previous is not None else None
    if left is not None and right is not None:
        centre_slope = (_slope(left.coef) + _slope(right.coef)) / 2
        width = float(left.coef[0] - right.coef[0]) / math.hypot(1.0, centre_slope)
    return (
        RoadModel(left.coef if left is not None else None, right.coef if right is not None else None, width),
        left,
        right,
    )


def detect_road(
    frame: LidarFrame, params: RoadDetectionParams | None = None, previous: RoadModel | None = None
) -> RoadResult:
    """The road in one frame; `previous` is the last frame's model (its centre line guides the
    reference points and its boundaries give eq. 10's Δ̂). Without one, or where it led to no
    road, the guide is grown from the near field (see _bootstrap_guide)."""
    p = params or RoadDetectionParams()
    x, y = frame.points[:, 0], frame.points[:, 1]
    roi = np.flatnonzero((x >= p.x_min_m) & (x <= p.x_max_m) & (np.abs(y) <= p.half_width_m))
    local, roi = _roi_frame(frame, roi)
    inside = np.arange(len(roi))
    result = None
    if previous is not None and previous.centre() is not None:
        result = _detect(local, inside, p, previous.centre(), previous)
    if result is None or not result.found:
        again = _detect(local, inside, p, _bootstrap_guide(local, inside, p, previous), previous)
        if result is None or again.confidence > result.confidence:
            result = again
    scores = np.full(len(frame.points), np.nan, dtype=np.float32)
    scores[roi] = result.scores
    return dataclasses.replace(result, scores=scores)


def _roi_frame(frame: LidarFrame, roi: np.ndarray) -> tuple[LidarFrame, np.ndarray]:
    """The points of the region of interest as a frame of their own, ring after ring, each ring in
    the frame's order (a stable sort), and their indices in the frame. Every scan of the frame
    (up to three: the bootstrap's two and the detection) reads its points from it: no scan sorts
    by ring again (_group_by_ring finds them sorted)."""
    ids = frame.ring_id[roi]
    roi = roi[np.argsort(ids.astype(np.int16 if ids.max(initial=0) < 2**15 else np.int64), kind="stable")]
    local = LidarFrame(
        np.take(frame.points, roi, axis=0),
        frame.ring_id[roi],
        frame.azimuth[roi],
        frame.sensor_index[roi],
        frame.sensor_origins,
    )
    return local, roi


def _bootstrap_guide(
    frame: LidarFrame, roi: np.ndarray, p: RoadDetectionParams, previous: RoadModel | None
) -> np.ndarray | None:
    """A centre line grown from the near field: the rings up to bootstrap_range_m, whose references
    are taken nearest y = 0 (still on the road there even in the tour's tightest bend), give a
    first centre line; with it as the guide, the rings up to twice as far give the next."""
    x = frame.points[roi, 0]
    guide = None
    for reach, order in ((p.bootstrap_range_m, 1), (2 * p.bootstrap_range_m, p.poly_order)):
        q = p.model_copy(update={"poly_order": order})  # a straight first guess: it is extrapolated far
        centre = _model(_scan(frame, roi[x <= reach], q, guide, None, reach), q, previous)[0].centre()
        guide = centre if centre is not None else guide
    return guide


def _detect(
    frame: LidarFrame, roi: np.ndarray, p: RoadDetectionParams, guide: np.ndarray | None, previous: RoadModel | None
) -> RoadResult:
    scan = _scan(frame, roi, p, guide, previous, p.x_max_m)
    model, left, right = _model(scan, p, previous)
    centre = model.centre()
    width = model.width_m if model.width_m is not None else math.nan
    confidence = road_confidence(left, right, width, p) if centre is not None else 0.0
    # The vehicle drives on the road: boundaries that leave it outside one were drawn on the verge.
    if (model.left is not None and model.left[0] <= 0.0) or (model.right is not None and model.right[0] >= 0.0):
        confidence = 0.0
    heading = offset = math.nan
    if centre is not None:
        # Across the road, not along y: perpendicular to the centre line at x = 0.
        heading = -math.atan(_slope(centre))
        offset = -float(centre[0]) * math.cos(heading)
    scores = np.full(len(frame.points), np.nan, dtype=np.float32)
    scores[scan.index] = scan.score
    return RoadResult(
        confidence > 0,
        confidence,
        offset,
        heading,
        width,
        model,
        scan.left,
        scan.right,
        left,
        right,
        scan.road_per_sensor,
        scores,
    )


def _slope(coef: np.ndarray) -> float:
    """dy/dx at x = 0."""
    return float(coef[1]) if len(coef) > 1 else 0.0
