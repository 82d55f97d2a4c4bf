"""``dcseg status``: print a job's status as JSON."""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any


def register(subparsers: Any) -> None:
    from dcseg.client import add_connection_options

    parser = subparsers.add_parser("status", help="show a job of a dcseg service")
    parser.add_argument("job_id")
    add_connection_options(parser)
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from dcseg.client import ApiError, client_from_args

    with client_from_args(args.url, args.api_key) as client:
        try:
            job = client.status(args.job_id)
        except ApiError as error:
            sys.stderr.write(f"dcseg status: {error}\n")
            return 1
    sys.stdout.write(json.dumps(job, indent=2) + "\n")
    return 0
