#!/usr/bin/env bash
# Set up, then run every test (tests/): without arguments in two parts (the in-process tests on
# both cores with pytest-xdist, then the whole-stack tests one by one); with arguments
# `python -m pytest -q "$@"` from the repository root (paths relative to the repository). Exits with pytest's
# code; "no tests collected" (5) counts as a failure.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$ROOT/scripts/setup.sh"
cd "$ROOT"
rc=0
if [ "$#" -gt 0 ]; then
  "$ROOT/.venv/bin/python" -m pytest -q "$@" || rc=$?
else
  # the whole suite in two parts: the tests that run in one process (most of them) on both cores;
  # then those that start whole stacks of processes, one at a time (each stack wants both cores)
  "$ROOT/.venv/bin/python" -m pytest -q -m "not stack" -n 2 || rc=$?
  stack_rc=0
  "$ROOT/.venv/bin/python" -m pytest -q -m stack || stack_rc=$?
  if [ "$rc" -eq 0 ]; then rc=$stack_rc; fi
fi
if [ "$rc" -eq 5 ]; then
  echo "[test] no tests were collected: that is a failure" >&2
  exit 1
fi
exit "$rc"
