"""DBW paper Fig. 28 and §5.2: the Manual/Automatic switching test. The driver takes over by the
steering wheel at 12 s and by the throttle at 73 s, 15 s each time, then Automatic again
(simulator/scenarios/takeover.yaml); what the black box recorded, as an auditor reads it."""

from __future__ import annotations

from ares.tools.reproduce.experiment import Context, Drive, ExperimentResult, Row
from ares.tools.reproduce.store_reading import events_and_records

PAPER_TAKEOVERS = (12.0, 73.0)
PAPER_MANUAL_S = 15.0


def run(ctx: Context) -> ExperimentResult:
    driven = ctx.drive(Drive(seconds=100.0, scenario="takeover"), ctx.out / "takeover")
    events, records = events_and_records(driven.store)
    changes = [(e["t"], e["message"].split(":")[0]) for e in events if e["kind"] == "mode_change"]
    actions = {e["data"]["action"]: e["t"] for e in events if e["kind"] == "driver_action"}
    to_manual = [t for t, what in changes if what == "AUTOMATIC -> MANUAL"]
    to_auto = [t for t, what in changes if what == "READY -> AUTOMATIC"][1:]  # after the start's
    rows = [
        Row("takeover by the steering wheel", PAPER_TAKEOVERS[0], _first(to_manual, 0), "s"),
        Row("... Manual after the wheel moved", "at once", _delay(actions.get("steer"), _first(to_manual, 0)), "s"),
        Row("Automatic again", PAPER_TAKEOVERS[0] + PAPER_MANUAL_S, _first(to_auto, 0), "s"),
        Row("takeover by the throttle", PAPER_TAKEOVERS[1], _first(to_manual, 1), "s"),
        Row("... Manual after the pedal moved", "at once", _delay(actions.get("throttle"), _first(to_manual, 1)), "s"),
        Row("Automatic again", PAPER_TAKEOVERS[1] + PAPER_MANUAL_S, _first(to_auto, 1), "s"),
        Row("collisions", 0, driven.figures.get("collisions"), ""),
    ]
    return ExperimentResult(
        "dbw-takeover",
        "Manual/Automatic switching",
        "DBW paper Fig. 28, §5.2",
        rows,
        _picture(ctx, records, changes),
        notes=[
            "The driver is the simulator's (a scenario's driver actions); the paper's driver changed lane "
            "by hand and drove on with the throttle, ARES's lets go after 2-3 s and the shuttle parks.",
            "Automatic again takes the Auto/Manual button (Ready) and `set_automatic_mode`, as on the paper's board.",
        ],
    )


def _first(values: list[float], k: int) -> float | None:
    return round(values[k], 2) if len(values) > k else None


def _delay(action_t: float | None, mode_t: float | None) -> float | None:
    return None if action_t is None or mode_t is None else round(mode_t - action_t, 3)


def _picture(ctx: Context, records: list[dict], changes: list):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = [r["t"] for r in records]
    fig, ax = plt.subplots(figsize=(11, 3.4))
    ax.plot(t, [r["speed_mps"] for r in records], label="speed (m/s)")
    manual = [1.0 if r["mode"] == "MANUAL" else 0.0 for r in records]
    ax.fill_between(t, 0, [m * 5 for m in manual], step="mid", color="#b54708", alpha=0.15, label="Manual")
    for when in PAPER_TAKEOVERS:
        ax.axvline(when, color="grey", ls="--", lw=0.8)
    ax.set(title="Takeovers (paper: 12 s wheel, 73 s throttle; dashed)", xlabel="stack time (s)", ylabel="m/s")
    ax.grid(alpha=0.3)
    ax.legend(loc="upper right")
    fig.tight_layout()
    path = ctx.out / "dbw_takeover.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
