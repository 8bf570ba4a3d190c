"""`ares soak`: the tour at --speed max with faults injected from a seeded plan (ares/tools/soak)."""

from __future__ import annotations

import argparse
import json

from .args import CliError, Command, endpoint, port, positive_float, positive_int


def add_parser(subparsers: argparse._SubParsersAction) -> dict[str, Command]:
    soak = subparsers.add_parser(
        "soak",
        help="drive the tour at --speed max and inject faults from a seeded plan; figures per fault kind",
        description="Drive the tour at --speed max and inject faults at seeded times: SIGKILL, SIGSTOP and a "
        "busy loop of any process; GNSS outage and RTK loss; a LiDAR covered or silent; the IMU frozen; the "
        "router restarted; the black box's store unavailable; a burst of bad API requests; a pedestrian or a "
        "parked object in the path. Reports, per fault kind and in all: faults injected, collisions, the "
        "movement gate's invariant violations, time to the safe state (max, p99), black-box seconds lost, "
        "time to recover, availability; and a picture. Progress on stderr; every fault as it recovers in "
        "DIR/faults.jsonl (a partial soak: --summarise DIR).",
    )
    soak.add_argument("--hours", type=positive_float, metavar="H", help="stack (vehicle) hours (default 1)")
    soak.add_argument("--faults", type=positive_int, metavar="N", help="faults to inject (default 100)")
    soak.add_argument("--seed", type=int, metavar="S", help="the plan's seed (default 1)")
    soak.add_argument("--json", action="store_true", help="print the figures as one JSON line (else a table)")
    soak.add_argument(
        "--config", action="append", default=[], metavar="FILE", help="a config file (repeatable), as for ares run"
    )
    soak.add_argument("--route", metavar="NAME|FILE", help="a built-in tour (default, campus) or a route file")
    soak.add_argument("--out", metavar="DIR", help="where the soak's files go (default runs/soak-<time>)")
    soak.add_argument("--listen", type=endpoint, metavar="ENDPOINT", help="the soak's router (default: a free port)")
    soak.add_argument("--api-port", type=port, metavar="PORT", help="the black box API's port (default: a free one)")
    soak.add_argument(
        "--lead", type=positive_float, metavar="S", help="stack time at which the plan starts (default 60)"
    )
    soak.add_argument("--kinds", metavar="K,K", help="only these fault kinds (default: every kind the run can take)")
    soak.add_argument(
        "--summarise", metavar="DIR", help="only summarise the soak in DIR (running, stopped or finished)"
    )
    soak.add_argument(
        "--resume",
        metavar="DIR",
        help="go on with the stopped soak in DIR: the plan's rest as a segment of its own (DIR/segments/<k>), "
        "the shuttle starting where it stood; then the figures of every segment together (DIR/soak-all.json)",
    )
    return {"soak": cmd_soak}


def cmd_soak(args: argparse.Namespace) -> int:
    import time
    from pathlib import Path

    from ares.core import config
    from ares.tools.soak import report, resume
    from ares.tools.soak.plan import KINDS
    from ares.tools.soak.runner import Soak, SoakOptions

    if args.resume:
        return resume_soak(args)
    if args.summarise:
        if not (Path(args.summarise) / "plan.json").exists():
            raise CliError(f"{args.summarise}: no soak there (no plan.json)")
        if len(resume.segment_dirs(Path(args.summarise))) > 1:
            summary = resume.write_merged(Path(args.summarise))
            print(json.dumps(summary) if args.json else table(summary))
            return 0
        summary = report.summarise_dir(Path(args.summarise))
        try:  # the picture of the soak so far, beside its files
            summary["picture"] = str(report.picture(Path(args.summarise), summary))
        except (OSError, ValueError) as exc:
            summary["picture_error"] = str(exc)
        print(json.dumps(summary) if args.json else table(summary))
        return 0
    kinds = tuple(k.strip() for k in args.kinds.split(",")) if args.kinds else None
    unknown = sorted(set(kinds or ()) - set(KINDS))
    if unknown:
        raise CliError(f"unknown fault kinds {unknown}; the kinds: {', '.join(KINDS)}")
    out = Path(args.out) if args.out else Path("runs") / time.strftime("soak-%Y%m%d-%H%M%S")
    opts = SoakOptions(
        hours=1.0 if args.hours is None else args.hours,
        faults=100 if args.faults is None else args.faults,
        seed=1 if args.seed is None else args.seed,
        out_dir=out,
        configs=tuple(args.config),
        listen=args.listen,
        api_port=args.api_port,
        lead_s=60.0 if args.lead is None else args.lead,
        kinds=kinds,
        route=args.route,
    )
    try:
        summary = Soak(opts).run()
    except (config.ConfigError, ValueError) as exc:
        raise CliError(str(exc)) from None
    print(json.dumps(summary) if args.json else table(summary))
    return 0 if summary["ok"] else 1


def resume_soak(args: argparse.Namespace) -> int:
    """The next segment of a stopped soak, then the figures of all its segments."""
    from pathlib import Path

    from ares.core import config
    from ares.tools.soak import resume
    from ares.tools.soak.runner import Soak, SoakOptions

    root = Path(args.resume)
    given = [
        flag
        for flag, value in (("--hours", args.hours), ("--faults", args.faults), ("--seed", args.seed),
                            ("--lead", args.lead), ("--route", args.route), ("--kinds", args.kinds),
                            ("--out", args.out), ("--config", args.config or None))
        if value is not None
    ]  # fmt: skip
    if given:
        flags = ", ".join(given)
        raise CliError(f"--resume goes on with the soak's own plan and configuration: no {flags} beside it")
    try:
        spec = resume.next_segment(root)
    except ValueError as exc:
        raise CliError(str(exc)) from None
    opts = SoakOptions(
        hours=spec["hours"],
        faults=len(spec["plan"]),
        seed=spec["seed"],
        out_dir=spec["out_dir"],
        configs=spec["configs"],
        listen=args.listen,
        api_port=args.api_port,
        lead_s=spec["lead_s"],
        kinds=spec["kinds"],
        route=spec["route"],
        plan=spec["plan"],
        start_s_m=spec["start_s_m"],
        segment=spec["segment"],
    )
    try:
        Soak(opts).run()
    except (config.ConfigError, ValueError) as exc:
        raise CliError(str(exc)) from None
    summary = resume.write_merged(root)
    print(json.dumps(summary) if args.json else table(summary))
    return 0 if summary["ok"] else 1


def table(summary: dict) -> str:
    """The figures for people: the totals, then one line per fault kind."""
    lines = [
        f"soak seed {summary['seed']}: {summary['faults_injected']} of {summary['faults_planned']} faults "
        + (f"({summary['faults_injected_so_far']} injected so far) " if "faults_injected_so_far" in summary else "")
        + (f"in {summary['segments']} segments, " if "segments" in summary else "")
        + f"in {summary['vehicle_hours']} vehicle hours ({'finished' if summary['finished'] else 'partial'})"
        + (f" [{summary['error']}]" if summary.get("error") else ""),
        f"  collisions {summary['collisions']}   invariant violations {summary['invariant_violations']}   "
        f"black-box seconds lost {summary.get('blackbox_seconds_lost')} "
        f"(+ {summary.get('blackbox_seconds_lost_recorder_down')} while the recorder itself was down)   "
        f"availability {summary['availability']}",
        f"  time to safe state (safety-relevant): max {summary['time_to_safe_state_max_s']} s, "
        f"p99 {summary['time_to_safe_state_p99_s']} s "
        f"(wall: max {summary['all']['time_to_safe_state_wall_max_s']} s)   "
        f"API requests {summary['api_requests']}, not 4xx {summary['api_not_4xx']} "
        f"(+ {summary['api_unanswered_api_down']} unanswered while the API itself was down)",
        f"  {'kind':<24}{'injected':>9}{'overlap':>8}{'safe max':>9}{'safe p99':>9}{'missed':>7}"
        f"{'recover p50':>12}{'max':>8}{'lost s':>8}",
    ]
    for kind, f in summary["per_kind"].items():
        lines.append(
            f"  {kind:<24}{f['injected']:>9}{f['overlapped']:>8}{_n(f['time_to_safe_state_max_s']):>9}"
            f"{_n(f['time_to_safe_state_p99_s']):>9}{f['safe_state_missed']:>7}{_n(f['time_to_recover_p50_s']):>12}"
            f"{_n(f['time_to_recover_max_s']):>8}{f['lost_s']:>8}"
        )
    records = summary.get("reliability_from_records") or {}
    if records:
        lines.append(
            f"  from the black box's records (DBW eqs. 21-25): {records['failures']} failures in "
            f"{records['operating_hours']:.3f} h of operation, MTBF {_n(records['mtbf_hours'])} h, "
            f"MTTR {_n(records['mttr_hours'])} h, availability {_n(records['availability'])}"
        )
    paper = summary["paper"]
    lines.append(
        f"  the drive-by-wire paper: availability {paper['availability']:.2%}, MTBF {paper['mtbf_hours']} h "
        f"({paper['failures']} failures in {paper['operating_hours']} h of operation)"
    )
    return "\n".join(lines)


def _n(value) -> str:
    return "-" if value is None else f"{value:g}"
