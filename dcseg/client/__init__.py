"""A Python client of the dcseg REST API (httpx): :class:`Client`.

:class:`AsyncClient` is its asyncio twin. Both retry what is safe to retry
(:class:`RetryPolicy`), resume downloads, follow a job's event stream, and raise
:class:`ClientError` subclasses with one-line messages.

Example:
    >>> with Client("http://127.0.0.1:8000", api_key="key") as client:  # doctest: +SKIP
    ...     upload = client.upload(Path("scene.tar"))
    ...     job = client.submit(upload["id"], preset="fast")
    ...     client.follow(job["id"], timeout=3600)
    ...     client.download(job["id"], Path("out"))  # the deliverables
"""

from __future__ import annotations

from dcseg.client.aio import AsyncClient
from dcseg.client.connect import DEFAULT_URL, add_connection_options, client_from_args
from dcseg.client.errors import ApiError, ClientError, JobFailed, NetworkError
from dcseg.client.events import ServerEvent
from dcseg.client.retry import RetryPolicy, retry_after
from dcseg.client.selection import DELIVERABLES, choose, deliverables, matches, select
from dcseg.client.sync import TERMINAL, Client

__all__ = [
    "DEFAULT_URL",
    "DELIVERABLES",
    "TERMINAL",
    "ApiError",
    "AsyncClient",
    "Client",
    "ClientError",
    "JobFailed",
    "NetworkError",
    "RetryPolicy",
    "ServerEvent",
    "add_connection_options",
    "choose",
    "client_from_args",
    "deliverables",
    "matches",
    "retry_after",
    "select",
]
