"""Request dependencies: the app's state, the caller's tenant (bearer keys) and rate limits."""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, field
from typing import Annotated

from fastapi import Depends, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from service.problems import ApiProblem
from service.queue import JobQueue
from service.settings import Settings
from service.store import Store, hash_key

LOCAL_TENANT = "local"
"""The tenant of every request when no API keys are configured."""


class RateLimiter:
    """Fixed one-minute windows per tenant, in this process's memory.

    With several API replicas each enforces the limit on its own share of the traffic.
    """

    def __init__(self, per_minute: int) -> None:
        self.per_minute = per_minute
        self._windows: dict[str, tuple[int, int]] = {}
        self._lock = threading.Lock()

    def hit(self, tenant: str, now: float | None = None) -> int | None:
        """Count one request; returns the seconds to wait when over the limit, else None."""
        now = time.time() if now is None else now
        window = int(now // 60)
        with self._lock:
            start, count = self._windows.get(tenant, (window, 0))
            if start != window:
                start, count = window, 0
            if count >= self.per_minute:
                return max(1, math.ceil((window + 1) * 60 - now))
            self._windows[tenant] = (start, count + 1)
        return None


@dataclass
class AppState:
    """Everything the routes need, built once per app in its lifespan."""

    settings: Settings
    store: Store
    queue: JobQueue
    key_hashes: dict[str, str] = field(default_factory=dict)
    limiter: RateLimiter = field(default_factory=lambda: RateLimiter(600))


def get_state(request: Request) -> AppState:
    state: AppState = request.app.state.dcseg
    return state


StateDep = Annotated[AppState, Depends(get_state)]

_bearer = HTTPBearer(auto_error=False, description="API key: `Authorization: Bearer <key>`")


def _unauthorized(detail: str, error: str | None) -> ApiProblem:
    challenge = 'Bearer realm="dcseg"' + (f', error="{error}"' if error else "")
    return ApiProblem(401, detail, slug="unauthorized", headers={"WWW-Authenticate": challenge})


def authenticate(
    state: StateDep,
    credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)],
) -> str:
    """The caller's tenant; 401 without a valid key, 429 over the tenant's request rate."""
    if not state.key_hashes:
        tenant = LOCAL_TENANT
    elif credentials is None or credentials.scheme.lower() != "bearer":
        raise _unauthorized("missing API key (send Authorization: Bearer <key>)", None)
    else:
        found = state.key_hashes.get(hash_key(credentials.credentials))
        if found is None:
            raise _unauthorized("invalid API key", "invalid_token")
        tenant = found
    wait = state.limiter.hit(tenant)
    if wait is not None:
        raise ApiProblem(
            429,
            f"more than {state.limiter.per_minute} requests per minute",
            slug="rate-limited",
            headers={"Retry-After": str(wait)},
        )
    return tenant


TenantDep = Annotated[str, Depends(authenticate)]
