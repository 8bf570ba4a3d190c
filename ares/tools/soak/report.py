"""A soak's figures and picture from its directory (ares.tools.soak.runner writes it as it goes), so
that a soak still running, or stopped early, is summarised the same way as a finished one.

Black-box seconds lost: every whole second of the soak, from its start to the last second the store
holds, that has no record. The reliability figures of the drive-by-wire paper (§5.4: MTBF, MTTR,
availability) come from the same records and FAULT events (blackbox.reliability), beside the
paper's own: 812 h of tests, 788 h in operation, 29 failures, MTBF 27.17 h, MTTR 0.8275 h,
availability 97.04 %.
"""

from __future__ import annotations

import csv
import json
import math
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
    from blackbox import reliability as rel
    from blackbox.store.sqlite_store import SqliteStore

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
    api = [f for f in faults if f["kind"] == "bad_api_burst"]
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
        "availability": running.get("availability"),
        "time_to_safe_state_max_s": per["all"]["time_to_safe_state_max_s"],
        "time_to_safe_state_p99_s": per["all"]["time_to_safe_state_p99_s"],
        "api_requests": sum(sum(f.get("api_answers", {}).values()) for f in api),
        # answered by a running API: each a 4xx; while the API process itself was down (a fault of its
        # own, restarting) nothing answers, and those are counted apart
        "api_not_4xx": sum(f.get("api_not_4xx", 0) for f in api if f.get("api_running", True)),
        "api_unanswered_api_down": sum(f.get("api_not_4xx", 0) for f in api if not f.get("api_running", True)),
        **({} if t_from is None else blackbox_figures(out, vehicle_id, t_from, t_to, faults)),
        "paper": PAPER,
        "per_kind": per["per_kind"],
        "all": per["all"],
        "run": {k: v for k, v in running.items() if k not in ("invariant_examples",)},
        "dir": str(out),
    }
    return summary


def picture(out: Path, summary: dict | None = None) -> Path:
    """The faults on a time line, with the speed and the awareness level (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out)
    with (out / "timeline.csv").open() as f:
        rows = [(float(r["t"]), float(r["v"]), int(r["level"])) for r in csv.DictReader(f)]
    faults = read_faults(out)
    if not rows:
        raise ValueError("no time line yet")
    t0 = rows[0][0]
    hours = (rows[-1][0] - t0) > 7200
    scale, unit = (3600.0, "h") if hours else (60.0, "min")
    ts = [(r[0] - t0) / scale for r in rows]
    fig, (ax_v, ax_l, ax_f) = plt.subplots(
        3, 1, figsize=(14, 7), sharex=True, gridspec_kw={"height_ratios": [3, 1, 2]}, constrained_layout=True
    )
    ax_v.plot(ts, [r[1] for r in rows], lw=0.6, color="tab:blue")
    ax_v.set_ylabel("speed (m/s)")
    ax_l.step(ts, [r[2] for r in rows], where="post", lw=0.8, color="tab:red")
    ax_l.set_yticks([-1, 0, 1, 2], ["?", "0", "1", "2"])
    ax_l.set_ylabel("awareness")
    kinds = sorted({f["kind"] for f in faults})
    colours = plt.get_cmap("tab20")
    for i, kind in enumerate(kinds):
        mine = [f for f in faults if f["kind"] == kind]
        xs = [(f["t"] - t0) / scale for f in mine]
        ax_f.scatter(xs, [i] * len(xs), s=10, color=colours(i % 20), marker="|" if len(faults) > 200 else "o")
        for f in mine:
            if f.get("duration_s"):
                x = (f["t"] - t0) / scale
                ax_f.plot([x, x + f["duration_s"] / scale], [i, i], lw=2, color=colours(i % 20), alpha=0.6)
    ax_f.set_yticks(range(len(kinds)), kinds, fontsize=7)
    ax_f.set_xlabel(f"stack time since the drive began ({unit})")
    if summary is None:
        done = out / "soak.json"
        summary = json.loads(done.read_text()) if done.exists() else summarise_dir(out)
    fig.suptitle(
        f"soak seed {summary['seed']}: {summary['faults_injected']} faults, collisions {summary['collisions']}, "
        f"invariant violations {summary['invariant_violations']}, availability {summary['availability']}, "
        f"max time to safe state {summary['time_to_safe_state_max_s']} s",
        fontsize=9,
    )
    path = out / "soak.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
