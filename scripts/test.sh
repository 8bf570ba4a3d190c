#!/usr/bin/env bash
# Set up, then run every test (tests/): `python -m pytest -q "$@"` from the repository root,
# so extra arguments are pytest's (paths relative to the repository). Exits with pytest's
# code; "no tests collected" (5) counts as a failure.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$ROOT/scripts/setup.sh"
cd "$ROOT"
rc=0
"$ROOT/.venv/bin/python" -m pytest -q "$@" || rc=$?
if [ "$rc" -eq 5 ]; then
  echo "[test] no tests were collected: that is a failure" >&2
  exit 1
fi
exit "$rc"
