#!/usr/bin/env bash
# The built-in example: set up .venv, then run `dcseg demo` on a synthetic scene.
# Usage: bash scripts/demo.sh [OUT_DIR]   (default: runs/demo)
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
.venv/bin/dcseg demo --out "${1:-runs/demo}"
