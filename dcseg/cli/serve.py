"""``dcseg serve``: the HTTP API (uvicorn); without a broker it also runs jobs itself."""

from __future__ import annotations

import argparse
import ipaddress
import sys
from typing import Any


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


def run(args: argparse.Namespace) -> int:
    import uvicorn

    from service.main import create_app
    from service.settings import get_settings

    settings = get_settings()
    if not settings.api_keys.strip() and not is_loopback(args.host):
        sys.stderr.write(
            f"dcseg serve: refusing to bind {args.host} without API keys; set DCSEG_API_KEYS "
            "(tenant:key,...) or bind 127.0.0.1\n"
        )
        return 2
    uvicorn.run(create_app(settings), host=args.host, port=args.port, log_level=args.log_level)
    return 0
