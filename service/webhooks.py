"""Webhooks: the callback URL check, the signature, and the dispatcher that sends the outbox.

The transaction that ends a job with a ``callback_url`` writes its delivery row
(:mod:`jobstore.store.webhooks`), whichever process ends it (a worker, a cancel, a sweep). The
dispatcher runs in the API process (its lifespan): it claims due rows under a lease, POSTs the
job's public JSON signed with ``DCSEG_WEBHOOK_SECRET``, records each attempt and retries with
exponential backoff. Workers only run jobs.
"""

from __future__ import annotations

import asyncio
import hashlib
import hmac
import ipaddress
import json
import logging
import os
import socket
import time
from datetime import timedelta
from urllib.parse import urlsplit

import httpx

from jobstore.settings import Settings
from jobstore.store import AttemptOutcome, DeliveryClaim, Store, new_id
from service.background import in_thread
from service.jobs import job_public

logger = logging.getLogger(__name__)

SIGNATURE_HEADER = "X-Dcseg-Signature"
TIMESTAMP_HEADER = "X-Dcseg-Timestamp"
BATCH = 10
"""Deliveries claimed at once."""


def sign(secret: str, timestamp: str, body: bytes) -> str:
    """``sha256=<hex HMAC-SHA256 of "<timestamp>.<body>">`` (the timestamp is signed too, so a
    receiver that rejects old timestamps cannot be sent a replayed body)."""
    message = timestamp.encode() + b"." + body
    return "sha256=" + hmac.new(secret.encode(), message, hashlib.sha256).hexdigest()


def _forbidden(address: str) -> bool:
    ip = ipaddress.ip_address(address.split("%", 1)[0])
    if isinstance(ip, ipaddress.IPv6Address) and ip.ipv4_mapped is not None:
        ip = ip.ipv4_mapped
    return (
        ip.is_private
        or ip.is_loopback
        or ip.is_link_local
        or ip.is_multicast
        or ip.is_reserved
        or ip.is_unspecified
    )


def url_refusal(url: str, allow_private: bool) -> str | None:
    """Why ``url`` may not be called back (its host does not resolve, or resolves to a
    private, loopback, link-local, multicast or reserved address), or None when it may."""
    parts = urlsplit(url)
    host = parts.hostname or ""
    port = parts.port or (443 if parts.scheme == "https" else 80)
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except (OSError, UnicodeError) as error:
        return f"the host {host!r} does not resolve ({error})"
    if allow_private:
        return None
    bad = sorted({str(info[4][0]) for info in infos if _forbidden(str(info[4][0]))})
    if bad:
        return (
            f"the host {host!r} resolves to a private, loopback, link-local, multicast or "
            f"reserved address ({', '.join(bad)}); the server refuses those "
            "(DCSEG_WEBHOOK_ALLOW_PRIVATE)"
        )
    return None


def backoff(settings: Settings, attempt: int) -> timedelta:
    """Wait after failed attempt number ``attempt``: doubling from ``webhook_backoff_s``."""
    delay = settings.webhook_backoff_s * 2 ** min(attempt - 1, 30)
    return timedelta(seconds=min(delay, settings.webhook_backoff_max_s))


class Dispatcher:
    """Sends the outbox: claim due deliveries, POST each, record the attempt; forever."""

    def __init__(
        self, store: Store, settings: Settings, transport: httpx.AsyncBaseTransport | None = None
    ) -> None:
        self.store = store
        self.settings = settings
        self.owner = f"{socket.gethostname()}:{os.getpid()}:{new_id()[:8]}"
        self.client = httpx.AsyncClient(
            timeout=settings.webhook_timeout_s, follow_redirects=False, transport=transport
        )

    async def run(self) -> None:
        """Forever: send what is due, else wait ``webhook_poll_s``."""
        try:
            while True:
                try:
                    sent = await self.run_once()
                except Exception:
                    logger.exception("webhook dispatch failed; retrying")
                    sent = 0
                if not sent:
                    await asyncio.sleep(self.settings.webhook_poll_s)
        finally:
            await self.client.aclose()

    async def run_once(self) -> int:
        """Claim the due deliveries and send them; returns how many were attempted."""
        if not await in_thread(self.store.webhooks_due):
            return 0
        lease = timedelta(seconds=self.settings.webhook_lease_s)
        claims = await in_thread(self.store.claim_webhook_deliveries, self.owner, lease, BATCH)
        for claim in claims:
            await self.deliver(claim)
        return len(claims)

    async def deliver(self, claim: DeliveryClaim) -> None:
        """POST the job to the claim's URL once and record the outcome."""
        outcome = await self._attempt(claim)
        state = await in_thread(
            self.store.record_webhook_attempt,
            claim,
            self.owner,
            outcome,
            max_attempts=self.settings.webhook_max_attempts,
            retry_in=backoff(self.settings, claim.attempt),
        )
        logger.info(
            "webhook %d of job %s, attempt %d: %s -> %s",
            claim.id,
            claim.job_id,
            claim.attempt,
            outcome.status_code or outcome.error,
            state,
        )

    async def _attempt(self, claim: DeliveryClaim) -> AttemptOutcome:
        job = await in_thread(self.store.get_job, claim.job_id)
        if job is None:
            return AttemptOutcome(None, "the job was deleted")
        refusal = await in_thread(url_refusal, claim.url, self.settings.webhook_allow_private)
        if refusal is not None:
            return AttemptOutcome(None, f"not sent: {refusal}")
        body = json.dumps(
            job_public(job).model_dump(mode="json"), ensure_ascii=False, separators=(",", ":")
        ).encode()
        timestamp = str(int(time.time()))
        secret = self.settings.webhook_secret.get_secret_value()
        headers = {
            "Content-Type": "application/json",
            "User-Agent": "dcseg-webhooks",
            SIGNATURE_HEADER: sign(secret, timestamp, body),
            TIMESTAMP_HEADER: timestamp,
            "X-Dcseg-Delivery": str(claim.id),
            "X-Dcseg-Attempt": str(claim.attempt),
        }
        try:
            response = await self.client.post(claim.url, content=body, headers=headers)
        except httpx.HTTPError as error:
            return AttemptOutcome(None, f"{type(error).__name__}: {error}"[:500])
        code = response.status_code
        return AttemptOutcome(code, None if 200 <= code < 300 else f"HTTP {code}")
