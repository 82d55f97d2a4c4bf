"""``dcseg download``: fetch a job's artifacts, some of them (``--only``), or an export of the
scene or of one object (``--format``, ``--instance``); every file's SHA-256 is checked."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any


def _names(text: str) -> list[str]:
    names = [n.strip() for n in text.split(",") if n.strip()]
    if not names:
        raise argparse.ArgumentTypeError("give at least one name, e.g. instances.json")
    return names


def _instance(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an instance id") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"instance ids start at 1, not {value}")
    return value


def register(subparsers: Any) -> None:
    from dcseg.client import add_connection_options
    from dcseg.export import FORMATS

    parser = subparsers.add_parser(
        "download",
        help="download a job's artifacts, some of them, or an export",
        description="Without --format: the job's artifacts (all, or those --only names). With"
        " --format: an export of the scene, or of one object with --instance, made by the"
        " service on demand (the command waits while it is made).",
    )
    parser.add_argument("job_id")
    parser.add_argument("dest", type=Path, help="folder to write into (one sub-folder per stage)")
    parser.add_argument(
        "--only",
        type=_names,
        metavar="NAMES",
        help="comma-separated file names to fetch, e.g. instances.json,scene_labelled.ply"
        " (a name matches the listed path it ends with)",
    )
    parser.add_argument("--format", choices=FORMATS, help="download an export in this format")
    parser.add_argument(
        "--instance", type=_instance, metavar="K", help="export object K alone (needs --format)"
    )
    parser.add_argument(
        "--timeout", type=float, default=3600.0, help="seconds to wait for an export (3600)"
    )
    add_connection_options(parser)
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from dcseg.client import ApiError, client_from_args

    if args.instance is not None and args.format is None:
        sys.stderr.write("dcseg download: --instance needs --format (see dcseg download -h)\n")
        return 2
    with client_from_args(args.url, args.api_key) as client:
        try:
            if args.format is None:
                files = client.download(args.job_id, args.dest, only=args.only)
            else:
                files = client.download_export(
                    args.job_id,
                    args.format,
                    args.dest,
                    instance=args.instance,
                    only=args.only,
                    timeout=args.timeout,
                )
        except (ApiError, TimeoutError) as error:
            sys.stderr.write(f"dcseg download: {error}\n")
            return 1
        except ValueError as error:
            sys.stderr.write(f"dcseg download: --only: {error}\n")
            return 2
    for path in files:
        sys.stdout.write(f"{path}\n")
    return 0
