"""How the CLI verbs make a client: flags, then the environment."""

from __future__ import annotations

from typing import Any

from dcseg.client.sync import Client

__all__ = ["DEFAULT_URL", "add_connection_options", "client_from_args"]

DEFAULT_URL = "http://127.0.0.1:8000"


def client_from_args(url: str | None, api_key: str | None) -> Client:
    """A client for the CLI verbs: flags first, then ``DCSEG_URL`` / ``DCSEG_API_KEY``.

    httpx logs every request at INFO (``dcseg wait`` would print one line per poll); its
    logger is raised to WARNING unless the CLI runs with ``--verbose`` (DEBUG).
    """
    import logging
    import os

    if not logging.getLogger().isEnabledFor(logging.DEBUG):
        logging.getLogger("httpx").setLevel(logging.WARNING)
    return Client(
        url or os.environ.get("DCSEG_URL", DEFAULT_URL),
        api_key or os.environ.get("DCSEG_API_KEY") or None,
    )


def add_connection_options(parser: Any) -> None:
    """``--url`` and ``--api-key`` for the CLI verbs talking to a service."""
    parser.add_argument("--url", help=f"service URL (default $DCSEG_URL or {DEFAULT_URL})")
    parser.add_argument("--api-key", help="API key (default $DCSEG_API_KEY)")
