#!/usr/bin/env bash
# The one test command (README and .ci/run): set up .venv, then lint, type-check and test.
# Usage: bash scripts/test.sh [extra pytest args]
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
. .venv/bin/activate
export OMP_WAIT_POLICY=PASSIVE  # torch and numba thread pools must not spin against each other

echo "== ruff"; ruff check . && ruff format --check .
echo "== mypy"; mypy dcseg tests benchmarks
echo "== pytest"; python -m pytest -q "$@"
