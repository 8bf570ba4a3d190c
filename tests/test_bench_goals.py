"""A bench's goals: judged on its result, failing `ares bench NAME --check` when one is missed (named
on stderr), and `ares bench report` making one table of several results."""

from __future__ import annotations

import io
import json
import subprocess
import sys

from ares.cli import build_parser
from ares.cli.bench import check_goals
from ares.cli.bench_table import BENCHES
from ares.tools.bench.common import Goal, judge, missed_goals
from ares.tools.bench.report import markdown_table
from tests.helpers.stack import REPO


def mpc_like(p50: float, misses: int) -> dict:
    return judge(
        {"bench": "mpc", "solve_p50_ms": p50, "deadlines": {"misses": misses}, "solve_max_ms": 2.5},
        {"solve_p50_ms": Goal(1.0), "deadlines.misses": Goal(0), "rate": Goal(10.0, at_least=True)},
    )


def test_goals_are_judged_by_their_bound_and_a_missing_figure_misses():
    result = mpc_like(p50=0.8, misses=0)
    assert result["goals"] == {
        "solve_p50_ms": {"at_most": 1.0},
        "deadlines.misses": {"at_most": 0},
        "rate": {"at_least": 10.0},
    }
    assert result["goals_met"] == {"solve_p50_ms": True, "deadlines.misses": True, "rate": False}  # no rate figure
    assert missed_goals(result) == ["rate None, goal at least 10"]
    slow = mpc_like(p50=1.2, misses=3)
    assert missed_goals(slow) == [
        "solve_p50_ms 1.2, goal at most 1",
        "deadlines.misses 3, goal at most 0",
        "rate None, goal at least 10",
    ]


def test_check_fails_on_a_missed_goal_and_names_it_also_from_a_result_read_back():
    missed = json.loads(json.dumps(mpc_like(p50=1.2, misses=0)))  # as `ares bench report` reads it
    err = io.StringIO()
    assert check_goals(missed, err) == 1
    assert "ares: mpc missed a goal: solve_p50_ms 1.2, goal at most 1" in err.getvalue()
    met = judge({"bench": "path", "query_p50_us": 12.0}, {"query_p50_us": Goal(30.0)})
    err = io.StringIO()
    assert check_goals(met, err) == 0 and err.getvalue() == ""
    err = io.StringIO()
    assert check_goals({"bench": "supervisor", "rounds": 3}, err) == 0 and "no goals" in err.getvalue()


def test_every_bench_takes_check_and_json():
    parser = build_parser()
    for bench in BENCHES:
        args = parser.parse_args(["bench", bench.name, "--json", "--check"])
        assert (args.bench, args.json, args.check) == (bench.name, True, True)


def test_a_real_bench_is_judged_by_its_goals_and_check_reads_them():
    # a short MPC bench, then its result judged against a deadline no solver meets (a p50 of 0 ms)
    from ares.tools.bench import mpc

    result = mpc.run_mpc_bench(solves=50)
    assert set(result["goals_met"]) == set(mpc.MPC_GOALS)
    strict = judge(result, {**mpc.MPC_GOALS, "solve_p50_ms": Goal(0.0)})
    err = io.StringIO()
    assert check_goals(strict, err) == 1 and "solve_p50_ms" in err.getvalue()


def test_report_makes_one_table_of_the_results(tmp_path):
    files = []
    for k, result in enumerate((mpc_like(p50=0.8, misses=0), mpc_like(p50=1.2, misses=2))):
        path = tmp_path / f"result{k}.json"
        path.write_text("[bench] progress that went to the same file\n" + json.dumps(result) + "\n")
        files.append(str(path))
    out = subprocess.run(
        [sys.executable, "-m", "ares.cli", "bench", "report", *files],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
        stdin=subprocess.DEVNULL,
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout == markdown_table([mpc_like(p50=0.8, misses=0), mpc_like(p50=1.2, misses=2)])
    lines = out.stdout.splitlines()
    assert lines[0] == "| bench | figure | value | goal | met |"
    assert "| `mpc` | `solve_p50_ms` | 0.8 | ≤ 1 | yes |" in lines
    assert "| `mpc` | `solve_p50_ms` | 1.2 | ≤ 1 | **no** |" in lines
    assert "| `mpc` | `rate` | n/a | ≥ 10 | **no** |" in lines
    assert lines.count("| `mpc` | `solve_max_ms` | 2.5 |  |  |") == 2  # a headline figure without a goal


def test_report_refuses_a_file_without_a_result(tmp_path):
    empty = tmp_path / "empty.json"
    empty.write_text("[bench] a bench that failed before its result\n")
    out = subprocess.run(
        [sys.executable, "-m", "ares.cli", "bench", "report", str(empty)],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
        stdin=subprocess.DEVNULL,
    )
    assert out.returncode == 1 and "no JSON result line" in out.stderr
