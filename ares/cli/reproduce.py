"""`ares reproduce`: the papers' experiments on ARES, each beside the paper's numbers, in a report.

    ares reproduce [--only ID ...] [--out DIR] [--quick] [--list] [--json]

Without --only every experiment runs (ares/tools/reproduce: their table); the report is
DIR/report.md with each experiment's picture beside it (default DIR: runs/reproduce-<time>).
--list names the experiments; --json prints the results as one JSON object (with --list: the
experiments). --quick runs each one's short version.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from .args import CliError, Command


def add_parser(subparsers: argparse._SubParsersAction) -> dict[str, Command]:
    p = subparsers.add_parser(
        "reproduce",
        help="the papers' experiments on ARES, beside the papers' numbers, in one report",
        description="Run the papers' experiments (or those named) and write a Markdown report with "
        "the paper's numbers and ARES's side by side, and the pictures.",
    )
    p.add_argument("--only", nargs="+", metavar="ID", help="only these experiments (see --list)")
    p.add_argument("--out", type=Path, metavar="DIR", help="the report's folder (default runs/reproduce-<time>)")
    p.add_argument("--quick", action="store_true", help="each experiment's short version")
    p.add_argument("--list", action="store_true", help="name the experiments and stop")
    p.add_argument("--json", action="store_true", help="one JSON object on stdout")
    return {"reproduce": cmd_reproduce}


def cmd_reproduce(args: argparse.Namespace) -> int:
    from ares.app.stack import default_run_dir
    from ares.tools.reproduce import EXPERIMENTS
    from ares.tools.reproduce.drives import stack_drive
    from ares.tools.reproduce.experiment import Context
    from ares.tools.reproduce.report import cell, write_report

    if args.list:
        listed = [{"id": e.id, "title": e.title, "paper": e.paper_ref} for e in EXPERIMENTS.values()]
        if args.json:
            print(json.dumps({"experiments": listed}))
        else:
            for e in listed:
                print(f"{e['id']:<14}{e['paper']:<30}{e['title']}")
        return 0
    unknown = [i for i in args.only or () if i not in EXPERIMENTS]
    if unknown:
        raise CliError(f"unknown experiments {unknown}; known: {', '.join(EXPERIMENTS)}")
    out = args.out or default_run_dir().parent / f"reproduce-{time.strftime('%Y%m%d-%H%M%S')}"
    out.mkdir(parents=True, exist_ok=True)
    ctx = Context(
        out=out,
        drive=stack_drive,
        quick=args.quick,
        progress=lambda m: print(f"[reproduce] {m}", file=sys.stderr, flush=True),
    )
    started = time.monotonic()
    results = [EXPERIMENTS[i](ctx) for i in (args.only or EXPERIMENTS)]
    report = write_report(out / "report.md", results, time.monotonic() - started)
    if args.json:
        print(json.dumps({"report": str(report), "experiments": [r.as_json() for r in results]}))
        return 0
    for r in results:
        print(f"{r.title} ({r.paper_ref}), {r.seconds:.0f} s")
        for row in r.rows:
            print(f"  {row.figure:<58} paper {cell(row.paper):<16} ARES {cell(row.ares)} {row.unit}")
    print(f"report: {report}")
    return 0
