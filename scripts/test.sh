#!/usr/bin/env bash
# The one test command (README and .ci/run): set up .venv, then lint, type-check and test.
# Usage: bash scripts/test.sh [extra pytest args]
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
. .venv/bin/activate
export OMP_WAIT_POLICY=PASSIVE  # torch and numba thread pools must not spin against each other

# The viewer test drives Debian's chromium (never a downloaded browser); install it when we
# can (root with apt-get), else that test skips saying so.
if ! command -v chromium >/dev/null && [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    echo "== apt-get install chromium"
    { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null; } \
        || echo "chromium could not be installed: the viewer tests will skip" >&2
fi

# One command per line: under `set -e` a failure on the left of `&&` does not stop the script
# (a ruff error once passed CI so).
echo "== ruff"; ruff check .
ruff format --check .
echo "== mypy"; mypy dcseg jobstore service worker tests benchmarks
echo "== import-linter"; lint-imports  # the layers in pyproject.toml [tool.importlinter]
echo "== pytest"; python -m pytest -q "$@"
