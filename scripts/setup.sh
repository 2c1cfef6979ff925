#!/usr/bin/env bash
# Create .venv and install StableMo with its test extras.
# TORCH_SPEC picks the torch build: the default is the CPU wheel pinned for machines without a
# GPU; GPU users set e.g. TORCH_SPEC="torch" (or a CUDA index) before running this.
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON=${PYTHON:-python3}
TORCH_SPEC=${TORCH_SPEC:-torch==2.13.0}
if [ ! -x .venv/bin/python ]; then
  "$PYTHON" -m venv .venv
fi
.venv/bin/python -m pip install -q --upgrade pip >/dev/null
.venv/bin/python -m pip install -q "$TORCH_SPEC"
# PYTHONWARNINGS: setuptools warns on every editable install that folders named like the package
# may shadow it (stablemo/ is that package); errors still print
PYTHONWARNINGS=ignore .venv/bin/python -m pip install -q -e ".[dev,serve]"
# `stablemo serve` needs three.js from its npm package (never committed); without npm the command says how to get it
if command -v npm >/dev/null; then
  .venv/bin/stablemo vendor three || echo "setup: three.js not vendored; \`stablemo serve\` will say how to get it"
  # Khronos' glTF validator, which tests/test_gltf.py runs on every GLB we write (into .venv/node)
  .venv/bin/stablemo vendor gltf-validator || echo "setup: gltf-validator not installed; its tests are skipped"
else
  echo "setup: npm not found, skipping three.js for \`stablemo serve\` (apt-get install npm, then: .venv/bin/stablemo vendor three)"
fi
