"""ARES paper Fig. 15 and §3.6.1: the MPC beside the Stanley method on the same path. The paper
shows it in pictures only ("the MPC provides better results ... in sharp curves and a closer path
following"); ARES drives the default tour with each pinned and measures the cross-track error."""

from __future__ import annotations

from ares.tools.reproduce.experiment import Context, Drive, ExperimentResult, Row

CONTROLLERS = ("mpc", "stanley")


def run(ctx: Context) -> ExperimentResult:
    seconds = 40.0 if ctx.quick else 240.0
    figures = {
        c: ctx.drive(Drive(seconds=seconds, controller=c), ctx.out / f"lateral_{c}").figures for c in CONTROLLERS
    }
    rows = []
    for key, label in (("xte_rmse_m", "cross-track error RMSE"), ("xte_max_m", "cross-track error max"),
                       ("jerk_rms_mps3", "jerk RMS")):  # fmt: skip
        for c in CONTROLLERS:
            unit = "m/s³" if key.startswith("jerk") else "m"
            rows.append(Row(f"{label}, {c}", None, figures[c].get(key), unit))
    mpc, stanley = (figures[c].get("xte_rmse_m") for c in CONTROLLERS)
    closer = mpc is not None and stanley is not None and mpc < stanley
    rows.append(Row("the MPC follows the path closer", "yes (pictures)", "yes" if closer else "no", ""))
    return ExperimentResult(
        "ares-fig15",
        "Lateral control: the MPC beside Stanley",
        "ARES paper Fig. 15, §3.6.1",
        rows,
        notes=[
            f"The default tour, {seconds:g} s of each controller pinned at --speed max; the paper gives no numbers.",
            "Stanley is the classic law (no curvature feed-forward, no dead-time compensation): control/stanley.py.",
        ],
    )
