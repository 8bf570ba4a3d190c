"""`ares route coverage`: where along a route the RTK corrections and an RTK fix are to be had
(after the ARES paper's Figure 3, the map of its route coloured by the receiver's fix: 95 % of it
with RTK), and the share of the route covered.

Two sources:
- **simulated** (`coverage_simulated`): the route driven at the speed manager's profile, the
  simulated receiver and its 4G link along it (simulator/corrections.py: the tour's `no_4g` zones,
  where the corrections stop and the fix degrades as they age, and its `rtk_loss` zones, where the
  sky is blocked), a fix every 0.2 s;
- **recorded** (`coverage_recorded`): a black box's records of a run (each second's position, and
  its corrections' link and fix quality), placed on the route by the nearest route point.

The route is cut into 1 m stretches; a stretch's fix is the one most often seen there. The share
covered is the share of the stretches driven that had RTK fixed (and, apart, whose corrections
arrived).
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from ares.core.messages import FIX_QUALITY_NAMES, VehicleRecord
from ares.core.route import Route

FIELDS = set(VehicleRecord.model_fields)

FIX_COLOURS = {4: "#15803d", 5: "#eab308", 2: "#f97316", 1: "#dc2626", 0: "#6b7280"}
STRETCH_M = 1.0


@dataclass
class CoverageResult:
    route: str
    source: str  # "simulated", or the black box's store
    length_m: float
    samples: int
    rtk_fixed_share: float  # of the stretches driven
    corrections_share: float | None  # ... whose corrections arrived (None: not known)
    fix_shares: dict[str, float]  # fix kind -> share of the stretches driven
    driven_share: float  # of the route's length, stretches with a sample
    stretch_fix: np.ndarray = field(repr=False)  # per stretch: the GGA quality most seen, -1 not driven
    stretch_link: np.ndarray = field(repr=False)  # per stretch: 1 corrections arrived, 0 not, -1 unknown

    def summary(self) -> dict[str, Any]:
        return {
            "route": self.route,
            "source": self.source,
            "length_m": round(self.length_m, 1),
            "samples": self.samples,
            "rtk_fixed_share": round(self.rtk_fixed_share, 4),
            "corrections_share": None if self.corrections_share is None else round(self.corrections_share, 4),
            "fix_shares": {k: round(v, 4) for k, v in self.fix_shares.items()},
            "driven_share": round(self.driven_share, 4),
        }


def _stretches(route: Route, s: np.ndarray, quality: np.ndarray, link: np.ndarray | None) -> tuple:
    n = max(int(np.ceil(route.length / STRETCH_M)), 1)
    index = np.clip((np.mod(s, route.length) / STRETCH_M).astype(int), 0, n - 1)
    fix = np.full(n, -1, dtype=int)
    up = np.full(n, -1, dtype=int)
    for k in np.unique(index):
        here = index == k
        fix[k] = Counter(quality[here].tolist()).most_common(1)[0][0]
        if link is not None:
            up[k] = int(np.mean(link[here]) >= 0.5)
    return fix, up


def _result(route: Route, source: str, s: np.ndarray, quality: np.ndarray, link: np.ndarray | None) -> CoverageResult:
    fix, up = _stretches(route, s, quality, link)
    driven = fix >= 0
    total = max(int(driven.sum()), 1)
    shares = {
        FIX_QUALITY_NAMES.get(q, f"quality {q}"): float(np.sum(fix == q)) / total for q in sorted(set(fix[driven]))
    }
    return CoverageResult(
        route=route.name,
        source=source,
        length_m=route.length,
        samples=len(s),
        rtk_fixed_share=float(np.sum(fix == 4)) / total,
        corrections_share=None if link is None else float(np.sum(up == 1)) / total,
        fix_shares=shares,
        driven_share=float(driven.mean()),
        stretch_fix=fix,
        stretch_link=up,
    )


def coverage_simulated(cfg: dict) -> CoverageResult:
    """The run configuration's route, driven once round at its speed profile, by the simulated receiver."""
    from ares.core import config
    from ares.core.geodesy import LocalFrame
    from ares.core.route import load_route
    from managers.speed import SpeedProfileParams, SpeedTable
    from simulator.params import SimParams
    from simulator.sensors import GnssSensor

    core = config.core(cfg)
    route = load_route(core)
    sim = config.section(cfg, "sim", SimParams)
    table = SpeedTable(route, config.section(cfg, "speed_profile", SpeedProfileParams), core.vehicle_profile)
    speed = np.maximum(table.profile, 0.3)  # m/s at each route sample (a standstill nowhere)
    step = np.diff(np.append(route.s, route.length))  # the last sample to the start again
    arrival = np.concatenate([[0.0], np.cumsum(step / speed)])[:-1]  # the time each route sample is reached
    gnss = GnssSensor(route, sim.gnss, LocalFrame(core.origin_utm), noise=False)
    assert gnss.link is not None  # plain simulation's 4G model
    times = np.arange(0.0, float(arrival[-1]) + float(step[-1] / speed[-1]), 1.0 / sim.gnss_hz)
    s = np.interp(times, arrival, route.s)
    quality = np.empty(len(times), dtype=int)
    link = np.empty(len(times), dtype=bool)
    for i, (t, si) in enumerate(zip(times, s, strict=True)):
        gnss.take_corrections(float(si), float(t))
        quality[i] = gnss.fix_kind(float(si), float(t)).quality
        link[i] = gnss.link.up(float(si), float(t))
    return _result(route, "simulated", s, quality, link)


def coverage_recorded(cfg: dict, store_uri: str, vehicle_id: str | None = None) -> CoverageResult:
    """A black box's records of the run configuration's route: each second's fix, where it was."""
    from ares.core import config
    from ares.core.route import load_route
    from blackbox.register.store.open_store import open_store

    route = load_route(config.core(cfg))
    store = open_store(store_uri)
    start, end = datetime(1970, 1, 1, tzinfo=UTC), datetime(2200, 1, 1, tzinfo=UTC)
    rows: list[VehicleRecord] = []
    try:
        vehicles = [vehicle_id] if vehicle_id else store.vehicles()
        if not vehicles:
            raise ValueError(f"{store_uri}: no vehicle's records in it")
        for vehicle in vehicles:
            taken = 0
            while True:
                page = store.records(vehicle, start, end, skip=taken, limit=5000)
                rows += [VehicleRecord.model_validate({k: v for k, v in d.items() if k in FIELDS}) for d in page]
                taken += len(page)
                if len(page) < 5000:
                    break
    finally:
        store.close()
    kept = [
        r
        for r in rows
        if r.position is not None and r.corrections is not None and r.corrections.fix_quality is not None
    ]
    if not kept:
        raise ValueError(f"{store_uri}: no record with a position and its fix ({len(rows)} records)")
    from scipy.spatial import cKDTree

    xy = np.array([(r.position.x, r.position.y) for r in kept])
    _, nearest = cKDTree(np.column_stack([route.x, route.y])).query(xy)
    s = route.s[nearest]
    quality = np.array([r.corrections.fix_quality for r in kept])
    links = [r.corrections.link for r in kept]
    link = None if any(x is None for x in links) else np.array([x == "streaming" for x in links])
    s, quality, link = _between_records(route, s, quality, link)
    return _result(route, str(store_uri), s, quality, link)


def _between_records(
    route: Route, s: np.ndarray, quality: np.ndarray, link: np.ndarray | None, max_gap_m: float = 10.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """A record a second, a few metres apart: the stretches between two records (up to `max_gap_m`
    on, in the direction of travel) take the earlier one's fix, so that a route driven is covered."""
    out_s, out_q, out_l = [s], [quality], [link] if link is not None else None
    step = np.mod(np.diff(s), route.length) if route.closed else np.diff(s)
    for i in np.flatnonzero((step > STRETCH_M / 2) & (step <= max_gap_m)):
        between = s[i] + np.arange(STRETCH_M / 2, step[i], STRETCH_M / 2)
        out_s.append(np.mod(between, route.length) if route.closed else between)
        out_q.append(np.full(len(between), quality[i]))
        if out_l is not None and link is not None:
            out_l.append(np.full(len(between), link[i]))
    return (
        np.concatenate(out_s),
        np.concatenate(out_q),
        np.concatenate(out_l) if out_l is not None else None,
    )


def write_coverage_png(path: str | Path, route: Route, result: CoverageResult, title: str) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection
    from matplotlib.patches import Patch

    fig, (top, bottom) = plt.subplots(2, 1, figsize=(10, 6.5), dpi=110, gridspec_kw={"height_ratios": [3, 1]})
    edges = np.arange(len(result.stretch_fix) + 1) * STRETCH_M
    points = np.array([route.point_at(min(e, route.length - 1e-6))[:2] for e in edges])
    segments = np.stack([points[:-1], points[1:]], axis=1)
    colours = [FIX_COLOURS.get(int(q), "#d1d5db") if q >= 0 else "#e5e7eb" for q in result.stretch_fix]
    top.add_collection(LineCollection(segments, colors=colours, linewidths=4))
    for zone in route.zones:
        if zone.kind not in ("no_4g", "rtk_loss"):
            continue
        x, y, _z, _yaw = route.point_at((zone.s_start + zone.s_end) / 2)
        label = "no 4G" if zone.kind == "no_4g" else "sky blocked"
        top.annotate(label, (x, y), xytext=(8, 8), textcoords="offset points", fontsize=8, color="#374151")
    top.autoscale()
    top.set_aspect("equal")
    top.set_xlabel("x (m)")
    top.set_ylabel("y (m)")
    shown = sorted({int(q) for q in result.stretch_fix if q >= 0}, reverse=True)
    top.legend(
        handles=[Patch(color=FIX_COLOURS.get(q, "#d1d5db"), label=FIX_QUALITY_NAMES.get(q, str(q))) for q in shown],
        loc="best",
        fontsize=8,
    )
    top.set_title(title, fontsize=10)
    # below: along the route, the fix and whether the corrections arrived
    s_mid = edges[:-1] + STRETCH_M / 2
    bottom.bar(s_mid, 1.0, width=STRETCH_M, bottom=1.0, color=colours, linewidth=0)
    if (result.stretch_link >= 0).any():
        link_colours = ["#2563eb" if u == 1 else "#111827" if u == 0 else "#e5e7eb" for u in result.stretch_link]
        bottom.bar(s_mid, 0.8, width=STRETCH_M, bottom=0.0, color=link_colours, linewidth=0)
    bottom.set_yticks([0.4, 1.5], ["corrections\n(blue: arriving)", "fix"], fontsize=8)
    bottom.set_xlim(0, route.length)
    bottom.set_xlabel("s along the route (m)")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path)
    plt.close(fig)
    return path
