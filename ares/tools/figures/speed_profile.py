"""The picture `ares route profile` draws, after the ARES paper's Figure 17: above, the path in
the local frame coloured by the profile's speed, each section's start marked (numbered where
there is room); below,
the speed over s: the profile, each section's single speed as a step, the sections shaded by
kind (acceleration green and deceleration red, as the paper's circles) and numbered."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ares.core.route import Route
from managers.speed import Section

KIND_COLOURS = {"cruise": "#e5e7eb", "curve": "#bfdbfe", "deceleration": "#fecaca", "acceleration": "#bbf7d0"}


def write_profile_figure(
    path: str | Path, route: Route, profile: np.ndarray, sections: list[Section], title: str
) -> Path:
    import matplotlib

    matplotlib.use("Agg")  # no display: a file is all we want
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection
    from matplotlib.patches import Patch

    fig, (top, bottom) = plt.subplots(2, 1, figsize=(11, 9), dpi=110, gridspec_kw={"height_ratios": [3, 2]})
    # the path coloured by speed: one segment per pair of samples, at the lower of their speeds
    xy = np.column_stack([route.x, route.y])
    if route.closed:
        xy = np.vstack([xy, xy[:1]])
        v = np.append(profile, profile[0])
    else:
        v = profile
    segments = np.stack([xy[:-1], xy[1:]], axis=1)
    lines = LineCollection(segments, cmap="viridis", linewidths=3)
    lines.set_array(np.minimum(v[:-1], v[1:]))
    low, high = float(profile.min()), float(profile.max())
    lines.set_clim(low, max(high, low + 0.1))  # the route's own range: the turns stand out
    top.add_collection(lines)
    fig.colorbar(lines, ax=top, label="speed limit (m/s)", shrink=0.8)
    for sec in sections:  # where each section starts, and its number where there is room
        x, y, _z, _yaw = route.point_at(sec.s_start)
        top.plot(x, y, "o", ms=3, mfc="none", color="black")
        if sec.s_end - sec.s_start < 0.01 * route.length:
            continue
        top.annotate(
            f"#{sec.index}",
            (x, y),
            fontsize=6,
            xytext=(3, 3),
            textcoords="offset points",
            color="#b91c1c" if sec.kind == "deceleration" else "#15803d" if sec.kind == "acceleration" else "#374151",
        )
    top.autoscale()
    top.set_aspect("equal")
    top.set_xlabel("x (m)")
    top.set_ylabel("y (m)")
    top.set_title(title, fontsize=10)

    # the speed over s: the sections shaded and stepped, the profile over them
    for sec in sections:
        bottom.axvspan(sec.s_start, sec.s_end, color=KIND_COLOURS[sec.kind], lw=0)
        bottom.hlines(sec.speed, sec.s_start, sec.s_end, color="black", lw=1.5)
    bottom.plot(route.s, profile, color="#1d4ed8", lw=1, label="profile")
    top_speed = float(profile.max()) if len(profile) else 1.0
    for sec in sections:  # numbers where there is room: the short ramp steps would overlap
        if sec.s_end - sec.s_start >= 0.01 * route.length:
            bottom.text(0.5 * (sec.s_start + sec.s_end), top_speed * 1.04, str(sec.index), ha="center", fontsize=6)
    bottom.set_xlim(0.0, route.length)
    bottom.set_ylim(0.0, top_speed * 1.12)
    bottom.set_xlabel("s along the route (m)")
    bottom.set_ylabel("speed (m/s)")
    handles = [Patch(color=c, label=k) for k, c in KIND_COLOURS.items()]
    handles.append(bottom.get_lines()[0])
    bottom.legend(handles=handles, loc="lower right", fontsize=8, framealpha=0.9)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, bbox_inches="tight")
    plt.close(fig)
    return path
