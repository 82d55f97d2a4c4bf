"""The ``dcseg`` command line: one module per verb under ``dcseg.cli``.

Each verb module defines ``register(subparsers)``, which adds its parser and sets ``run`` (a
function taking the parsed arguments and returning the exit code). Verb modules import heavy
packages (torch, pybullet) inside ``run`` so that ``dcseg --help`` stays fast.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import pkgutil
import sys
from collections.abc import Sequence

from dcseg import __version__


def verbs() -> list[str]:
    """The verb modules of this package, in alphabetical order."""
    return sorted(m.name for m in pkgutil.iter_modules(__path__) if not m.name.startswith("_"))


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="dcseg",
        description="Segment posed RGB-D captures into labelled 3D Gaussians (DCSEG).",
    )
    parser.add_argument("--version", action="version", version=f"dcseg {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="log debug messages")
    subparsers = parser.add_subparsers(dest="verb", required=True, metavar="COMMAND")
    for verb in verbs():
        importlib.import_module(f"dcseg.cli.{verb}").register(subparsers)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``dcseg`` console script; returns the process exit code."""
    # torch and numba each run a thread pool; spinning waits make them fight over the cores
    # (5-20x slower renders on 2 cores). Must be set before either library loads.
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    args = build_parser().parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
    )
    code: int = args.run(args)
    return code


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
