"""``dcseg submit``: upload a capture archive (or reuse an upload) and create a job."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any


def register(subparsers: Any) -> None:
    from dcseg.client import add_connection_options

    parser = subparsers.add_parser(
        "submit",
        help="submit a job to a dcseg service",
        description="Upload ARCHIVE (.zip/.tar/.tar.gz whose root holds the capture and "
        "optionally masks/agnostic/, masks/semantic/, vocabulary.txt, gt/points.ply) and "
        "create a job. ARCHIVE may also be the id of an earlier upload. Prints the job id.",
    )
    parser.add_argument("archive", help="capture archive, or an upload id")
    parser.add_argument("--preset", default="fast", help="parameter preset (fast, paper)")
    parser.add_argument(
        "--options",
        default="{}",
        help='JSON options, e.g. \'{"reconstruct": {"iterations": 500}}\'',
    )
    parser.add_argument("--parent", help="derive from this finished job (reuses its stages)")
    parser.add_argument("--idempotency-key", help="retry-safe key for the job creation")
    parser.add_argument("--json", action="store_true", help="print the whole job as JSON")
    add_connection_options(parser)
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from dcseg.client import ApiError, client_from_args

    try:
        options = json.loads(args.options)
    except json.JSONDecodeError as error:
        sys.stderr.write(f"dcseg submit: --options is not JSON ({error})\n")
        return 2
    with client_from_args(args.url, args.api_key) as client:
        try:
            path = Path(args.archive)
            upload_id = client.upload(path)["id"] if path.is_file() else args.archive
            job = client.submit(
                upload_id,
                preset=args.preset,
                options=options,
                parent_job_id=args.parent,
                idempotency_key=args.idempotency_key,
            )
        except ApiError as error:
            sys.stderr.write(f"dcseg submit: {error}\n")
            for item in error.problem.get("errors", []):
                sys.stderr.write(f"  - {item.get('path')}: {item.get('reason')}\n")
            return 1
    sys.stdout.write((json.dumps(job, indent=2) if args.json else job["id"]) + "\n")
    return 0
