#!/usr/bin/env bash
# Set up, then run the whole stack: `ares run "$@"` (embedded router, simulated shuttle; in lockstep
# at most at real time unless --speed says otherwise: on a small machine the simulated sensors then
# slow the run down rather than miss their rates, which the stack would take for faults).
# Runs go to <repo>/runs/ unless ARES_RUNS_DIR or --run-dir says otherwise.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$ROOT/scripts/setup.sh"
export ARES_RUNS_DIR="${ARES_RUNS_DIR:-$ROOT/runs}"
exec "$ROOT/.venv/bin/ares" run "$@"
