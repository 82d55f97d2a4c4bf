"""Request dependencies: the app's state, the caller's tenant (bearer keys) and rate limits."""

from __future__ import annotations

import ipaddress
import logging
import math
import threading
import time
from dataclasses import dataclass, field
from typing import Annotated, Protocol

import redis
from fastapi import Depends, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from jobstore.blobstore import Storage, make_storage
from jobstore.settings import Settings
from jobstore.store import Store, hash_key
from service.problems import ApiProblem
from service.queue import JobQueue

logger = logging.getLogger(__name__)

LOCAL_TENANT = "local"
"""The tenant of every request when no API keys are configured."""

WINDOW_S = 60
"""Length of one rate-limit window (the limits are per minute)."""

REDIS_RETRY_S = 5.0
"""After a Redis error the shared limiter uses the in-process one for this long."""


class Limiter(Protocol):
    """Counts requests per name in one-minute windows."""

    per_minute: int

    def hit(self, name: str, now: float | None = None) -> int | None:
        """Count one request; returns the seconds to wait when over the limit, else None."""
        ...

    def over(self, name: str, now: float | None = None) -> int | None:
        """The seconds to wait when ``name`` is already over the limit (counts nothing)."""
        ...


def _wait(now: float) -> int:
    """Seconds until the window containing ``now`` ends (at least 1)."""
    return max(1, math.ceil((int(now // WINDOW_S) + 1) * WINDOW_S - now))


class RateLimiter:
    """Fixed one-minute windows per name, in this process's memory.

    With several API replicas each enforces the limit on its own share of the traffic.
    """

    def __init__(self, per_minute: int) -> None:
        self.per_minute = per_minute
        self._windows: dict[str, tuple[int, int]] = {}
        self._lock = threading.Lock()

    def _count(self, name: str, window: int) -> int:
        start, count = self._windows.get(name, (window, 0))
        return count if start == window else 0

    def hit(self, name: str, now: float | None = None) -> int | None:
        now = time.time() if now is None else now
        window = int(now // WINDOW_S)
        with self._lock:
            count = self._count(name, window)
            if count >= self.per_minute:
                return _wait(now)
            self._windows[name] = (window, count + 1)
        return None

    def over(self, name: str, now: float | None = None) -> int | None:
        now = time.time() if now is None else now
        with self._lock:
            count = self._count(name, int(now // WINDOW_S))
        return _wait(now) if count >= self.per_minute else None


class RedisRateLimiter:
    """Fixed one-minute windows per name in Redis (``INCR`` + ``EXPIRE``), shared by every API
    replica. When Redis fails it falls back to an in-process :class:`RateLimiter` (fail open to
    per-process limits, with a logged warning) and tries Redis again after ``REDIS_RETRY_S``."""

    def __init__(self, client: redis.Redis, prefix: str, per_minute: int) -> None:
        self.per_minute = per_minute
        self._redis = client
        self._prefix = prefix
        self._fallback = RateLimiter(per_minute)
        self._retry_at = 0.0

    def _key(self, name: str, now: float) -> str:
        return f"{self._prefix}{name}:{int(now // WINDOW_S)}"

    def _redis_down(self, error: redis.RedisError) -> None:
        if time.monotonic() >= self._retry_at:
            logger.warning(
                "rate limiter: Redis unreachable (%s); using per-process limits for %.0f s",
                error,
                REDIS_RETRY_S,
            )
        self._retry_at = time.monotonic() + REDIS_RETRY_S

    def _use_redis(self) -> bool:
        return time.monotonic() >= self._retry_at

    def hit(self, name: str, now: float | None = None) -> int | None:
        now = time.time() if now is None else now
        if self._use_redis():
            key = self._key(name, now)
            try:
                with self._redis.pipeline() as pipe:
                    pipe.incr(key)
                    pipe.expire(key, 2 * WINDOW_S)
                    count, _ = pipe.execute()
                return _wait(now) if int(count) > self.per_minute else None
            except redis.RedisError as error:
                self._redis_down(error)
        return self._fallback.hit(name, now)

    def over(self, name: str, now: float | None = None) -> int | None:
        now = time.time() if now is None else now
        if self._use_redis():
            try:
                count = self._redis.get(self._key(name, now))
                return _wait(now) if int(count or 0) >= self.per_minute else None
            except redis.RedisError as error:
                self._redis_down(error)
        return self._fallback.over(name, now)


def make_limiter(settings: Settings, scope: str, per_minute: int) -> Limiter:
    """The shared Redis limiter when :attr:`Settings.effective_rate_limit_url` is set, else the
    in-process one; ``scope`` separates the Redis keys of different limits."""
    url = settings.effective_rate_limit_url
    if url is None:
        return RateLimiter(per_minute)
    client = redis.Redis.from_url(url, socket_timeout=0.5, socket_connect_timeout=0.5)
    return RedisRateLimiter(client, f"{settings.rate_limit_key_prefix}{scope}:", per_minute)


class StreamSlots:
    """Open event streams per tenant in this process."""

    def __init__(self) -> None:
        self._open: dict[str, int] = {}
        self._lock = threading.Lock()

    def acquire(self, tenant: str, cap: int) -> bool:
        """Take a slot; False when ``tenant`` already has ``cap`` streams open."""
        with self._lock:
            if self._open.get(tenant, 0) >= cap:
                return False
            self._open[tenant] = self._open.get(tenant, 0) + 1
            return True

    def release(self, tenant: str) -> None:
        with self._lock:
            self._open[tenant] = max(0, self._open.get(tenant, 0) - 1)

    def open(self, tenant: str) -> int:
        """How many streams ``tenant`` has open."""
        with self._lock:
            return self._open.get(tenant, 0)


@dataclass
class AppState:
    """Everything the routes need, built once per app in its lifespan."""

    settings: Settings
    store: Store
    queue: JobQueue
    key_hashes: dict[str, str] = field(default_factory=dict)
    limiter: Limiter = field(default_factory=lambda: RateLimiter(600))
    """Requests per tenant."""
    auth_limiter: Limiter = field(default_factory=lambda: RateLimiter(30))
    """Failed authentications per client address."""
    streams: StreamSlots = field(default_factory=StreamSlots)
    storage: Storage = field(default=None)  # type: ignore[assignment]
    """Uploads, stage outputs and artifacts (default: from the settings)."""

    def __post_init__(self) -> None:
        if self.storage is None:
            self.storage = make_storage(self.settings)


def get_state(request: Request) -> AppState:
    state: AppState = request.app.state.dcseg
    return state


StateDep = Annotated[AppState, Depends(get_state)]

_bearer = HTTPBearer(auto_error=False, description="API key: `Authorization: Bearer <key>`")


def is_loopback_name(host: str) -> bool:
    """``localhost`` or a loopback IP (an IPv4-mapped IPv6 address counts as its IPv4)."""
    if host.lower() == "localhost":
        return True
    try:
        address = ipaddress.ip_address(host)
    except ValueError:
        return False
    if isinstance(address, ipaddress.IPv6Address) and address.ipv4_mapped is not None:
        return address.ipv4_mapped.is_loopback
    return address.is_loopback


def is_loopback_authority(authority: str) -> bool:
    """Whether a ``Host`` header (``name[:port]``, ``[v6][:port]``) names a loopback host."""
    host = authority.strip()
    if host.startswith("["):
        end = host.find("]")
        if end < 0:
            return False
        host, rest = host[1:end], host[end + 1 :]
        if rest and not (rest.startswith(":") and rest[1:].isdigit()):
            return False
        return ":" in host and is_loopback_name(host)
    host, sep, port = host.partition(":")
    if sep and not port.isdigit():
        return False
    return is_loopback_name(host)


def guard_open_mode(request: Request) -> None:
    """With no API keys (and auth not explicitly off): 403 for a non-loopback client, 421 for a
    ``Host`` that is not a loopback name (a DNS-rebinding page in the user's browser)."""
    client = request.client.host if request.client else ""
    if not is_loopback_name(client):
        raise ApiProblem(
            403,
            f"no API keys are configured, so only loopback clients are served (not {client!r});"
            " set DCSEG_API_KEYS, or DCSEG_ALLOW_UNAUTHENTICATED=true to serve everyone",
            slug="loopback-only",
        )
    host = request.headers.get("host", "")
    if not is_loopback_authority(host):
        raise ApiProblem(
            421,
            f"the Host header {host!r} is not a loopback name; without API keys this server only"
            " answers to localhost, 127.0.0.1 or [::1]",
            slug="host-not-loopback",
        )


def _unauthorized(detail: str, error: str | None) -> ApiProblem:
    challenge = 'Bearer realm="dcseg"' + (f', error="{error}"' if error else "")
    return ApiProblem(401, detail, slug="unauthorized", headers={"WWW-Authenticate": challenge})


def _auth_limited(state: AppState, wait: int) -> ApiProblem:
    return ApiProblem(
        429,
        f"more than {state.auth_limiter.per_minute} failed authentications per minute from this"
        " address (DCSEG_FAILED_AUTH_PER_MINUTE); wait for Retry-After",
        slug="rate-limited",
        headers={"Retry-After": str(wait)},
    )


def _tenant_of_key(
    state: AppState, client: str, credentials: HTTPAuthorizationCredentials | None
) -> str:
    """The tenant of the bearer key; 401 (or 429 past the failed-auth limit) otherwise."""
    name = f"address:{client}"
    wait = state.auth_limiter.over(name)
    if wait is not None:
        raise _auth_limited(state, wait)
    if credentials is None or credentials.scheme.lower() != "bearer":
        problem = _unauthorized("missing API key (send Authorization: Bearer <key>)", None)
    else:
        found = state.key_hashes.get(hash_key(credentials.credentials))
        if found is not None:
            return found
        problem = _unauthorized("invalid API key", "invalid_token")
    wait = state.auth_limiter.hit(name)
    raise problem if wait is None else _auth_limited(state, wait)


def authenticate(
    request: Request,
    state: StateDep,
    credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)],
) -> str:
    """The caller's tenant; 401 without a valid key, 429 over the tenant's request rate or the
    address's failed authentications; 403/421 off loopback when no keys are configured."""
    if state.key_hashes:
        client = request.client.host if request.client else "unknown"
        tenant = _tenant_of_key(state, client, credentials)
    else:
        if not state.settings.allow_unauthenticated:
            guard_open_mode(request)
        tenant = LOCAL_TENANT
    wait = state.limiter.hit(f"tenant:{tenant}")
    if wait is not None:
        raise ApiProblem(
            429,
            f"more than {state.limiter.per_minute} requests per minute",
            slug="rate-limited",
            headers={"Retry-After": str(wait)},
        )
    return tenant


TenantDep = Annotated[str, Depends(authenticate)]
