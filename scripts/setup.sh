#!/usr/bin/env bash
# Set up this checkout: system libraries, .venv (Python >= 3.11), `pip install -e '.[test]'`, the
# pages' JavaScript libraries (npm ci in blackbox/web).
# Idempotent and fast when already done: pip runs only when pyproject.toml changed since the
# last install (its hash is kept in .venv/.ares-install-stamp). Progress goes to stderr.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="$ROOT/.venv"
STAMP="$VENV/.ares-install-stamp"
# open3d needs libusb and libGL; numpy/open3d libgomp; wrk: API bench load; chromium: the page tests'
# browser (Playwright drives Debian's Chromium). npm (the pages' libraries) only where no npm is on
# the PATH: a Node.js from elsewhere brings its own, and Debian's npm package would conflict with it.
# iproute2: `ares deploy rehearse` builds its hosts as network namespaces. gpsd, gpsd-clients: the GNSS driver's
# tests replay receiver logs through gpsd with gpsfake. rtklib: str2str, the NTRIP caster of `ares run --wire` and the tests.
SYSTEM_PACKAGES=(libusb-1.0-0 libgl1 libgomp1 wrk chromium iproute2 gpsd gpsd-clients rtklib)
command -v npm >/dev/null 2>&1 || SYSTEM_PACKAGES+=(npm)

say() { echo "[setup] $*" >&2; }

# ---- 1. system libraries (Debian/Ubuntu) --------------------------------------------------
if command -v dpkg-query >/dev/null 2>&1; then
  missing=()
  for pkg in "${SYSTEM_PACKAGES[@]}"; do
    if ! dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed"; then
      missing+=("$pkg")
    fi
  done
  if [ ${#missing[@]} -eq 0 ]; then
    say "system libraries: present"
  elif [ "$(id -u)" -eq 0 ] && command -v apt-get >/dev/null 2>&1; then
    say "system libraries: installing ${missing[*]}"
    export DEBIAN_FRONTEND=noninteractive
    apt_log="$(mktemp)"
    if ! { apt-get update -qq && apt-get install -y -qq --no-install-recommends "${missing[@]}"; } >"$apt_log" 2>&1; then
      tail -n 5 "$apt_log" >&2
      say "WARNING: could not install ${missing[*]}; what needs them will fail (open3d: the LiDAR simulation;"
    say "         chromium: the page tests; npm: the pages' map and plots)"
    fi
    rm -f "$apt_log"
  else
    say "WARNING: missing system libraries: ${missing[*]}"
    say "         install them with: sudo apt-get install -y ${missing[*]}"
  fi
else
  say "system libraries: not a dpkg system, make sure libusb-1.0, libGL and libgomp are installed"
fi

# ---- 2. virtual environment ---------------------------------------------------------------
python_ok() {  # is $1 a Python >= 3.11?
  "$1" -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else 1)' >/dev/null 2>&1
}
if [ -x "$VENV/bin/python" ] && python_ok "$VENV/bin/python"; then
  say ".venv: present ($("$VENV/bin/python" -V 2>&1))"
else
  PY=""
  for candidate in "${PYTHON:-}" python3.13 python3.12 python3.11 python3; do
    if [ -n "$candidate" ] && command -v "$candidate" >/dev/null 2>&1 && python_ok "$candidate"; then
      PY="$(command -v "$candidate")"
      break
    fi
  done
  if [ -z "$PY" ]; then
    say "ERROR: Python 3.11 or newer is needed (set PYTHON=/path/to/python3.11)"
    exit 1
  fi
  say ".venv: creating with $("$PY" -V 2>&1)"
  rm -f "$STAMP"
  "$PY" -m venv "$VENV"
fi

# ---- 3. the package and its dependencies --------------------------------------------------
want="$(cat "$ROOT/pyproject.toml" <("$VENV/bin/python" -V 2>&1) | sha256sum | cut -d' ' -f1)"
have="$(cat "$STAMP" 2>/dev/null || true)"
if [ "$want" = "$have" ] && [ -x "$VENV/bin/ares" ]; then
  say "package: up to date"
else
  say "package: pip install -e '.[test]' (pyproject.toml changed or first install)"
  "$VENV/bin/python" -m pip install --disable-pip-version-check -q -e "$ROOT[test]"
  echo "$want" > "$STAMP"
  say "package: installed"
fi

# ---- 4. the pages' libraries (Leaflet, uPlot) from the npm registry -------------------------
WEB="$ROOT/blackbox/web"
web_want="$(sha256sum "$WEB/package-lock.json" | cut -d' ' -f1)"
web_have="$(cat "$WEB/node_modules/.ares-install-stamp" 2>/dev/null || true)"
if [ "$web_want" = "$web_have" ]; then
  say "page libraries: up to date"
elif command -v npm >/dev/null 2>&1; then
  say "page libraries: npm ci (blackbox/web)"
  (cd "$WEB" && npm ci --no-audit --no-fund --loglevel=error >&2)
  echo "$web_want" > "$WEB/node_modules/.ares-install-stamp"
else
  say "WARNING: npm is missing: the web pages will have no map or plots (apt-get install npm)"
fi
