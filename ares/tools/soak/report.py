"""A soak's figures and picture from its directory (ares.tools.soak.runner writes it as it goes), so
that a soak still running, or stopped early, is summarised the same way as a finished one.

Black-box seconds lost: every whole second of the soak, from its start to the last second the store
holds, that has no record. The reliability figures of the drive-by-wire paper (§5.4: MTBF, MTTR,
availability) come from the same records and FAULT events (blackbox.register.reliability), beside the
paper's own: 812 h of tests, 788 h in operation, 29 failures, MTBF 27.17 h, MTTR 0.8275 h,
availability 97.04 %.
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Sequence
from datetime import UTC, datetime
from pathlib import Path

from ares.core.messages import EventLevel
from ares.tools.soak.measure import summarise

PAPER = {
    "source": "Techs4AgeCar drive-by-wire paper §5.4, eqs. 21-25 (seeds/000_53034b33ae840bf9.txt)",
    "test_hours": 812,
    "operating_hours": 788,
    "failures": 29,
    "mtbf_hours": 27.17,
    "mttr_hours": 0.8275,
    "availability": 0.9704,
}
PAST, FUTURE = datetime(2000, 1, 1, tzinfo=UTC), datetime(2200, 1, 1, tzinfo=UTC)
BATCH = 5000


def read_faults(out: Path) -> list[dict]:
    path = out / "faults.jsonl"
    if not path.exists():
        return []
    rows = []
    for line in path.read_text().splitlines():
        try:
            rows.append(json.loads(line))
        except json.JSONDecodeError:  # the line being written when a running soak was read
            continue
    return rows


RECORDER = "blackbox"  # the recorder's process: while it is itself killed or hung, nothing can record


def recorder_down(faults: list[dict]) -> list[tuple[float, float]]:
    """The spans (stack time) from a process fault of the recorder itself to its recovery."""
    return [
        (f["t"], f["t"] + (f["time_to_recover_s"] if f["time_to_recover_s"] is not None else 60.0) + 1.0)
        for f in faults
        if f.get("target") == RECORDER and f["kind"].endswith("_process") and f["injected"]
    ]


def blackbox_figures(out: Path, vehicle_id: str, t_from: float, t_to: float | None, faults: list[dict]) -> dict:
    """Seconds of [t_from, t_to] (t_to: the last stored second) without a record, apart from those
    while the recorder itself was down (killed, hung or busy by a fault: no process is left to
    record them, and they are counted on their own); the paper's reliability figures from the
    records and FAULT events of that span."""
    from blackbox.register import reliability as rel
    from blackbox.register.store.sqlite_store import SqliteStore

    path = out / "blackbox.sqlite"
    if not path.exists():
        return {"blackbox_error": f"no store at {path}"}
    store = SqliteStore(str(path))
    try:
        seconds: set[int] = set()
        records: list[dict] = []
        skip = 0
        while True:
            batch = store.records(vehicle_id, PAST, FUTURE, skip=skip, limit=BATCH)
            for r in batch:
                if r["t"] >= t_from - 1.0 and (t_to is None or r["t"] <= t_to + 1.0):
                    seconds.add(int(r["t"]))
                    records.append(r)
            if len(batch) < BATCH:
                break
            skip += BATCH
        events = store.events(vehicle_id, PAST, FUTURE, limit=1_000_000)
    finally:
        store.close()
    if not seconds:
        return {"blackbox_records": 0, "blackbox_seconds_lost": None}
    first, last = math.ceil(t_from), max(seconds) if t_to is None else min(max(seconds), math.floor(t_to))
    down = recorder_down(faults)
    missing = [s for s in range(first, last + 1) if s not in seconds]
    lost = [s for s in missing if not any(a <= s <= b for a, b in down)]
    lost_down = [s for s in missing if any(a <= s <= b for a, b in down)]
    in_span = [r for r in records if first <= r["t"] <= last + 1]
    faults = [
        e["time"]
        for e in events
        if str(getattr(e.get("level"), "value", e.get("level"))) == EventLevel.FAULT.value
        and first <= e["t"] <= last + 1
    ]
    figures = {}
    if in_span:
        tally = rel.tally_window(in_span, sorted(faults), until=in_span[-1]["time"])
        figures = tally.figures().as_dict()
    return {
        "blackbox_records": len(seconds),
        "blackbox_span_s": [first, last],
        "blackbox_seconds_lost": len(lost),
        "blackbox_lost_examples": lost[:10],
        "blackbox_seconds_lost_recorder_down": len(lost_down),
        "recorder_faults": len(down),
        "blackbox_store_outages": sum(1 for e in events if e.get("kind") == "blackbox_store_down"),
        "reliability_from_records": figures,
    }


def api_figures(faults: list[dict]) -> dict:
    """The bad-API bursts' answers: every request, those a running API did not answer with a 4xx,
    and those nothing answered while the API process itself was down (a fault of its own)."""
    api = [f for f in faults if f["kind"] == "bad_api_burst"]
    return {
        "api_requests": sum(sum(f.get("api_answers", {}).values()) for f in api),
        "api_not_4xx": sum(f.get("api_not_4xx", 0) for f in api if f.get("api_running", True)),
        "api_unanswered_api_down": sum(f.get("api_not_4xx", 0) for f in api if not f.get("api_running", True)),
    }


def summarise_dir(out: Path, final: dict | None = None) -> dict:
    """The soak's figures from its directory; `final` is the runner's last word (when it ran to its end)."""
    out = Path(out)
    plan = json.loads((out / "plan.json").read_text())
    progress_path = out / "progress.json"
    progress = json.loads(progress_path.read_text()) if progress_path.exists() else {}
    running = {**progress, **(final or {})}
    faults = read_faults(out)
    config = json.loads((out / "run" / "config.json").read_text()) if (out / "run" / "config.json").exists() else {}
    vehicle_id = config.get("vehicle_id", "shuttle01")
    t_from = running.get("t_start_s")
    t_to = running.get("t") if final else None
    per = summarise(faults)
    summary = {
        "ok": bool(final and final.get("ok")),
        "finished": bool(final and final.get("ok")),  # ran to its planned end (not stopped, not failed)
        **({"error": final["error"]} if final and final.get("error") else {}),
        "seed": plan["seed"],
        "hours_planned": plan["hours"],
        "faults_planned": plan["faults"],
        "faults_injected": per["all"]["injected"],  # written down (recovered, or the soak's end)
        "faults_injected_so_far": running.get("faults_injected"),  # a running soak's: some not yet over
        "vehicle_hours": round(running.get("measured_s", 0.0) / 3600.0, 3),
        "collisions": running.get("collisions"),
        "invariant_violations": running.get("invariant_violations"),
        "invariant_examples": running.get("invariant_examples", []),
        "min_clearance_m": running.get("min_clearance_m"),
        "closest_approach": running.get("closest_approach"),  # stack time, obstacle, kind, speed
        "availability": running.get("availability"),
        "time_to_safe_state_max_s": per["all"]["time_to_safe_state_max_s"],
        "time_to_safe_state_p99_s": per["all"]["time_to_safe_state_p99_s"],
        **api_figures(faults),
        **({} if t_from is None else blackbox_figures(out, vehicle_id, t_from, t_to, faults)),
        "paper": PAPER,
        "per_kind": per["per_kind"],
        "all": per["all"],
        "run": {k: v for k, v in running.items() if k not in ("invariant_examples",)},
        "dir": str(out),
    }
    return summary


def draw(
    path: Path,
    rows: list[tuple[float, float, int]],
    faults: list[tuple[float, str, float]],
    title: str,
    x_label: str,
    starts: Sequence[float] = (),
) -> Path:
    """The three panels of a soak's picture, time in seconds on the x axis (shown in minutes, or
    hours past two): the speed, the awareness level, and each fault (time, kind, duration) on its
    kind's line; a dashed line at each of `starts`."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scale, unit = (3600.0, "h") if rows[-1][0] - rows[0][0] > 7200 else (60.0, "min")
    fig, (ax_v, ax_l, ax_f) = plt.subplots(
        3, 1, figsize=(14, 7), sharex=True, gridspec_kw={"height_ratios": [3, 1, 2]}, constrained_layout=True
    )
    ts = [r[0] / scale for r in rows]
    ax_v.plot(ts, [r[1] for r in rows], lw=0.6, color="tab:blue")
    ax_v.set_ylabel("speed (m/s)")
    ax_l.step(ts, [r[2] for r in rows], where="post", lw=0.8, color="tab:red")
    ax_l.set_yticks([-1, 0, 1, 2], ["?", "0", "1", "2"])
    ax_l.set_ylabel("awareness")
    kinds = sorted({kind for _, kind, _ in faults})
    colours = plt.get_cmap("tab20")
    for i, kind in enumerate(kinds):
        mine = [(t, d) for t, k, d in faults if k == kind]
        ax_f.scatter([t / scale for t, _ in mine], [i] * len(mine), s=10, color=colours(i % 20),
                     marker="|" if len(faults) > 200 else "o")  # fmt: skip
        for t, duration in mine:
            if duration:
                ax_f.plot([t / scale, (t + duration) / scale], [i, i], lw=2, color=colours(i % 20), alpha=0.6)
    ax_f.set_yticks(range(len(kinds)), kinds, fontsize=7)
    ax_f.set_xlabel(f"{x_label} ({unit})")
    for ax in (ax_v, ax_l, ax_f):
        for start in starts:
            ax.axvline(start / scale, color="grey", ls="--", lw=0.8)
    fig.suptitle(title, fontsize=9)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def picture(out: Path, summary: dict | None = None) -> Path:
    """The faults on a time line, with the speed and the awareness level (PNG)."""
    out = Path(out)
    with (out / "timeline.csv").open() as f:
        rows = [(float(r["t"]), float(r["v"]), int(r["level"])) for r in csv.DictReader(f)]
    if not rows:
        raise ValueError("no time line yet")
    t0 = rows[0][0]
    if summary is None:
        done = out / "soak.json"
        summary = json.loads(done.read_text()) if done.exists() else summarise_dir(out)
    title = (
        f"soak seed {summary['seed']}: {summary['faults_injected']} faults, collisions {summary['collisions']}, "
        f"invariant violations {summary['invariant_violations']}, availability {summary['availability']}, "
        f"max time to safe state {summary['time_to_safe_state_max_s']} s"
    )
    return draw(
        out / "soak.png",
        [(t - t0, v, level) for t, v, level in rows],
        [(f["t"] - t0, f["kind"], f.get("duration_s", 0.0)) for f in read_faults(out)],
        title,
        "stack time since the drive began",
    )
