#!/usr/bin/env bash
# Set up smspace from nothing: a virtual environment in .venv with pinned versions.
# Idempotent: a second run only checks. Usage: bash scripts/setup.sh
set -euo pipefail
cd "$(dirname "$0")/.."

# A Vulkan device for SAPIEN (the arm setups): Mesa 25 lavapipe in .vk/, unless a GPU driver exists.
bash scripts/setup-vulkan.sh

# The network tests check with `ss` (iproute2) that every server they start listens on 127.0.0.1 only.
if ! command -v ss >/dev/null 2>&1; then
  SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  $SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends iproute2 >/dev/null
fi

PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv
fi
# torch is pinned to 2.13.0 (CPU wheel): an unpinned torch pulls a multi-GB CUDA build. [dev] brings
# the s3 and cluster extras (s3fs, Ray) and moto's S3 server for the tests.
.venv/bin/python -m pip install -q --disable-pip-version-check -c constraints.txt -e ".[dev]"
# Example plugins (setups and a network registered through entry points): the tests use them.
.venv/bin/python -m pip install -q --disable-pip-version-check --no-deps -e examples/plugin-demo -e examples/ambiguous-room
# rerun's CLI would otherwise print a first-run analytics notice (and try to phone home).
.venv/bin/rerun analytics disable >/dev/null 2>&1 || true
echo "smspace is set up in .venv ($(.venv/bin/smgen --version))"
