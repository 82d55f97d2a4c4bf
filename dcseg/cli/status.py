"""``dcseg status``: print a job's status as JSON (exit codes: see ``dcseg.cli._client``)."""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any


def register(subparsers: Any) -> None:
    from dcseg.client import add_connection_options

    parser = subparsers.add_parser(
        "status",
        help="show a job of a dcseg service",
        description="Print the job as JSON. Exit codes: 0 shown, 3 service unreachable,"
        " 4 no such job (or not yours).",
    )
    parser.add_argument("job_id")
    add_connection_options(parser)
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from dcseg.cli._client import report
    from dcseg.client import ClientError, client_from_args

    with client_from_args(args.url, args.api_key) as client:
        try:
            job = client.status(args.job_id)
        except ClientError as error:
            return report("status", error)
    sys.stdout.write(json.dumps(job, indent=2) + "\n")
    return 0
