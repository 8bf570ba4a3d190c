"""What a headless run measures: the lap (cross-track error of the true pose against the route)
and the localization (the fused estimate and the odometry score against the simulator's truth).
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, field

import numpy as np

from ares.core.geometry import wrap_angle
from ares.core.route import Route

SETTLE_S = 2.0  # after the start and after RTK comes or goes, the filter gets this long
MOVING_MPS = 0.5  # the vehicle counts as under way from this speed
BOUNDARY_S = 0.1  # samples this close to an RTK change are not attributed to either side


def _rmse(values) -> float | None:
    return round(float(np.sqrt(np.mean(np.square(values)))), 4) if len(values) else None


def _round(value, digits=4):
    return None if value is None else round(float(value), digits)


@dataclass
class LapTracker:
    """Progress and cross-track error of the true pose along the route."""

    route: Route
    s_hint: float | None = None
    travelled_m: float = 0.0
    odometer_start: float | None = None
    odometer_m: float = 0.0
    xte: list[float] = field(default_factory=list)
    xs: list[float] = field(default_factory=list)
    ys: list[float] = field(default_factory=list)
    progress: list[float] = field(default_factory=list)

    def update(self, x: float, y: float, odometer: float) -> None:
        s, xte, _ = self.route.project(x, y, self.s_hint)
        if self.s_hint is not None:
            self.travelled_m += self.route.step_between(self.s_hint, s)
        self.s_hint = s
        if self.odometer_start is None:
            self.odometer_start = odometer
        self.odometer_m = odometer - self.odometer_start
        self.xte.append(xte)
        self.xs.append(x)
        self.ys.append(y)
        self.progress.append(self.travelled_m)

    def summary(self) -> dict:
        err = np.abs(np.array(self.xte)) if self.xte else np.array([math.nan])
        worst = int(np.argmax(err)) if self.xte else None
        return {
            "distance_m": round(self.odometer_m, 2),
            "xte_rmse_m": round(float(np.sqrt(np.mean(err**2))), 4),
            "xte_max_m": round(float(np.max(err)), 4),
            "xte_max_at_m": None if worst is None else round(self.progress[worst], 1),
        }


@dataclass
class LocalizationTracker:
    """Pairs each pose estimate and odometry score with the truth at the same stack time.

    Nothing counts until SETTLE_S after both the first estimate and the vehicle getting under way:
    before the first GNSS fix there is no estimate (score 0, by design) and, until the vehicle
    moves, the heading is the magnetometer's offset guess. Then `rtk` samples are those where the
    simulator's GNSS has had RTK corrections for SETTLE_S; `deadzone` samples are inside an
    RTK-loss zone (for the score: after SETTLE_S in it, as the issue asks; for the position
    error: everywhere in it).
    """

    truth_t: list[float] = field(default_factory=list)
    truth: list[tuple[float, float, float, bool]] = field(default_factory=list)  # x, y, yaw, rtk
    rtk_since: float | None = None  # stack time RTK availability last changed
    rtk_now: bool | None = None
    moving_since: float | None = None  # the filter's heading converges once the vehicle moves
    first_pose_t: float | None = None
    pos_err_rtk: list[float] = field(default_factory=list)
    pos_err_dead: list[float] = field(default_factory=list)
    yaw_err_rtk: list[float] = field(default_factory=list)
    score_rtk: list[float] = field(default_factory=list)
    score_dead: list[float] = field(default_factory=list)
    changes: list[tuple[float, bool]] = field(default_factory=list)  # (t, rtk available from t)
    pending: list[tuple[str, float, tuple]] = field(default_factory=list)  # newer than the truth so far

    def add_truth(self, t: float, x: float, y: float, yaw: float, rtk: bool, v: float) -> None:
        if self.moving_since is None and v >= MOVING_MPS:
            self.moving_since = t
        if rtk != self.rtk_now:
            self.changes.append((t, rtk))
            self.rtk_now = rtk
        self.truth_t.append(t)
        self.truth.append((x, y, yaw, rtk))
        if self.pending and self.pending[0][1] <= t:
            ready = [p for p in self.pending if p[1] <= t]
            self.pending = [p for p in self.pending if p[1] > t]
            for kind, pt, values in ready:
                (self.add_pose if kind == "pose" else self.add_score)(pt, *values)

    def _truth_at(self, t: float):
        i = bisect.bisect_left(self.truth_t, t)
        if i == 0 or i >= len(self.truth_t):
            return None
        t0, t1 = self.truth_t[i - 1], self.truth_t[i]
        if t1 - t0 > 0.5:
            return None
        f = (t - t0) / (t1 - t0) if t1 > t0 else 0.0
        (x0, y0, a0, r0), (x1, y1, a1, r1) = self.truth[i - 1], self.truth[i]
        yaw = a0 + f * wrap_angle(a1 - a0)
        return x0 + f * (x1 - x0), y0 + f * (y1 - y0), yaw, (r0 if f < 0.5 else r1)

    def _settled_for(self, t: float) -> float:
        """Stack seconds since the start or the last change of RTK availability before t; minus
        infinity right at a change, where the truth's sampling cannot tell which side t is on."""
        if self.moving_since is None or self.first_pose_t is None:
            return -math.inf
        last = max(self.moving_since, self.first_pose_t)
        for change_t, _ in self.changes[1:]:
            if abs(change_t - t) <= BOUNDARY_S:
                return -math.inf
            if change_t <= t:
                last = change_t
        return t - last

    def _wait_for_truth(self, kind: str, t: float, values: tuple) -> bool:
        if self.truth_t and t > self.truth_t[-1]:
            self.pending.append((kind, t, values))
            return True
        return False

    def add_pose(self, t: float, x: float, y: float, yaw: float) -> None:
        if self.first_pose_t is None:
            self.first_pose_t = t
        if self._wait_for_truth("pose", t, (x, y, yaw)):
            return
        truth = self._truth_at(t)
        if truth is None:
            return
        tx, ty, tyaw, rtk = truth
        err = math.hypot(x - tx, y - ty)
        if rtk and self._settled_for(t) >= SETTLE_S:
            self.pos_err_rtk.append(err)
            self.yaw_err_rtk.append(math.degrees(wrap_angle(yaw - tyaw)))
        elif not rtk and self._settled_for(t) >= 0:
            self.pos_err_dead.append(err)

    def add_score(self, t: float, score: float) -> None:
        if self._wait_for_truth("score", t, (score,)):
            return
        truth = self._truth_at(t)
        if truth is None:
            return
        settled = self._settled_for(t) >= SETTLE_S
        if truth[3] and settled:
            self.score_rtk.append(score)
        elif not truth[3] and settled:
            self.score_dead.append(score)

    def summary(self) -> dict:
        return {
            "loc_rmse_rtk_m": _rmse(self.pos_err_rtk),
            "yaw_rmse_deg": _rmse(self.yaw_err_rtk),
            "loc_max_deadzone_m": _round(max(self.pos_err_dead)) if self.pos_err_dead else None,
            "score_min_rtk": _round(min(self.score_rtk)) if self.score_rtk else None,
            "score_max_deadzone": _round(max(self.score_dead)) if self.score_dead else None,
            "loc_samples_rtk": len(self.pos_err_rtk),
            "loc_samples_deadzone": len(self.pos_err_dead),
        }
