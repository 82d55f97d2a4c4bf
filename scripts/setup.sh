#!/usr/bin/env bash
# Create .venv (if missing), install dcseg with its dev extras and build the browser viewer.
# Source it or run it.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

python3 -c 'import sys; assert sys.version_info >= (3, 11), "dcseg needs Python >= 3.11"'
[ -x .venv/bin/python ] || python3 -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
# The CPU wheel first: an unpinned torch would pull a multi-GB CUDA build.
.venv/bin/python -m pip install -q torch==2.13.0
.venv/bin/python -m pip install -q -e ".[dev]"

# The viewer's JavaScript (versions locked in viewer/package-lock.json) into
# dcseg/viewer/static/viewer.js; without npm, `dcseg view` and /viewer/{id} say how to build it.
if command -v npm >/dev/null; then
    (cd viewer && npm ci --no-audit --no-fund --loglevel=error && npm run --silent build)
    # The independent readers the export tests run (glTF validator, splat-transform); registry
    # tarballs only (--ignore-scripts: nothing is downloaded at install time).
    (cd tools/export-check && npm ci --no-audit --no-fund --ignore-scripts --loglevel=error)
else
    echo "setup: npm not found; the browser viewer is not built (see viewer/)" >&2
fi

# Compile the numba kernels once into their on-disk cache (~30 s of CPU), so that the first run
# does not; prints the count of kernels compiled or loaded.
.venv/bin/dcseg warmup | tail -n 2
