"""``dcseg serve``: the HTTP API (uvicorn); without a broker it also runs jobs itself.

The API (``service``) and the workers (``worker``) never import each other: this command, the
layer above both, hands the app its embedded worker (:func:`embedded_worker`).
``uvicorn dcseg.cli.serve:create_app --factory`` serves the same app without the command's
checks; ``uvicorn service.main:app`` serves the API alone.
"""

from __future__ import annotations

import argparse
import importlib.util
import ipaddress
import math
import sys
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from fastapi import FastAPI

    from jobstore.settings import Settings
    from worker.local import EmbeddedWorker


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "serve",
        help="run the HTTP API (and, without DCSEG_BROKER_URL, a local worker)",
        description="Serve the dcseg REST API. Settings come from DCSEG_* environment variables "
        "(storage, database, broker, API keys). With no DCSEG_BROKER_URL, jobs run in a local "
        "worker process, so this one command serves jobs on a laptop.",
    )
    parser.add_argument("--host", default="127.0.0.1", help="address to bind (default 127.0.0.1)")
    parser.add_argument("--port", type=int, default=8000, help="port (default 8000)")
    parser.add_argument("--log-level", default="info", help="uvicorn log level")
    parser.set_defaults(run=run)


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def refusal(settings: Settings, host: str) -> str | None:
    """Why ``dcseg serve`` must not start with ``settings`` on ``host``, or None. Tests the
    parsed keys: ``@file`` of comments, ``#x`` or `` , `` configure none."""
    try:
        keys = settings.parsed_api_keys()
    except (OSError, ValueError) as error:
        return str(error)
    if keys or settings.allow_unauthenticated or is_loopback(host):
        return None
    return (
        f"refusing to bind {host} without API keys (DCSEG_API_KEYS configures none); set "
        "DCSEG_API_KEYS (tenant:key,...), bind 127.0.0.1, or set "
        "DCSEG_ALLOW_UNAUTHENTICATED=true to serve everyone without authentication"
    )


def embedded(settings: Settings) -> bool:
    """Whether jobs run in an embedded worker: no broker, and ``DCSEG_EMBEDDED_WORKER`` on."""
    return settings.broker_url is None and settings.embedded_worker != "off"


def embedded_worker(settings: Settings) -> EmbeddedWorker | None:
    """The app's local worker (``service.main.LocalWorkerFactory``): the embedded worker in
    ``DCSEG_EMBEDDED_WORKER`` mode (a child process by default), or None with a broker."""
    mode = settings.embedded_worker
    if mode == "off" or not embedded(settings):
        return None
    from worker.local import EmbeddedWorker

    return EmbeddedWorker(settings, mode=mode)


def missing_worker(settings: Settings) -> str | None:
    """Why jobs could not run here (embedded mode, but no ``worker`` package: the API image),
    or None."""
    if not embedded(settings) or importlib.util.find_spec("worker") is not None:
        return None
    return (
        "no DCSEG_BROKER_URL, so jobs would run in an embedded worker, but the worker package "
        "is not installed (the API image); set DCSEG_BROKER_URL, or DCSEG_EMBEDDED_WORKER=off "
        "to serve the API alone"
    )


def create_app(settings: Settings | None = None) -> FastAPI:
    """The app ``dcseg serve`` runs: the API plus, without a broker, the embedded worker;
    ``settings`` defaults to the environment's."""
    from service.main import create_app as create_api

    return create_api(settings, local_worker=embedded_worker)


def run(args: argparse.Namespace) -> int:
    import uvicorn

    from jobstore.settings import get_settings

    settings = get_settings()
    reason = refusal(settings, args.host) or missing_worker(settings)
    if reason is not None:
        sys.stderr.write(f"dcseg serve: {reason}\n")
        return 2
    uvicorn.run(
        create_app(settings),
        host=args.host,
        port=args.port,
        log_level=args.log_level,
        # open responses (uploads, downloads) get the shutdown grace, then are cancelled
        timeout_graceful_shutdown=graceful_timeout_s(settings),
    )
    return 0


def graceful_timeout_s(settings: Settings) -> int:
    """uvicorn's ``timeout_graceful_shutdown`` (whole seconds): ``shutdown_grace_s``."""
    return max(1, math.ceil(settings.shutdown_grace_s))
