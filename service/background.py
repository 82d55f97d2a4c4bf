"""Blocking calls from the API's background tasks that outlive a cancellation.

Cancelling a task awaiting ``run_in_threadpool`` ends the task at once while its thread keeps
running, holding a database connection. If the store is closed then (app shutdown), that
connection is returned to a disposed pool and never closed: it leaks until garbage collection.
:func:`in_thread` lets the thread finish before the cancellation goes on, so the shutdown's
deadline (``shutdown_grace_s``) is the only bound and the store closes after its users.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from typing import ParamSpec, TypeVar

from fastapi.concurrency import run_in_threadpool

P = ParamSpec("P")
T = TypeVar("T")


async def in_thread(func: Callable[P, T], *args: P.args, **kwargs: P.kwargs) -> T:
    """``func(*args, **kwargs)`` in the thread pool; when the caller is cancelled, wait for the
    call to return (its result or error is dropped) and then re-raise the cancellation."""
    call = asyncio.ensure_future(run_in_threadpool(func, *args, **kwargs))
    try:
        return await asyncio.shield(call)
    except asyncio.CancelledError:
        await asyncio.wait([call])
        if not call.cancelled():
            call.exception()  # retrieved: no "exception was never retrieved" warning
        raise
