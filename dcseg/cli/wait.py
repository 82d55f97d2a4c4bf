"""``dcseg wait``: wait for a job to end; exit 0 when it succeeded, 1 otherwise."""

from __future__ import annotations

import argparse
import sys
from typing import Any


def register(subparsers: Any) -> None:
    from dcseg.client import add_connection_options

    parser = subparsers.add_parser("wait", help="wait for a job of a dcseg service to end")
    parser.add_argument("job_id")
    parser.add_argument(
        "--timeout", type=float, default=24 * 3600.0, help="seconds (default 1 day)"
    )
    add_connection_options(parser)
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from dcseg.client import ApiError, JobFailed, client_from_args

    with client_from_args(args.url, args.api_key) as client:
        try:
            job = client.wait(args.job_id, timeout=args.timeout)
        except JobFailed as failed:
            sys.stderr.write(f"dcseg wait: {failed}\n")
            return 1
        except (ApiError, TimeoutError) as error:
            sys.stderr.write(f"dcseg wait: {error}\n")
            return 1
    sys.stdout.write(f"{job['id']} {job['status']}\n")
    return 0
