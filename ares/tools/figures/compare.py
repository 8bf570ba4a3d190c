"""The picture `ares compare` draws: the cross-track error of each run along the distance driven,
one panel per controller on one scale, with the stretches shaded where road reactive control was
in charge (red) or the vehicle was stopping (grey). Each run leaves its trace in trace.npz
(ares.app.stack: distance, cross-track error, the controller in charge, at the simulator's rate)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

SHADES = {"rrc": "#fecaca", "creep": "#fde68a", "stop": "#e5e7eb"}


def write_comparison_png(path: str | Path, traces: dict[str, Path], title: str) -> Path:
    import matplotlib

    matplotlib.use("Agg")  # no display: a file is all we want
    import matplotlib.pyplot as plt

    loaded = {name: np.load(trace, allow_pickle=False) for name, trace in traces.items() if Path(trace).exists()}
    fig, axes = plt.subplots(
        max(len(loaded), 1),
        1,
        figsize=(11, 2.4 * max(len(loaded), 1) + 0.8),
        dpi=110,
        sharex=True,
        sharey=True,
        squeeze=False,
    )
    top = max((float(np.max(np.abs(d["xte"]))) for d in loaded.values() if len(d["xte"])), default=1.0)
    for ax, (name, data) in zip(axes[:, 0], loaded.items()):
        dist, xte, who = data["progress"], np.abs(data["xte"]), data["controller"].astype(str)
        for kind, colour in SHADES.items():
            _shade(ax, dist, who == kind, colour)
        ax.plot(dist, xte, lw=0.9, color="#1d4ed8")
        rmse = float(np.sqrt(np.mean(xte**2))) if len(xte) else float("nan")
        ax.set_title(
            f"{name}: |cross-track error| RMSE {rmse:.3f} m, max {np.max(xte, initial=0):.3f} m",
            fontsize=10,
            loc="left",
        )
        ax.set_ylabel("m")
        ax.set_ylim(0, top * 1.05)
        ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("distance driven (m); shaded: road reactive control (red), stopping (grey)")
    fig.suptitle(title)
    fig.tight_layout()
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out)
    plt.close(fig)
    return out


def _shade(ax, dist: np.ndarray, mask: np.ndarray, colour: str) -> None:
    if not mask.any():
        return
    edges = np.flatnonzero(np.diff(np.r_[0, mask.astype(int), 0]))
    for a, b in zip(edges[::2], edges[1::2]):
        ax.axvspan(dist[a], dist[min(b, len(dist)) - 1], color=colour, lw=0)
