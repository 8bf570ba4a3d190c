"""A headless run's picture (`lap.svg` in the run's folder): above, the route (grey) with its zones
and POIs and the path driven (blue); below, the cross-track error |xte| along the distance driven.

Drawn with matplotlib (Agg) as the other figures are, written as SVG so that it opens in any
browser. Text stays text (`svg.fonttype` none) and the three curves carry ids (`route`, `driven`,
`xte`), so that the file can be read back (tests/test_lap_figure.py).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ares.core.route import Route

ROUTE_COLOUR, DRIVEN_COLOUR, ERROR_COLOUR = "#bbbbbb", "#1f6fd1", "#c0392b"
ZONE_COLOURS = {
    "rtk_loss": "#e8a33d",
    "no_4g": "#d35400",
    "intersection": "#c0392b",
    "road_opening": "#8e44ad",
    "narrow": "#16a085",
}


def write_lap_svg(
    path: str | Path,
    route: Route,
    xs: np.ndarray,
    ys: np.ndarray,
    progress: np.ndarray,
    xte: np.ndarray,
    title: str,
) -> Path:
    """The map of `route` with the driven path (xs, ys in the local frame) over the chart of |xte|
    against `progress` (distance driven, m), written to `path` as SVG."""
    import matplotlib

    matplotlib.use("Agg")  # no display: a file is all we want
    import matplotlib.pyplot as plt

    xs, ys = np.asarray(xs, dtype=float), np.asarray(ys, dtype=float)
    err, progress = np.abs(np.asarray(xte, dtype=float)), np.asarray(progress, dtype=float)
    with plt.rc_context({"svg.fonttype": "none", "font.size": 9}):
        fig, (top, bottom) = plt.subplots(2, 1, figsize=(9, 7.6), dpi=100, gridspec_kw={"height_ratios": [14, 5]})

        # the map: the route, its zones, the POIs, the path driven
        close = (lambda a: np.append(a, a[:1])) if route.closed else (lambda a: a)  # noqa: E731
        top.plot(close(route.x), close(route.y), color=ROUTE_COLOUR, lw=6, label="route", gid="route")
        for kind, colour in ZONE_COLOURS.items():
            inside = np.zeros(len(route.s), dtype=bool)
            for zone in route.zones:
                if zone.kind == kind:
                    inside |= (route.s >= zone.s_start) & (route.s <= zone.s_end)
            if inside.any():  # NaN outside: one line per kind, broken between its zones
                top.plot(
                    np.where(inside, route.x, np.nan),
                    np.where(inside, route.y, np.nan),
                    color=colour,
                    lw=6,
                    label=kind.replace("_", " "),
                )
        for poi in route.pois:
            x, y = route.point_at(poi.s)[:2]
            top.plot(x, y, "o", ms=6, color="#2c3e50")
            top.annotate(poi.name, (x, y), xytext=(6, 5), textcoords="offset points")
        if len(xs):
            top.plot(xs, ys, color=DRIVEN_COLOUR, lw=1.5, label="driven", gid="driven")
        all_x = np.concatenate([route.x, xs])
        all_y = np.concatenate([route.y, ys])
        span = max(float(np.ptp(all_x)), float(np.ptp(all_y)), 1.0)
        top.set_aspect("equal", adjustable="datalim")
        top.set_xlabel(f"x (m); {span:.0f} m across")
        top.set_ylabel("y (m)")
        top.legend(loc="upper center", ncol=3, fontsize=8, framealpha=0.9)
        top.set_title(title, loc="left", fontsize=11)

        # the error along the distance driven
        if len(err):
            bottom.plot(progress, err, color=ERROR_COLOUR, lw=1.2, gid="xte")
            rmse = float(np.sqrt(np.mean(err**2)))
            bottom.set_title(
                f"|cross-track error| (m), max {err.max():.3f} m, RMSE {rmse:.3f} m, "
                f"against distance driven ({float(np.max(progress)):.0f} m)",
                loc="left",
                fontsize=9,
            )
            bottom.set_xlim(0.0, max(float(np.max(progress)), 1.0))
            bottom.set_ylim(0.0, max(float(err.max()) * 1.1, 0.05))
        else:
            bottom.set_title("|cross-track error| (m): nothing driven", loc="left", fontsize=9)
        bottom.set_xlabel("distance driven (m)")
        bottom.set_ylabel("m")
        bottom.grid(alpha=0.3)
        fig.tight_layout()
        out = Path(path)
        out.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(out, format="svg", metadata={"Date": None})
        plt.close(fig)
    return out
