"""``dcseg download``: fetch every artifact of a job (SHA-256 checked)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any


def register(subparsers: Any) -> None:
    from dcseg.client import add_connection_options

    parser = subparsers.add_parser("download", help="download a job's artifacts")
    parser.add_argument("job_id")
    parser.add_argument("dest", type=Path, help="folder to write into (one sub-folder per stage)")
    add_connection_options(parser)
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from dcseg.client import ApiError, client_from_args

    with client_from_args(args.url, args.api_key) as client:
        try:
            files = client.download(args.job_id, args.dest)
        except ApiError as error:
            sys.stderr.write(f"dcseg download: {error}\n")
            return 1
    for path in files:
        sys.stdout.write(f"{path}\n")
    return 0
