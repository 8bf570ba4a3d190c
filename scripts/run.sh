#!/usr/bin/env bash
# Set up, then run the whole stack: `ares run --speed paced "$@"` (embedded router, simulated shuttle).
# Runs go to <repo>/runs/ unless ARES_RUNS_DIR or --run-dir says otherwise.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$ROOT/scripts/setup.sh"
export ARES_RUNS_DIR="${ARES_RUNS_DIR:-$ROOT/runs}"
# in lockstep at most at real time unless --speed says otherwise: on a small machine the simulated
# sensors then slow the run down rather than miss their rates (which the stack would take for faults)
case " $* " in
  *" --speed "*|*" --speed="*) exec "$ROOT/.venv/bin/ares" run "$@" ;;
  *) exec "$ROOT/.venv/bin/ares" run --speed paced "$@" ;;
esac
