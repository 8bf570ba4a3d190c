"""What a headless run measures of control: who drove when, the switches and their causes, the
cross-track error while road reactive control drove, the ride's comfort and the MPC's solve times.

Each truth sample is attributed to the controller in charge at its time (the latest
control/status at or before it). Comfort comes from the simulator's truth: lateral acceleration
v·ω, and jerk as the rate of change of the (longitudinal, lateral) acceleration vector, both
averaged over JERK_BIN_S bins first (the plant's road roughness shakes the raw samples; a
passenger feels the bins).
"""

from __future__ import annotations

import bisect
import collections
from dataclasses import dataclass, field

import numpy as np

from ares.core.stats import percentile

JERK_BIN_S = 0.1
MPC_PERIOD_S = 0.1  # 10 Hz: a solve longer than this misses its deadline


@dataclass
class ControlTracker:
    status_t: list[float] = field(default_factory=list)
    status_controller: list[str] = field(default_factory=list)
    truth_t: list[float] = field(default_factory=list)
    truth_xte: list[float] = field(default_factory=list)
    truth_accel: list[tuple[float, float]] = field(default_factory=list)  # longitudinal, lateral
    switch_causes: collections.Counter = field(default_factory=collections.Counter)
    mpc_solve_ms: list[float] = field(default_factory=list)
    mpc_stale: int = 0  # candidates answered with a reused solution

    def add_status(self, t: float, controller: str) -> None:
        if self.status_t and t < self.status_t[-1]:
            return  # out of order: keep the time line sorted
        self.status_t.append(t)
        self.status_controller.append(controller)

    def add_truth(self, t: float, xte: float, v: float, yaw_rate: float, accel: float) -> None:
        self.truth_t.append(t)
        self.truth_xte.append(xte)
        self.truth_accel.append((accel, v * yaw_rate))

    def add_switch(self, data: dict) -> None:
        self.switch_causes[f"{data.get('from')}->{data.get('to')}: {data.get('cause')}"] += 1

    def add_mpc(self, solve_ms: float | None, fresh: bool) -> None:
        if solve_ms is not None:
            self.mpc_solve_ms.append(solve_ms)
        if not fresh:
            self.mpc_stale += 1

    def in_charge(self) -> list[str | None]:
        """The controller in charge at each truth sample."""
        out: list[str | None] = []
        for t in self.truth_t:
            k = bisect.bisect_right(self.status_t, t) - 1
            out.append(self.status_controller[k] if k >= 0 else None)
        return out

    def summary(self) -> dict:
        who = self.in_charge()
        counted = [c for c in who if c is not None]
        share = collections.Counter(counted)
        rrc = np.abs([x for x, c in zip(self.truth_xte, who) if c == "rrc"])
        solves = np.array(self.mpc_solve_ms)
        return {
            "controller_time_share": {c: round(n / len(counted), 4) for c, n in sorted(share.items())},
            "switches": int(sum(self.switch_causes.values())),
            "switch_reasons": dict(sorted(self.switch_causes.items())),
            "xte_rmse_rrc_m": round(float(np.sqrt(np.mean(rrc**2))), 4) if len(rrc) else None,
            "xte_max_rrc_m": round(float(np.max(rrc)), 4) if len(rrc) else None,
            **self.comfort(),
            "mpc_solves": int(len(solves)),
            "mpc_solve_p50_ms": percentile(solves, 50, 3),
            "mpc_solve_p99_ms": percentile(solves, 99, 3),
            "mpc_deadline_misses": int(np.sum(solves > MPC_PERIOD_S * 1e3)) + self.mpc_stale,
        }

    def comfort(self) -> dict:
        if len(self.truth_t) < 2:
            return {"lat_accel_max_mps2": None, "jerk_rms_mps3": None}
        t = np.array(self.truth_t)
        acc = np.array(self.truth_accel)
        bins = np.floor((t - t[0]) / JERK_BIN_S).astype(int)
        counts = np.bincount(bins)
        keep = counts > 0
        mean = np.stack([np.bincount(bins, acc[:, i]) for i in (0, 1)], axis=1)[keep] / counts[keep, None]
        index = np.nonzero(keep)[0]
        consecutive = np.diff(index) == 1
        jerk = np.linalg.norm(np.diff(mean, axis=0), axis=1)[consecutive] / JERK_BIN_S
        return {
            "lat_accel_max_mps2": round(float(np.max(np.abs(mean[:, 1]))), 3),
            "jerk_rms_mps3": round(float(np.sqrt(np.mean(jerk**2))), 3) if len(jerk) else None,
        }
