#!/usr/bin/env bash
# Set up, then run every check and every test. Without arguments:
#   1. the static checks: ruff (lint and format), mypy (strict on the core); import-linter's layers are
#      a test (tests/test_layers.py);
#   2. the tests that run in one process (most of them, the in-process stack among them) on both
#      cores (pytest-xdist, `-m "not stack"`): three workers, so that a test waiting on a paced
#      client or a timeout leaves its core to the others, and work stealing, so that no worker
#      idles while another still holds a queue of tests;
#   3. the tests that start real processes over a real router (`-m stack`): those with a few processes
#      three at a time, then those that start a whole vehicle stack (`-m whole_stack`: each wants
#      both cores) one at a time;
# then the time pytest took, both parts added up. With arguments: `python -m pytest -q "$@"` from the
# repository root (paths relative to it), no static checks. Exits non-zero if anything failed;
# "no tests collected" (5) counts as a failure.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$ROOT/scripts/setup.sh"
cd "$ROOT"
BIN="$ROOT/.venv/bin"
# compiled modules and pytest's rewritten tests are kept (in __pycache__, ignored by git): without
# them every pytest worker rewrites every test module again (~7 s of CPU each) and every process
# of every stack compiles its modules again
unset PYTHONDONTWRITEBYTECODE
say() { echo "[test] $*" >&2; }

if [ "$#" -gt 0 ]; then
  rc=0
  "$BIN/python" -m pytest -q "$@" || rc=$?
  if [ "$rc" -eq 5 ]; then say "no tests were collected: that is a failure"; exit 1; fi
  exit "$rc"
fi

checks_rc=0
say "ruff check";            "$BIN/ruff" check --quiet . || checks_rc=1
say "ruff format --check";   "$BIN/ruff" format --check --quiet . || checks_rc=1
say "mypy";                  "$BIN/mypy" || checks_rc=1

seconds() { date +%s.%N; }
rc=0
start=$(seconds)
"$BIN/python" -m pytest -q -m "not stack" -n 3 --dist worksteal || rc=$?
middle=$(seconds)
stack_rc=0
# only the modules that hold stack tests: collecting all of them again costs ~6 s. Those that start a
# few processes (the supervisor's, the API's) mostly wait on timers: three at a time; each whole
# vehicle stack wants both cores: one at a time
mapfile -t stack_modules < <(grep -l "pytest.mark.stack" tests/test_*.py)
"$BIN/python" -m pytest -q -m "stack and not whole_stack" -n 3 "${stack_modules[@]}" || stack_rc=$?
"$BIN/python" -m pytest -q -m whole_stack "${stack_modules[@]}" || stack_rc=$?
end=$(seconds)
if [ "$rc" -eq 0 ]; then rc=$stack_rc; fi
# the budget (8 minutes) is reported, loudly when it is overrun, not enforced: a test run's time
# is the machine's as much as the tests', and a slow day must not fail a correct change
awk -v a="$start" -v b="$middle" -v c="$end" 'BEGIN {
  printf "[test] pytest: %.0f s in one process + %.0f s real processes = %.0f s (budget 480 s)\n", b - a, c - b, c - a
  if (c - a > 480) printf "[test] OVER BUDGET: the tests took more than 8 minutes; make the slowest (above) cheaper\n" }' >&2
if [ "$rc" -eq 5 ]; then say "no tests were collected: that is a failure"; rc=1; fi
if [ "$checks_rc" -ne 0 ]; then say "the static checks failed (above)"; [ "$rc" -ne 0 ] || rc=1; fi
exit "$rc"
