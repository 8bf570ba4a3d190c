"""`ares bench NAME [--json] [--check]`: the benchmarks of ares/cli/bench_table.py; `ares bench
report FILE...`: their `--json` results as one Markdown table."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TextIO

from .args import CliError, Command
from .bench_table import BENCHES, BY_NAME, Bench

REPORT = "report"


def add_parser(subparsers: argparse._SubParsersAction) -> dict[str, Command]:
    bench = subparsers.add_parser("bench", help="benchmarks", description="Benchmarks.")
    bench_sub = bench.add_subparsers(dest="bench", metavar="BENCH")
    for entry in BENCHES:
        _add_bench(bench_sub, entry)
    _add_report(bench_sub)
    return {"bench": cmd_bench}


def _add_bench(bench_sub: argparse._SubParsersAction, entry: Bench) -> None:
    p = bench_sub.add_parser(entry.name, help=entry.help, description=entry.description)
    p.add_argument("--json", action="store_true", help="print one JSON object (last line of stdout)")
    p.add_argument(
        "--check",
        action="store_true",
        help="exit 1 when the bench missed one of its goals (each missed goal is named on stderr)",
    )
    entry.add_arguments(p)


def _add_report(bench_sub: argparse._SubParsersAction) -> None:
    p = bench_sub.add_parser(
        REPORT,
        help="the benches' --json results as one Markdown table (figure, value, goal, met)",
        description="Reads the results of `ares bench NAME --json` (one per file: its last JSON line) and "
        "prints them as one Markdown table: each bench's goals, then its other headline figures.",
    )
    p.add_argument("files", nargs="+", type=Path, metavar="FILE", help="a bench's --json output")
    p.add_argument("--out", type=Path, metavar="FILE.md", help="write the table there instead of stdout")


def check_goals(result: dict, err: TextIO) -> int:
    """The exit code of `--check`: 1 when the result missed a goal (each named on `err`), else 0."""
    from ares.tools.bench.common import missed_goals

    name = result.get("bench", "the bench")
    if "goals_met" not in result:
        err.write(f"ares: {name} has no goals: nothing to check\n")
        return 0
    missed = missed_goals(result)
    for line in missed:
        err.write(f"ares: {name} missed a goal: {line}\n")
    return 1 if missed else 0


def cmd_bench(args: argparse.Namespace) -> int:
    if args.bench == REPORT:
        return _report(args.files, args.out)
    entry = BY_NAME.get(args.bench)
    if entry is None:
        names = ", ".join(f"`ares bench {b.name}`" for b in BENCHES)
        raise CliError(f"which benchmark? try {names}, or `ares bench {REPORT} FILE...`")
    from ares.tools.bench.common import BenchError

    progress = lambda msg: print(f"[bench] {msg}", file=sys.stderr, flush=True)  # noqa: E731
    try:
        result = entry.run(args, progress)
    except BenchError as exc:
        raise CliError(f"{entry.name} bench failed: {exc}") from None
    result.setdefault("bench", entry.name)
    if args.json:
        print(json.dumps(result))
    else:
        entry.show(result, sys.stdout)
    return check_goals(result, sys.stderr) if args.check else 0


def _report(files: list[Path], out: Path | None) -> int:
    from ares.tools.bench.common import BenchError
    from ares.tools.bench.report import markdown_table, read_result

    try:
        table = markdown_table([read_result(path) for path in files])
    except BenchError as exc:
        raise CliError(str(exc)) from None
    if out is None:
        sys.stdout.write(table)
    else:
        out.write_text(table)
    return 0
