"""A soak in segments: `ares soak --resume DIR` goes on with a soak that was stopped (Ctrl-C, a
reboot, a machine wanted for something else) instead of starting it again.

The first segment is the soak's own directory; each resumed one is a soak of its own in
DIR/segments/<k>/, with the plan's rest: the faults not yet over, their times moved back by the
plan time the segments before reached (`plan_offset_s`), the shuttle started where it stood. A
fault still open when its segment stopped (injected, neither recovered nor given up on) tells
nothing: it is left out and injected again in the next segment. The figures of every segment are
merged into one summary (DIR/soak-all.json, and its picture DIR/soak-all.png): counts and seconds
added up, maxima and percentiles over every fault, availability over every measured second.

Between two segments the stack is stopped: those seconds are neither driven nor recorded, and
each segment begins with its own `lead_s` of engaging and driving off. A soak in segments is the
sum of its segments, not one unbroken run: a slow leak has each segment's length to show.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

from ares.tools.soak import report
from ares.tools.soak.measure import GIVE_UP_S, summarise
from ares.tools.soak.plan import MIN_SLOT_S, PlannedFault

SEGMENTS = "segments"


def segment_dirs(root: Path) -> list[Path]:
    """The soak's segments in order: its own directory, then DIR/segments/1, 2, ..."""
    root = Path(root)
    more = root / SEGMENTS
    if not more.is_dir():
        return [root]
    resumed = sorted(
        (d for d in more.iterdir() if d.name.isdigit() and (d / "plan.json").exists()), key=lambda d: int(d.name)
    )
    return [root, *resumed]


def _json(path: Path) -> dict:
    return json.loads(path.read_text()) if path.exists() else {}


def _planned(row: dict) -> PlannedFault:
    fields = PlannedFault.__dataclass_fields__  # (plan.json leaves out what is nought, a moment's duration too)
    return PlannedFault(**{"duration_s": 0.0, **{k: v for k, v in row.items() if k in fields}})


class Segment:
    """One segment's directory read back: its plan's offset, how far it got, its faults."""

    def __init__(self, path: Path):
        self.path = Path(path)
        self.plan = _json(self.path / "plan.json")
        self.progress = _json(self.path / "progress.json")
        self.result = _json(self.path / "soak.json")
        self.offset_s = float((self.plan.get("segment") or {}).get("plan_offset_s", 0.0))
        self.finished = bool(self.result.get("finished"))
        self.rows = report.read_faults(self.path)
        self.end_t = self.progress.get("t")

    @property
    def plan_start_s(self) -> float:
        return float(self.progress.get("plan_start_s", self.plan.get("lead_s", 0.0)))

    def reached_s(self) -> float:
        """The plan time this segment got to (the soak's own, offset included)."""
        if self.end_t is None:
            return self.offset_s
        return self.offset_s + max(float(self.end_t) - self.plan_start_s, 0.0)

    def cut_short(self, row: dict) -> bool:
        """A fault this segment's stop left open: injected, not recovered, and not yet given up on."""
        if self.finished or not row["injected"] or row["time_to_recover_s"] is not None or self.end_t is None:
            return False
        return float(self.end_t) - (row["t"] + row.get("duration_s", 0.0)) <= GIVE_UP_S

    def kept_rows(self) -> list[dict]:
        """Its faults that count, each with `plan_t_s`: its time on the whole soak's plan clock."""
        return [
            {**row, "plan_t_s": round(self.offset_s + row["t"] - self.plan_start_s, 3), "segment": self.path.name}
            for row in self.rows
            if not self.cut_short(row)
        ]


def next_segment(root: Path) -> dict:
    """What the next segment runs: its plan (the rest, moved back), its hours, where it starts, its
    directory and what it records of itself. ValueError when nothing is left to run."""
    root = Path(root)
    whole = _json(root / "plan.json")
    if not whole:
        raise ValueError(f"{root}: no soak there (no plan.json)")
    if "configs" not in whole:
        raise ValueError(f"{root}: its plan.json does not record the soak's configuration (older than --resume)")
    segments = [Segment(d) for d in segment_dirs(root)]
    last = segments[-1]
    if last.finished:
        raise ValueError(f"{root}: the soak has run to its end; nothing to resume")
    done = {row["index"] for seg in segments for row in seg.kept_rows()}
    offset = last.reached_s()
    rest: list[PlannedFault] = []
    for row in whole["plan"]:
        if row["index"] in done:
            continue
        fault = _planned(row)
        at = fault.at_s - offset
        if rest:  # one cut short comes again at once, the next once it is over and a slot has passed
            at = max(at, rest[-1].ends_s + MIN_SLOT_S)
        rest.append(replace(fault, at_s=round(max(at, 0.0), 2)))
    if not rest:
        raise ValueError(f"{root}: every fault of the plan is over; nothing to resume")
    hours = max(whole["hours"] - offset / 3600.0, (rest[-1].ends_s + MIN_SLOT_S) / 3600.0)
    index = len(segments)
    # where the shuttle stood: the last segment that got as far as saying so
    start_s = next((seg.progress["s"] for seg in reversed(segments) if seg.progress.get("s") is not None), None)
    return {
        "plan": rest,
        "hours": hours,
        "start_s_m": start_s,
        "out_dir": root / SEGMENTS / str(index),
        "segment": {"of": str(root.resolve()), "index": index, "plan_offset_s": round(offset, 2)},
        "seed": whole["seed"],
        "lead_s": whole["lead_s"],
        "kinds": tuple(whole["kinds"]),
        "configs": tuple(whole.get("configs", ())),
        "route": whole.get("route"),
    }


def closest_approach(segment: Segment, part: dict) -> dict | None:
    """Where a segment's closest approach was, with its time on the whole soak's plan clock (None
    for a soak from before it was kept)."""
    where = part.get("closest_approach")
    if not where:
        return None
    plan_t_s = round(segment.offset_s + where["t"] - segment.plan_start_s, 2)
    return {**where, "plan_t_s": plan_t_s, "segment": segment.path.name}


def merged_summary(root: Path, segments: list[Segment] | None = None) -> dict:
    """The figures of every segment as one soak's (see the module's docstring); `segments`: read
    already."""
    root = Path(root)
    whole = _json(root / "plan.json")
    segments = segments if segments is not None else [Segment(d) for d in segment_dirs(root)]
    parts = [report.summarise_dir(seg.path, final=seg.result.get("run") if seg.finished else None) for seg in segments]
    rows = [row for seg in segments for row in seg.kept_rows()]
    # a fault cut short and injected again counts once: the last segment's
    rows = list({row["index"]: row for row in rows}.values())
    per = summarise(rows)
    # what a fault cut short did measure before the stop: its time to the safe state, if it got there
    cut_short = [row for seg in segments for row in seg.rows if seg.cut_short(row)]
    cut_short_safe = [
        r["time_to_safe_state_s"]
        for r in cut_short
        if r["safety_relevant"] and not r["overlapped"] and r["time_to_safe_state_s"] is not None
    ]
    safe = [v for v in (per["all"]["time_to_safe_state_max_s"], *cut_short_safe) if v is not None]
    measured = sum(seg.progress.get("measured_s", 0.0) for seg in segments)
    available = sum(seg.progress.get("available_s", 0.0) for seg in segments)
    tallies = [p.get("reliability_from_records") or {} for p in parts]
    operating = sum(t.get("operating_hours", 0.0) for t in tallies)
    repair = sum(t.get("repair_hours", 0.0) for t in tallies)
    failures = sum(t.get("failures", 0) for t in tallies)
    nearest = min(
        (k for k, p in enumerate(parts) if p.get("min_clearance_m") is not None),
        key=lambda k: parts[k]["min_clearance_m"],
        default=None,
    )
    last = segments[-1]
    from blackbox.register import reliability as rel

    def total(key: str) -> int | None:
        values = [p.get(key) for p in parts]
        return None if all(v is None for v in values) else sum(v or 0 for v in values)

    return {
        "ok": bool(last.finished and last.result.get("ok")),
        "finished": last.finished,
        "segments": len(segments),
        "seed": whole["seed"],
        "hours_planned": whole["hours"],
        "faults_planned": whole["faults"],
        "faults_injected": per["all"]["injected"],
        # open when their segment stopped: injected again by the next one (or by the next --resume)
        "faults_cut_short": len(cut_short),
        "vehicle_hours": round(measured / 3600.0, 3),
        "plan_hours_reached": round(last.reached_s() / 3600.0, 3),
        "wall_hours": round(sum(seg.progress.get("wall_s", 0.0) for seg in segments) / 3600.0, 3),
        "collisions": total("collisions"),
        "invariant_violations": total("invariant_violations"),
        "invariant_examples": [e for p in parts for e in p.get("invariant_examples", [])][:10],
        "min_clearance_m": None if nearest is None else parts[nearest]["min_clearance_m"],
        "closest_approach": None if nearest is None else closest_approach(segments[nearest], parts[nearest]),
        "availability": round(available / measured, 5) if measured else None,
        # over every fault, and over what the faults cut short measured before their stop
        "time_to_safe_state_max_s": max(safe, default=None),
        "time_to_safe_state_max_cut_short_s": max(cut_short_safe, default=None),
        "time_to_safe_state_p99_s": per["all"]["time_to_safe_state_p99_s"],
        **report.api_figures(rows),
        "blackbox_records": total("blackbox_records"),
        "blackbox_seconds_lost": total("blackbox_seconds_lost"),
        "blackbox_seconds_lost_recorder_down": total("blackbox_seconds_lost_recorder_down"),
        "blackbox_store_outages": total("blackbox_store_outages"),
        "reliability_from_records": rel.figures(operating, failures, repair).as_dict() if operating else {},
        "paper": report.PAPER,
        "per_kind": per["per_kind"],
        "all": per["all"],
        "run": {
            "router_restarts": sum(seg.progress.get("router_restarts", 0) for seg in segments),
            "rearms": sum(seg.progress.get("rearms", 0) for seg in segments),
            "engagements": sum(seg.progress.get("engagements", 0) for seg in segments),
            "process_restarts": sum(sum(seg.progress.get("process_restarts", {}).values()) for seg in segments),
        },
        "per_segment": [
            {
                "dir": str(seg.path),
                "plan_offset_s": seg.offset_s,
                "vehicle_hours": round(seg.progress.get("measured_s", 0.0) / 3600.0, 3),
                "wall_hours": round(seg.progress.get("wall_s", 0.0) / 3600.0, 3),
                "faults_kept": len(seg.kept_rows()),
                "finished": seg.finished,
                **({"error": part["error"]} if part.get("error") else {}),
            }
            for seg, part in zip(segments, parts, strict=True)
        ],
        "dir": str(root),
    }


def merged_timeline(segments: list[Segment]) -> tuple[list[tuple[float, float, int]], list[float]]:
    """(plan time, v, level) rows of every segment on the whole soak's plan clock (a resumed one's
    from where the plan resumes), and where each resumed segment begins on it."""
    rows: list[tuple[float, float, int]] = []
    starts: list[float] = []
    for k, seg in enumerate(segments):
        path = seg.path / "timeline.csv"
        if not path.exists():
            continue
        lines = path.read_text().splitlines()[1:]
        shift = seg.offset_s - seg.plan_start_s
        if k:
            starts.append(seg.offset_s)
        for line in lines:
            try:
                t, v, level = line.split(",")
                row = (float(t) + shift, float(v), int(level))
            except ValueError:  # the line being written when a running soak was read
                continue
            if not k or row[0] >= seg.offset_s:  # a resumed segment's start-up lies before its plan resumes
                rows.append(row)
    return rows, starts


def merged_picture(root: Path, summary: dict, segments: list[Segment]) -> Path:
    """report.draw over every segment on the plan clock, the segments' starts marked."""
    rows, starts = merged_timeline(segments)
    if not rows:
        raise ValueError("no time line yet")
    faults = [(f["plan_t_s"], f["kind"], f.get("duration_s", 0.0)) for seg in segments for f in seg.kept_rows()]
    title = (
        f"soak seed {summary['seed']} in {summary['segments']} segments: {summary['faults_injected']} faults in "
        f"{summary['vehicle_hours']} vehicle hours, collisions {summary['collisions']}, invariant violations "
        f"{summary['invariant_violations']}, availability {summary['availability']}, max time to safe state "
        f"{summary['time_to_safe_state_max_s']} s"
    )
    x_label = "the soak's plan time; dashed: a resumed segment begins"
    return report.draw(Path(root) / "soak-all.png", rows, faults, title, x_label, starts)


def write_merged(root: Path) -> dict:
    """soak-all.json and soak-all.png in the soak's directory; the summary."""
    segments = [Segment(d) for d in segment_dirs(root)]
    summary = merged_summary(root, segments)
    try:
        summary["picture"] = str(merged_picture(root, summary, segments))
    except (OSError, ValueError) as exc:
        summary["picture_error"] = str(exc)
    (Path(root) / "soak-all.json").write_text(json.dumps(summary, indent=1))
    return summary
