"""``dcseg wait``: follow a job until it ends, with a progress bar on stderr; exit 0 when it
succeeded, 1 when it failed or was canceled (the reason in one line)."""

from __future__ import annotations

import argparse
import sys
from contextlib import closing
from typing import Any

STEPS = 1000
BAR = "{desc}: {percentage:3.0f}%|{bar}| {elapsed}{postfix}"
"""No rate or remaining time: the job's fraction does not advance at a steady rate."""


def register(subparsers: Any) -> None:
    from dcseg.client import add_connection_options

    parser = subparsers.add_parser(
        "wait",
        help="wait for a job of a dcseg service to end, showing its progress",
        description="Follow the job's event stream (reconnecting with Last-Event-ID after a"
        " dropped connection; polling the job when the stream is unavailable) with a progress"
        " bar on stderr. Prints 'JOB succeeded'. Exit codes: 0 succeeded, 1 failed or"
        " canceled, 3 service unreachable, 4 no such job, 5 still running at --timeout.",
    )
    parser.add_argument("job_id")
    parser.add_argument(
        "--timeout", type=float, default=24 * 3600.0, help="seconds (default 1 day)"
    )
    parser.add_argument("--poll", action="store_true", help="poll the job, no event stream")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    add_connection_options(parser)
    parser.set_defaults(run=run)


class JobBar:
    """One tqdm bar for the whole job: the job's fraction, its stage (``segment 4/4``) and
    the last message; ``log`` events are printed above it."""

    def __init__(self, enabled: bool) -> None:
        self.enabled = enabled
        self.bar: Any = None

    def __call__(self, event: Any) -> None:
        if not self.enabled or not isinstance(event.data, dict):
            return
        data: dict[str, Any] = event.data
        if self.bar is None:
            from tqdm import tqdm

            self.bar = tqdm(total=STEPS, file=sys.stderr, leave=True, desc="queued", bar_format=BAR)
        if event.type == "progress":
            index, count = data.get("stage_index"), data.get("stage_count")
            place = f" {index + 1}/{count}" if index is not None and count else ""
            self.bar.set_description_str(f"{data.get('stage')}{place}", refresh=False)
            self.bar.n = min(STEPS, round(float(data.get("fraction") or 0.0) * STEPS))
        elif event.type == "log":
            self.bar.write(f"  {data.get('message')}", file=sys.stderr)
        elif event.type in ("status", "completed") and data.get("status"):
            if data.get("status") == "succeeded":
                self.bar.n = STEPS
            self.bar.set_description_str(str(data["status"]), refresh=False)
        if data.get("message"):
            self.bar.set_postfix_str(" ".join(str(data["message"]).split()), refresh=False)
        self.bar.refresh()

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
        self.bar = None


def run(args: argparse.Namespace) -> int:
    from dcseg.cli._client import report
    from dcseg.client import ClientError, client_from_args

    with client_from_args(args.url, args.api_key) as client, closing(JobBar(not args.quiet)) as bar:
        try:
            if args.poll:
                job = client.wait(args.job_id, timeout=args.timeout, on_event=bar)
            else:
                job = client.follow(args.job_id, on_event=bar, timeout=args.timeout)
        except (ClientError, TimeoutError) as error:
            bar.close()  # the error line goes below the bar
            return report("wait", error)
    sys.stdout.write(f"{job['id']} {job['status']}\n")
    return 0
