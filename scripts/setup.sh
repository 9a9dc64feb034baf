#!/usr/bin/env bash
# Set up smspace from nothing: a virtual environment in .venv with pinned versions.
# Idempotent: a second run only checks. Usage: bash scripts/setup.sh
set -euo pipefail
cd "$(dirname "$0")/.."

# A Vulkan device for SAPIEN (the arm setups): Mesa 25 lavapipe in .vk/, unless a GPU driver exists.
bash scripts/setup-vulkan.sh

PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv
fi
# torch is pinned to 2.13.0 (CPU wheel): an unpinned torch pulls a multi-GB CUDA build.
.venv/bin/python -m pip install -q --disable-pip-version-check -c constraints.txt -e ".[dev]"
# rerun's CLI would otherwise print a first-run analytics notice (and try to phone home).
.venv/bin/rerun analytics disable >/dev/null 2>&1 || true
echo "smspace is set up in .venv ($(.venv/bin/smgen --version))"
