"""``Idempotency-Key`` on POSTs, per tenant: the one helper every idempotent route uses.

Same key + same request replays the first response (``Idempotent-Replayed: true``); same key +
another request answers 422; same key while the first request is still running answers 409; a
request that fails forgets the key so the client may retry. Records expire after
``DCSEG_IDEMPOTENCY_TTL_S``.
"""

from __future__ import annotations

import json
from collections.abc import AsyncIterator, Iterator
from contextlib import asynccontextmanager, contextmanager
from datetime import timedelta
from typing import Annotated, Any

import anyio
from fastapi import Header
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse

from service.deps import AppState
from service.problems import ApiProblem

IdempotencyKeyHeader = Annotated[
    str | None,
    Header(
        alias="Idempotency-Key",
        max_length=255,
        description="Same key + same body replays the first response (per tenant).",
    ),
]

_REPLAYED_HEADERS = ("location", "operation-location", "etag")


class IdempotentRequest:
    """One request under an ``Idempotency-Key`` (or none): a replay, or a response to keep."""

    def __init__(self, replay: JSONResponse | None = None) -> None:
        self.replay = replay
        """The first request's response when this one repeats it; answer it as is."""
        self.kept: JSONResponse | None = None

    def keep(self, response: JSONResponse) -> JSONResponse:
        """Record ``response`` as the answer to replay; returns it."""
        self.kept = response
        return response


def _replay(status_code: int, stored: dict[str, Any]) -> JSONResponse:
    headers = {**stored["headers"], "Idempotent-Replayed": "true"}
    return JSONResponse(stored["body"], status_code=status_code, headers=headers)


def _stored(response: JSONResponse) -> dict[str, Any]:
    headers = {k: v for k, v in response.headers.items() if k in _REPLAYED_HEADERS}
    return {"body": json.loads(bytes(response.body)), "headers": headers}


def _begin(state: AppState, tenant: str, key: str, request_hash: str) -> IdempotentRequest:
    ttl = timedelta(seconds=state.settings.idempotency_ttl_s)
    in_flight = timedelta(seconds=state.settings.idempotency_in_flight_s)
    outcome = state.store.idempotency_begin(tenant, key, request_hash, ttl, in_flight)
    if outcome.kind == "mismatch":
        raise ApiProblem(
            422, "Idempotency-Key was used with a different body", slug="idempotency-mismatch"
        )
    if outcome.kind == "in_flight":
        raise ApiProblem(
            409, "a request with this Idempotency-Key is in progress", slug="idempotency-in-flight"
        )
    if outcome.kind == "replay":
        assert outcome.status_code is not None and outcome.response is not None
        return IdempotentRequest(_replay(outcome.status_code, outcome.response))
    return IdempotentRequest()


def _settle(state: AppState, tenant: str, key: str, request: IdempotentRequest) -> None:
    """After the request ran: store the kept response, or forget the key (nothing kept)."""
    if request.kept is None:
        state.store.idempotency_release(tenant, key)
    else:
        kept = request.kept
        state.store.idempotency_finish(tenant, key, kept.status_code, _stored(kept))


@contextmanager
def idempotent(
    state: AppState, tenant: str, key: str | None, request_hash: str
) -> Iterator[IdempotentRequest]:
    """Run a POST under ``key``: answer ``replay`` when set, else ``keep`` the response.
    For sync routes (the store is called on the current thread).

    Example::

        with idempotent(state, tenant, key, request_hash(body)) as request:
            if request.replay is not None:
                return request.replay
            return request.keep(create(...))
    """
    if key is None:
        yield IdempotentRequest()
        return
    request = _begin(state, tenant, key, request_hash)
    if request.replay is not None:
        yield request
        return
    try:
        yield request
    except BaseException:
        state.store.idempotency_release(tenant, key)
        raise
    _settle(state, tenant, key, request)


@asynccontextmanager
async def idempotent_async(
    state: AppState, tenant: str, key: str | None, request_hash: str
) -> AsyncIterator[IdempotentRequest]:
    """:func:`idempotent` for async routes: the store is called on a worker thread, never on
    the event loop."""
    if key is None:
        yield IdempotentRequest()
        return
    request = await run_in_threadpool(_begin, state, tenant, key, request_hash)
    if request.replay is not None:
        yield request
        return
    try:
        yield request
    except BaseException:
        with anyio.CancelScope(shield=True):  # also when the client went away
            await run_in_threadpool(state.store.idempotency_release, tenant, key)
        raise
    with anyio.CancelScope(shield=True):
        await run_in_threadpool(_settle, state, tenant, key, request)
