"""``dcseg submit``: upload a capture (a folder, packed on the fly, or an archive), or reuse
an upload by its id, and create a job; prints the job's id."""

from __future__ import annotations

import argparse
import json
import sys
import uuid
from pathlib import Path
from typing import Any


def register(subparsers: Any) -> None:
    from dcseg.client import add_connection_options

    parser = subparsers.add_parser(
        "submit",
        help="submit a job to a dcseg service",
        description="Upload CAPTURE (a folder, packed into a tar in a temporary file, or a"
        " .zip/.tar/.tar.gz archive; its root holds the capture and optionally"
        " masks/agnostic/, masks/semantic/, vocabulary.txt, gt/points.ply) and create a job;"
        " CAPTURE may also be the id of an earlier upload. Prints the job id. Both requests"
        " carry an Idempotency-Key, so they are retried safely after a network error. Exit"
        " codes: 0 submitted, 1 refused (the problem's fields are listed), 2 bad arguments,"
        " 3 service unreachable, 4 upload or parent job not found.",
    )
    parser.add_argument("capture", help="capture folder or archive, or an upload id")
    parser.add_argument("--preset", default="fast", help="parameter preset (fast, paper)")
    parser.add_argument(
        "--options",
        default="{}",
        help='JSON options, e.g. \'{"reconstruct": {"iterations": 500}}\'',
    )
    parser.add_argument("--parent", help="derive from this finished job (reuses its stages)")
    parser.add_argument(
        "--idempotency-key",
        help="retry-safe key (default: a new one); the same key again answers with the job"
        " the first submission created",
    )
    parser.add_argument("--json", action="store_true", help="print the whole job as JSON")
    add_connection_options(parser)
    parser.set_defaults(run=run)


def _source(text: str) -> Path | str | None:
    """The capture to upload (a path), an upload id, or None when it is neither."""
    path = Path(text)
    if path.exists():
        return path
    try:
        return str(uuid.UUID(text))
    except ValueError:
        return None


def run(args: argparse.Namespace) -> int:
    from dcseg.cli._client import USAGE, report
    from dcseg.client import ClientError, client_from_args

    try:
        options = json.loads(args.options)
    except json.JSONDecodeError as error:
        sys.stderr.write(f"dcseg submit: --options is not JSON ({error})\n")
        return USAGE
    source = _source(args.capture)
    if source is None:
        sys.stderr.write(f"dcseg submit: {args.capture}: no such folder or archive\n")
        return USAGE
    key = args.idempotency_key or str(uuid.uuid4())
    with client_from_args(args.url, args.api_key) as client:
        try:
            if isinstance(source, Path):
                source = str(client.upload(source, idempotency_key=f"{key}.upload")["id"])
            job = client.submit(
                source,
                preset=args.preset,
                options=options,
                parent_job_id=args.parent,
                idempotency_key=key,
            )
        except ValueError as error:
            sys.stderr.write(f"dcseg submit: {error}\n")
            return USAGE
        except ClientError as error:
            return report("submit", error)
    sys.stdout.write((json.dumps(job, indent=2) if args.json else job["id"]) + "\n")
    return 0
