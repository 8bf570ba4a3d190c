"""`ares compare`: the same headless run with each controller in turn, figures side by side.

    ares compare [--controllers mpc,stanley] [--route R] [--vehicle V] [--scenario S]
                 [--laps N | --seconds S] [--config FILE] [--out PNG] [--json]

Each run is `ares run --headless --speed max --controller C ...` (ares.app.stack.run), one after
the other (the machine's two cores are the stack's); `auto` lets the control manager choose. The
table shows the figures that tell controllers apart; the picture, the cross-track error of each
along the route with the stretches where road reactive control drove shaded.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from .args import CliError, Command, positive_float, positive_int

CONTROLLER_CHOICES = ("auto", "mpc", "rrc", "pure_pursuit", "stanley")
FIGURES = (
    "distance_m",
    "lap_time_s",
    "xte_rmse_m",
    "xte_max_m",
    "xte_max_at_m",
    "xte_rmse_rrc_m",
    "xte_max_rrc_m",
    "lat_accel_max_mps2",
    "jerk_rms_mps3",
    "switches",
    "controller_time_share",
    "mpc_solve_p50_ms",
    "mpc_deadline_misses",
    "loc_max_deadzone_m",
)


def controllers(text: str) -> list[str]:
    names = [n.strip() for n in text.split(",") if n.strip()]
    bad = [n for n in names if n not in CONTROLLER_CHOICES]
    if bad or not names:
        raise argparse.ArgumentTypeError(
            f"controllers are a comma-separated list of {', '.join(CONTROLLER_CHOICES)}; got {text!r}"
        )
    return names


def add_parser(subparsers: argparse._SubParsersAction) -> dict[str, Command]:
    p = subparsers.add_parser(
        "compare",
        help="headless runs with each controller in turn, figures side by side",
        description="The same headless run (--speed max) with each controller pinned in turn "
        "(auto: the control manager chooses); prints the figures side by side "
        "and draws the cross-track error along the route.",
    )
    p.add_argument(
        "--controllers",
        type=controllers,
        default=["mpc", "stanley"],
        metavar="LIST",
        help="comma-separated, of auto, mpc, rrc, pure_pursuit, stanley (default mpc,stanley: ARES Fig. 15's pair)",
    )
    p.add_argument("--route", metavar="NAME|FILE", help="as ares run --route")
    p.add_argument("--vehicle", metavar="NAME", help="as ares run --vehicle")
    p.add_argument("--scenario", metavar="NAME|FILE", help="as ares run --scenario")
    p.add_argument("--laps", type=positive_int, metavar="N", help="laps per run (default 1)")
    p.add_argument(
        "--mission",
        choices=["tour", "drive"],
        default="drive",
        help="as ares run --mission (default drive: comparisons are about control, not stops)",
    )
    p.add_argument("--seconds", type=positive_float, metavar="S", help="vehicle seconds per run instead of laps")
    p.add_argument("--config", action="append", default=[], metavar="FILE", help="as ares run --config")
    p.add_argument("--out", metavar="PNG", help="the picture (default: compare-<time>.png in the runs folder)")
    p.add_argument("--json", action="store_true", help="print one JSON object (last line of stdout)")
    return {"compare": cmd_compare}


def run_one(controller: str, args: argparse.Namespace, run_dir: Path) -> dict:
    """The headless run with `controller` pinned; its result's figures, as `ares run` prints them."""
    from ares.app import stack
    from ares.app.run_options import RunOptions

    options = RunOptions(
        headless=True,
        speed="max",
        controller=controller,
        run_dir=run_dir,
        route=args.route,
        vehicle=args.vehicle,
        scenario=args.scenario,
        laps=args.laps,
        seconds=args.seconds,
        mission=args.mission,
        config_files=tuple(args.config),
    )
    print(f"[compare] {controller}: in {run_dir}", file=sys.stderr, flush=True)
    result = stack.run(options)
    if result.refused:
        raise CliError(f"the run with {controller} was refused: {result.error}")
    if result.interrupted:
        raise CliError(f"interrupted during the run with {controller} (its logs are in {run_dir})")
    if not result.ok:  # a controller that could not finish is a result too: its figures until then
        print(f"[compare] {controller} did not finish: {result.error}", file=sys.stderr, flush=True)
    return result.summary()


def table(results: dict[str, dict]) -> str:
    names = list(results)
    rows = [
        ["figure", *names],
        ["finished", *("yes" if results[n].get("ok") else "no: " + _short(results[n].get("error", "")) for n in names)],
    ]
    for key in FIGURES:
        values = [results[n].get(key) for n in names]
        if all(v is None for v in values):
            continue
        rows.append([key, *(_cell(v) for v in values)])
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    return "\n".join("  ".join(cell.ljust(w) for cell, w in zip(row, widths)) for row in rows)


def _short(error: str, width: int = 40) -> str:
    return error if len(error) <= width else error[: width - 1] + "…"


def _cell(value) -> str:
    if value is None:
        return "-"
    if isinstance(value, dict):
        return " ".join(f"{k} {v:.2f}" for k, v in value.items()) or "-"
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value)


def cmd_compare(args: argparse.Namespace) -> int:
    from ares.app.stack import default_run_dir
    from ares.tools.figures.compare import write_comparison_png

    base = default_run_dir()
    results: dict[str, dict] = {}
    for controller in args.controllers:
        results[controller] = run_one(controller, args, base / f"compare-{controller}")
    out = Path(args.out) if args.out else base / f"compare-{time.strftime('%Y%m%d-%H%M%S')}.png"
    traces = {
        name: Path(r["run_dir"]) / "trace.npz"
        for name, r in results.items()
        if (Path(r["run_dir"]) / "trace.npz").exists()
    }
    first = next(iter(results.values()))
    picture = (
        write_comparison_png(out, traces, title=f"{first.get('route', '')}, {first.get('vehicle', '')}")
        if traces
        else None
    )
    print(table(results))
    print(f"picture: {picture}")
    if args.json:
        print(json.dumps({"runs": results, "plot": None if picture is None else str(picture)}))
    return 0 if all(r.get("ok") for r in results.values()) else 1
