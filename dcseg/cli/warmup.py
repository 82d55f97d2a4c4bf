"""``dcseg warmup``: compile every numba kernel once, so that the first real run starts at once."""

from __future__ import annotations

import argparse
import sys
import time
from collections import Counter
from typing import Any


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "warmup",
        help="compile the numba kernels into their on-disk cache",
        description="Run every stage that uses a numba kernel on a tiny in-memory scene, so that "
        "each kernel is compiled once and written to numba's cache (next to the installed "
        "package, or under NUMBA_CACHE_DIR when set: set it when the package folder is "
        "read-only). Later runs load the kernels instead of compiling them (~30 s of CPU). "
        "Prints each kernel and whether it was compiled or loaded; exits 1 when a kernel "
        "was not reached.",
    )
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    start = time.perf_counter()
    try:
        from dcseg.warmup import warm_kernels

        kernels = warm_kernels()
    except RuntimeError as error:
        if "cannot cache function" not in str(error):
            raise
        sys.stderr.write(
            f"dcseg warmup: {error}\nnumba cannot write its cache next to the package: set "
            "NUMBA_CACHE_DIR to a writable folder (and keep it set for later runs)\n"
        )
        return 1
    seconds = time.perf_counter() - start
    for kernel in kernels:
        sys.stdout.write(f"{kernel.status:<10}  {kernel.name}  ({kernel.signatures} signatures)\n")
    counts = Counter(k.status for k in kernels)
    caches = sorted({k.cache for k in kernels if k.signatures})
    summary = ", ".join(f"{n} {status}" for status, n in sorted(counts.items()))
    sys.stdout.write(f"{len(kernels)} kernels in {seconds:.1f} s: {summary}\n")
    sys.stdout.write(f"cache: {'; '.join(caches)}\n")
    missed = [k.name for k in kernels if k.status == "missed"]
    if missed:
        sys.stderr.write(f"dcseg warmup: not reached by the tiny scene: {', '.join(missed)}\n")
        return 1
    return 0
