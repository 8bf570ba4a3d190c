"""`ares compare`: its arguments, its table (a run that could not finish is a column too) and its
picture. The runs themselves are headless stack runs (tests/test_stack.py)."""

from __future__ import annotations

import argparse

import numpy as np
import pytest

from ares.cli.compare import controllers, table
from ares.tools.figures.compare import write_comparison_png


def test_controllers_are_a_list_of_known_names():
    assert controllers("auto, mpc,pure_pursuit") == ["auto", "mpc", "pure_pursuit"]
    for bad in ("mpc,pp", "", ","):
        known = "comma-separated list of auto, mpc, rrc, pure_pursuit, stanley"
        with pytest.raises(argparse.ArgumentTypeError, match=known):
            controllers(bad)


def test_the_table_puts_the_figures_side_by_side_and_says_who_did_not_finish():
    results = {
        "mpc": {
            "ok": True,
            "xte_rmse_m": 0.0285,
            "xte_max_m": 0.0904,
            "controller_time_share": {"mpc": 1.0},
            "switches": 0,
        },
        "pure_pursuit": {
            "ok": False,
            "error": "the shuttle has not moved for 60 s, at 244 of 801 m: ...",
            "xte_rmse_m": 1.93,
            "xte_max_m": 6.1,
            "controller_time_share": {"pure_pursuit": 0.8, "stop": 0.2},
        },
    }
    lines = table(results).splitlines()
    assert lines[0].split() == ["figure", "mpc", "pure_pursuit"]
    finished = lines[1]
    assert finished.startswith("finished") and "yes" in finished and "no: the shuttle has not moved" in finished
    rows = {line.split()[0]: line for line in lines[2:]}
    assert rows["xte_rmse_m"].split()[1:] == ["0.0285", "1.93"]
    assert rows["xte_max_m"].split()[1:] == ["0.0904", "6.1"]
    assert "pure_pursuit 0.80 stop 0.20" in rows["controller_time_share"]
    assert rows["switches"].split()[1:] == ["0", "-"]  # a figure one run lacks
    assert "lap_time_s" not in rows  # and none has: no row


def test_the_picture_has_a_panel_per_run(tmp_path):
    traces = {}
    for name, scale in (("mpc", 0.03), ("rrc", 0.2)):
        progress = np.linspace(0.0, 800.0, 4000)
        who = np.where((progress > 300) & (progress < 400), "rrc", name)
        np.savez_compressed(
            tmp_path / f"{name}.npz", progress=progress, xte=scale * np.sin(progress / 7.0), controller=who
        )
        traces[name] = tmp_path / f"{name}.npz"
    out = write_comparison_png(tmp_path / "compare.png", traces, title="campus, techs4agecar")
    assert out.exists() and out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    import matplotlib.image

    height, width, _ = matplotlib.image.imread(out).shape
    assert height > 2 * 2.4 * 110 * 0.9 and width >= 11 * 110 * 0.9  # two panels, full width
