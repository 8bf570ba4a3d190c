"""DBW paper Figs. 25-26 and §5.1: the drive-by-wire board's step responses, steering and throttle,
with two and four people aboard, as the board's 10 Hz PID closes the loop on the simulated
actuators of the Techs4AgeCar profile (ares/tools/harness/step_response.py)."""

from __future__ import annotations

from ares.tools.harness.step_response import step_response
from ares.tools.reproduce.experiment import Context, ExperimentResult, Row

VEHICLE = "techs4agecar"
PAPER = {  # §5.1
    "steering": {"dead_time_s": 0.100, "rise_time_s": 0.650, "settling_time_s": 0.799, "overshoot_pct": 3.92},
    "throttle2": {"dead_time_s": 0.320, "rise_time_s": 2.20, "settling_time_s": 4.80, "overshoot_pct": 4.73},
    "throttle4": {"dead_time_s": 0.320, "rise_time_s": 2.39, "settling_time_s": 5.45, "overshoot_pct": 4.73},
}
LABELS = {"dead_time_s": "dead time", "rise_time_s": "rise time (90 %)", "settling_time_s": "settling time",
          "overshoot_pct": "overshoot"}  # fmt: skip


def run(ctx: Context) -> ExperimentResult:
    responses = {
        "steering": step_response("steering", VEHICLE, passengers=2),
        "throttle2": step_response("throttle", VEHICLE, passengers=2),
        "throttle4": step_response("throttle", VEHICLE, passengers=4),
    }
    rows = []
    for name, r in responses.items():
        loop = {"steering": "steering, 200°", "throttle2": "throttle 0→3 m/s, 2 people",
                "throttle4": "throttle 0→3 m/s, 4 people"}[name]  # fmt: skip
        for key, label in LABELS.items():
            unit = "%" if key == "overshoot_pct" else "s"
            rows.append(Row(f"{loop}: {label}", PAPER[name][key], round(getattr(r, key), 3), unit))
        error_unit = "°" if name == "steering" else "rad/s"
        paper_error = "±4" if name == "steering" else "±0.35 (±20°/s)"
        rows.append(Row(f"{loop}: steady-state error", paper_error, round(r.steady_state_error, 2), error_unit))
    picture = _picture(ctx, responses)
    return ExperimentResult(
        "dbw-steps",
        "Drive-by-wire step responses",
        "DBW paper Figs. 25-26, §5.1",
        rows,
        picture,
        notes=[
            "ARES simulates the board's actuators (a first-order motor with dead time and rate limits, "
            "tuned to these steps) where the paper measured the real car; the PID and its 10 Hz are the board's.",
            "The settling band is 2 % (the paper does not say its band).",
        ],
    )


def _picture(ctx: Context, responses: dict):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 3.6))
    s = responses["steering"]
    axes[0].plot(s.t, s.y, label="ARES")
    axes[0].axhline(s.reference, color="grey", lw=0.8, ls="--", label="reference")
    axes[0].set(title="Steer-by-wire, 200° (Fig. 25a)", xlabel="s", ylabel="steering wheel (°)")
    for name, label in (("throttle2", "2 people"), ("throttle4", "4 people")):
        r = responses[name]
        axes[1].plot(r.t, r.y, label=label)
    axes[1].axhline(responses["throttle2"].reference, color="grey", lw=0.8, ls="--", label="reference")
    axes[1].set(title="Throttle-by-wire, 0→3 m/s (Figs. 25b, 26b)", xlabel="s", ylabel="drive wheel (rad/s)")
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend()
    fig.tight_layout()
    path = ctx.out / "dbw_steps.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
