"""``dcseg worker``: a Celery worker running dcseg jobs from the broker (DCSEG_BROKER_URL)."""

from __future__ import annotations

import argparse
import sys
from typing import Any


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "worker",
        help="run a Celery worker for dcseg jobs",
        description="Consume dcseg jobs from DCSEG_BROKER_URL. Run one worker per GPU "
        "(--concurrency 1, the default). SIGTERM stops the running job at its next progress "
        "report and puts it back on the queue; the next worker resumes it after its last "
        "finished stage.",
    )
    parser.add_argument("--queues", default=None, help="comma-separated queues (default: gpu)")
    parser.add_argument("--concurrency", type=int, default=1, help="worker processes (default 1)")
    parser.add_argument(
        "--pool", default="prefork", choices=["prefork", "solo", "threads"], help="Celery pool"
    )
    parser.add_argument("--loglevel", default="info", help="Celery log level")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from jobstore.settings import get_settings

    settings = get_settings()
    if not settings.broker_url:
        sys.stderr.write(
            "dcseg worker: DCSEG_BROKER_URL is not set (without a broker, `dcseg serve` runs "
            "jobs itself)\n"
        )
        return 2
    from worker.celery_app import app
    from worker.workspace import clear_scratch

    clear_scratch(settings)  # left by a worker killed mid-job (its jobs resume elsewhere)
    queues = args.queues or settings.gpu_queue
    app.worker_main(
        [
            "worker",
            "--queues",
            queues,
            "--concurrency",
            str(args.concurrency),
            "--pool",
            args.pool,
            "--loglevel",
            args.loglevel,
            "--without-gossip",
            "--without-mingle",
        ]
    )
    return 0
