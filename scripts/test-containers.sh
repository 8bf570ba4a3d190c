#!/usr/bin/env bash
# The optional container stage (docs/deploy.md, "The container rehearsal"): not part of
# scripts/test.sh, since it needs root, a Docker engine and about 8 minutes. It installs Debian's
# docker.io and debootstrap when they are missing, builds the images on the given base
# (debootstrap unless told) and runs the fleet's and two vehicles' compose stacks for real.
# Exit 0 only if every figure holds and nothing is left behind.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
base="${1:-debootstrap}"
bash scripts/setup.sh
bash scripts/setup-containers.sh
.venv/bin/python -m ares.cli deploy images --base "$base"
.venv/bin/python -m ares.cli deploy rehearse --containers --base "$base" --json
