"""Benchmark start-up: the CLI's import cost, numba compilation and ``dcseg reconstruct``.

Usage::

    python benchmarks/bench_startup.py --capture ../shared/data/replica_room0_small \\
        --intrinsics 600,600,599.5,339.5 --baseline /path/to/other/checkout \\
        --out benchmarks/results/startup.json

Every figure is a whole child process's user + system CPU seconds and peak RSS (the operating
system's accounting, ``os.wait4``) and its wall seconds, as median, min and max over
``--runs``. With ``--baseline`` (another checkout of dcseg, run with ``PYTHONPATH`` pointing
at it) each command runs in turn for this tree and the baseline (A B A B ...) and the ratio
this/baseline is taken pair by pair, so that drifts of a shared machine cancel. Commands:

* ``help``: ``python -m dcseg --help`` (what every command pays before it starts);
* ``reconstruct``: ``python -m dcseg reconstruct CAPTURE --iterations N --device cpu`` with
  warm numba caches (each tree's ``dcseg warmup`` runs once first), plus the report's
  ``read`` and ``init`` seconds (decoding and initialisation, wall);
* ``warmup_cold`` / ``warmup_warm`` (this tree only): ``python -m dcseg warmup`` with an empty
  ``NUMBA_CACHE_DIR`` (every kernel compiled) and again with that cache filled (loaded).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent


def measure(cmd: Sequence[str], tree: Path, env: dict[str, str] | None = None) -> dict[str, float]:
    """One run of ``cmd`` with ``PYTHONPATH=tree`` from a neutral folder: CPU, wall, peak."""
    child_env = {**os.environ, "PYTHONPATH": str(tree), **(env or {})}
    start = time.perf_counter()
    proc = subprocess.Popen(
        cmd, env=child_env, cwd=tempfile.gettempdir(),
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
    )  # fmt: skip
    assert proc.stderr is not None
    err = proc.stderr.read()
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - start
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} exited {proc.returncode}: {err.decode()[-2000:]}")
    return {
        "cpu_s": usage.ru_utime + usage.ru_stime,
        "user_s": usage.ru_utime,
        "sys_s": usage.ru_stime,
        "wall_s": wall,
        "peak_mb": usage.ru_maxrss / 1024.0,
    }


def summary(runs: list[dict[str, float]]) -> dict[str, Any]:
    keys = runs[0].keys()
    return {
        key: {
            "median": round(statistics.median(r[key] for r in runs), 3),
            "min": round(min(r[key] for r in runs), 3),
            "max": round(max(r[key] for r in runs), 3),
        }
        for key in keys
    } | {"runs": len(runs)}


def compare(
    cmd: Sequence[str],
    trees: dict[str, Path],
    runs: int,
    extra: Any = None,
    prepare: Any = None,
) -> dict[str, Any]:
    """``runs`` rounds of ``cmd`` for every tree in turn; per tree a summary, then ratios.
    ``prepare`` (if given) runs before each measurement, ``extra`` after it adds to its row."""
    results: dict[str, list[dict[str, float]]] = {name: [] for name in trees}
    for _ in range(runs):
        for name, tree in trees.items():
            if prepare is not None:
                prepare()
            row = measure(cmd, tree)
            if extra is not None:
                row |= extra()
            results[name].append(row)
    out: dict[str, Any] = {name: summary(rows) for name, rows in results.items()}
    if "baseline" in results:
        pairs = zip(results["this"], results["baseline"], strict=True)
        ratios = [
            {k: a[k] / b[k] for k in ("cpu_s", "user_s", "wall_s", "peak_mb")} for a, b in pairs
        ]
        out["ratio_this_over_baseline"] = summary(ratios)
    return out


def report_seconds(out: Path) -> dict[str, float]:
    seconds = json.loads((out / "reconstruction.json").read_text())["seconds"]
    return {"read_s": float(seconds["read"]), "init_s": float(seconds["init"])}


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--capture", type=Path, required=True, help="the capture to reconstruct")
    parser.add_argument("--intrinsics", help="fx,fy,cx,cy for layouts that store none")
    parser.add_argument("--iterations", type=int, default=30, help="reconstruction steps")
    parser.add_argument("--baseline", type=Path, help="another dcseg checkout to compare with")
    parser.add_argument("--runs", type=int, default=5, help="counted runs of each command")
    parser.add_argument("--cold-runs", type=int, default=2, help="runs of the cold warmup")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks/results/startup.json")
    args = parser.parse_args(argv)

    python = sys.executable
    trees = {"this": ROOT} | ({"baseline": args.baseline.resolve()} if args.baseline else {})
    record: dict[str, Any] = {
        "commits": {name: _commit(tree) for name, tree in trees.items()},
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version()},
        "load_average_before": os.getloadavg(),
    }
    record["help"] = compare([python, "-m", "dcseg", "--help"], trees, 2 * args.runs)

    with tempfile.TemporaryDirectory(prefix="bench-startup-") as tmp:
        cold_runs = []
        for i in range(args.cold_runs):
            env = {"NUMBA_CACHE_DIR": str(Path(tmp) / f"numba-{i}")}
            cold_runs.append(measure([python, "-m", "dcseg", "warmup"], ROOT, env))
        warm_env = {"NUMBA_CACHE_DIR": str(Path(tmp) / "numba-0")}
        warm_runs = [measure([python, "-m", "dcseg", "warmup"], ROOT, warm_env) for _ in range(3)]
        record["warmup_cold"] = summary(cold_runs)
        record["warmup_warm"] = summary(warm_runs)

        for name, tree in trees.items():  # warm each tree's own kernel cache (the baseline
            out = Path(tmp) / f"prime-{name}"  # may have no warmup command: a reconstruction)
            measure(_reconstruct(python, args, out, 2), tree)
        out = Path(tmp) / "reconstruct"
        cmd = _reconstruct(python, args, out, args.iterations)
        record["reconstruct"] = compare(
            cmd, trees, args.runs, extra=lambda: report_seconds(out),
            prepare=lambda: shutil.rmtree(out, ignore_errors=True),  # OUT must be new or empty
        )  # fmt: skip
        shown = [args.capture.name if c == str(args.capture.resolve()) else c for c in cmd[1:]]
        record["reconstruct"]["command"] = " ".join(shown).replace(str(out), "OUT")
    record["load_average_after"] = os.getloadavg()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(record, indent=2) + "\n", encoding="utf-8")
    print(json.dumps(record, indent=2))
    return 0


def _reconstruct(python: str, args: argparse.Namespace, out: Path, steps: int) -> list[str]:
    cmd = [python, "-m", "dcseg", "reconstruct", str(args.capture.resolve()), "--out", str(out)]
    cmd += ["--iterations", str(steps), "--device", "cpu"]
    return cmd + (["--intrinsics", args.intrinsics] if args.intrinsics else [])


def _commit(tree: Path) -> str:
    done = subprocess.run(
        ["git", "-C", str(tree), "rev-parse", "--short", "HEAD"], capture_output=True, text=True
    )
    return done.stdout.strip()


if __name__ == "__main__":
    sys.exit(main())
