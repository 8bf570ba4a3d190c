"""A headless run's picture: the route, the path driven, and the cross-track error along it.

Plain SVG, written by hand so that a run needs no plotting library and the file opens in any
browser.
"""

from __future__ import annotations

from pathlib import Path
from xml.sax.saxutils import escape

import numpy as np

from ares.core.route import Route

WIDTH, MAP_HEIGHT, CHART_HEIGHT, MARGIN = 900, 560, 200, 40


def _polyline(xs, ys, colour: str, width: float, dash: str = "") -> str:
    points = " ".join(f"{x:.1f},{y:.1f}" for x, y in zip(xs, ys))
    dash_attr = f' stroke-dasharray="{dash}"' if dash else ""
    return (
        f'<polyline points="{points}" fill="none" stroke="{colour}" stroke-width="{width}"'
        f'{dash_attr} stroke-linejoin="round"/>'
    )


def lap_svg(route: Route, xs: np.ndarray, ys: np.ndarray, progress: np.ndarray, xte: np.ndarray, title: str) -> str:
    """Map of the route (grey) with the driven path (blue) and zones, over a chart of |xte|."""
    all_x = np.concatenate([route.x, xs]) if len(xs) else route.x
    all_y = np.concatenate([route.y, ys]) if len(ys) else route.y
    span = max(np.ptp(all_x), np.ptp(all_y), 1.0)
    scale = min((WIDTH - 2 * MARGIN) / max(np.ptp(all_x), 1.0), (MAP_HEIGHT - 2 * MARGIN) / max(np.ptp(all_y), 1.0))
    to_px = lambda x, y: (MARGIN + (x - all_x.min()) * scale, MAP_HEIGHT - MARGIN - (y - all_y.min()) * scale)  # noqa: E731
    parts = [
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{WIDTH}" height="{MAP_HEIGHT + CHART_HEIGHT}" '
        f'font-family="sans-serif" font-size="12">',
        '<rect width="100%" height="100%" fill="white"/>',
        f'<text x="{MARGIN}" y="22" font-size="15">{escape(title)}</text>',
    ]
    rx, ry = to_px(route.x, route.y)
    parts.append(_polyline(rx, ry, "#bbbbbb", 6))
    colours = {"rtk_loss": "#e8a33d", "intersection": "#c0392b", "road_opening": "#8e44ad", "narrow": "#16a085"}
    for zone in route.zones:
        mask = (route.s >= zone.s_start) & (route.s <= zone.s_end)
        if mask.any():
            parts.append(_polyline(rx[mask], ry[mask], colours.get(zone.kind, "#555"), 6))
    for poi in route.pois:
        px, py = to_px(*route.point_at(poi.s)[:2])
        parts.append(
            f'<circle cx="{px:.1f}" cy="{py:.1f}" r="5" fill="#2c3e50"/>'
            f'<text x="{px + 8:.1f}" y="{py - 6:.1f}">{escape(poi.name)}</text>'
        )
    if len(xs):
        dx, dy = to_px(np.asarray(xs), np.asarray(ys))
        parts.append(_polyline(dx, dy, "#1f6fd1", 1.5))
    legend = [("route", "#bbbbbb"), ("driven", "#1f6fd1")] + [(k.replace("_", " "), c) for k, c in colours.items()]
    for k, (label, colour) in enumerate(legend):
        y = 44 + 16 * k
        parts.append(
            f'<rect x="{WIDTH - 150}" y="{y - 9}" width="14" height="8" fill="{colour}"/>'
            f'<text x="{WIDTH - 130}" y="{y}">{escape(label)}</text>'
        )
    parts.append(f'<text x="{MARGIN}" y="{MAP_HEIGHT - 12}">{span:.0f} m across</text>')

    top = MAP_HEIGHT
    h = CHART_HEIGHT - 50
    err = np.abs(np.asarray(xte))
    if len(err):
        ymax = max(float(err.max()) * 1.1, 0.05)
        xmax = max(float(np.max(progress)), 1.0)
        cx = MARGIN + np.asarray(progress) / xmax * (WIDTH - 2 * MARGIN)
        cy = top + 20 + h - err / ymax * h
        parts.append(
            f'<line x1="{MARGIN}" y1="{top + 20 + h}" x2="{WIDTH - MARGIN}" y2="{top + 20 + h}" stroke="#999"/>'
        )
        parts.append(_polyline(cx, cy, "#c0392b", 1.2))
        parts.append(
            f'<text x="{MARGIN}" y="{top + 14}">|cross-track error| (m), max {err.max():.3f} m, '
            f"RMSE {np.sqrt(np.mean(err**2)):.3f} m, against distance driven ({xmax:.0f} m)</text>"
        )
        parts.append(f'<text x="{MARGIN - 4}" y="{top + 24}" text-anchor="end">{ymax:.2f}</text>')
    parts.append("</svg>")
    return "\n".join(parts)


def write_lap_svg(path: Path, *args, **kwargs) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(lap_svg(*args, **kwargs))
    return path
