"""``dcseg download``: fetch a job's deliverables (default), every artifact (``--all``), those
``--only`` names, or an export of the scene or of one object (``--format``, ``--instance``);
every file's SHA-256 is checked, sizes go to stderr and paths to stdout."""

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
        help="download a job's results, some of its files, or an export",
        description="Without --format: the job's deliverables (the segment stage's labelled"
        " Gaussians, instances.json, labels.json, labels/, masks/, metrics.json, preview.png,"
        " run.json; its state/ caches and the earlier stages' folders are left out), every"
        " file with --all, or those --only names. With --format: an export of the scene, or"
        " of one object with --instance, made by the service on demand (the command waits"
        " while it is made). A file already in DEST with the right SHA-256 is kept; an"
        " interrupted download resumes. Exit codes: 0 done, 1 refused, 2 bad arguments,"
        " 3 service unreachable, 4 job not found, 5 export not ready within --timeout.",
    )
    parser.add_argument("job_id")
    parser.add_argument("dest", type=Path, help="folder to write into (one sub-folder per stage)")
    chosen = parser.add_mutually_exclusive_group()
    chosen.add_argument(
        "--only",
        type=_names,
        action="append",
        metavar="PATTERN",
        help="fetch the files this glob names (repeatable; commas separate several), e.g."
        " instances.json, 'segment/labels/*', masks (a pattern matches the whole listed path,"
        " its end after a '/', or a folder)",
    )
    chosen.add_argument(
        "--all", action="store_true", help="fetch every file of every stage (state/ included)"
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


def _report(name: str, size: int) -> None:
    from dcseg.client.selection import human_size

    sys.stderr.write(f"{human_size(size):>10}  {name}\n")


def _fetch(client: Any, args: argparse.Namespace, only: list[str] | None) -> list[Path]:
    if args.format is not None:
        exported: list[Path] = client.download_export(
            args.job_id,
            args.format,
            args.dest,
            instance=args.instance,
            only=only,
            timeout=args.timeout,
        )
        for path in exported:
            _report(path.relative_to(args.dest).as_posix(), path.stat().st_size)
        return exported
    items = client.choose(args.job_id, only=only, everything=args.all)
    files = []
    for item in items:
        files.append(client.fetch_one(item, args.dest))
        _report(item["name"], int(item.get("size") or files[-1].stat().st_size))
    return files


def run(args: argparse.Namespace) -> int:
    from dcseg.cli._client import USAGE, report
    from dcseg.client import ClientError, client_from_args
    from dcseg.client.selection import human_size

    if args.instance is not None and args.format is None:
        sys.stderr.write("dcseg download: --instance needs --format (see dcseg download -h)\n")
        return USAGE
    only = [name for group in args.only for name in group] if args.only else None
    with client_from_args(args.url, args.api_key) as client:
        try:
            files = _fetch(client, args, only)
        except (ClientError, TimeoutError) as error:
            return report("download", error)
        except ValueError as error:
            sys.stderr.write(f"dcseg download: --only: {error}\n")
            return USAGE
    total = sum(path.stat().st_size for path in files)
    sys.stderr.write(f"{human_size(total):>10}  total, {len(files)} files in {args.dest}\n")
    for path in files:
        sys.stdout.write(f"{path}\n")
    return 0
