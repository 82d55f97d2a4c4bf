"""The asyncio client (httpx.AsyncClient): the calls of :class:`dcseg.client.Client` that a
service or notebook awaits (upload, submit, status, wait, follow, artifacts, download), under
the same :class:`RetryPolicy`, with the same resumable downloads and errors.

Example:
    >>> async with AsyncClient("http://127.0.0.1:8000", api_key="key") as client:  # doctest: +SKIP
    ...     job = await client.submit((await client.upload(Path("scan.tar")))["id"])
    ...     await client.follow(job["id"])
    ...     await client.download(job["id"], Path("out"))
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import AsyncIterator, Awaitable, Callable, Sequence
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any

from dcseg.client.downloads import range_start
from dcseg.client.errors import ApiError, checked
from dcseg.client.events import Cursor, EventParser
from dcseg.client.files import ready_target, sha256_of, verified
from dcseg.client.retry import RetryPolicy, replayable
from dcseg.client.selection import choose
from dcseg.client.shared import (
    TERMINAL,
    EventHandler,
    Tries,
    auth_headers,
    finished,
    job_body,
    key_headers,
    offers_stream,
    poll_delay,
    range_request,
    stream_headers,
    stream_step,
    upload_headers,
)

if TYPE_CHECKING:
    import httpx

__all__ = ["AsyncClient"]


async def _chunks(path: Path, size: int = 1 << 20) -> AsyncIterator[bytes]:
    """``path``'s bytes, each read in a thread (the event loop never waits on the disk)."""
    with path.open("rb") as handle:
        while chunk := await asyncio.to_thread(handle.read, size):
            yield chunk


class AsyncClient:
    """Talks to one dcseg service with one API key; the arguments of
    :class:`dcseg.client.Client` (``sleep`` is awaited)."""

    def __init__(
        self,
        base_url: str,
        api_key: str | None = None,
        *,
        timeout: float = 60.0,
        retry: RetryPolicy | None = None,
        transport: httpx.AsyncBaseTransport | None = None,
        sleep: Callable[[float], Awaitable[None]] = asyncio.sleep,
    ) -> None:
        import httpx

        headers = auth_headers(api_key)
        self.retry = retry or RetryPolicy()
        self._sleep = sleep
        self._http = httpx.AsyncClient(
            base_url=base_url, headers=headers, timeout=timeout, transport=transport
        )

    async def __aenter__(self) -> AsyncClient:
        return self

    async def __aexit__(
        self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        await self.aclose()

    async def aclose(self) -> None:
        await self._http.aclose()

    async def _request(
        self,
        method: str,
        url: str,
        *,
        body: Callable[[], Any] | None = None,
        headers: dict[str, str] | None = None,
        **kwargs: Any,
    ) -> httpx.Response:
        """One request under the retry policy (as :meth:`Client._request`)."""
        import httpx

        retried = replayable(method, headers)
        tries = Tries(self.retry, method, self._http.base_url.join(url))
        while True:
            try:
                content = body() if body is not None else None
                response = await self._http.request(
                    method, url, content=content, headers=headers, **kwargs
                )
            except httpx.TransportError as error:
                await self._sleep(tries.dropped(error, retried))
                continue
            wait = tries.answered(response, retried)
            if wait is None:
                return response
            await self._sleep(wait)

    async def _get(self, url: str, **kwargs: Any) -> dict[str, Any]:
        return checked(await self._request("GET", url, **kwargs))

    async def upload(self, path: Path, *, idempotency_key: str | None = None) -> dict[str, Any]:
        """Upload a capture archive (.zip, .tar, .tar.gz); see :meth:`Client.upload`."""
        headers = upload_headers(path, idempotency_key, "a .zip, .tar or .tar.gz archive")
        digest = await asyncio.to_thread(sha256_of, path)
        response = await self._request(
            "POST",
            "/v1/uploads",
            params={"sha256": digest},
            body=lambda: _chunks(path),
            headers=headers,
            timeout=None,
        )
        return checked(response)

    async def submit(
        self,
        upload_id: str | None = None,
        *,
        preset: str = "fast",
        options: dict[str, Any] | None = None,
        parent_job_id: str | None = None,
        idempotency_key: str | None = None,
    ) -> dict[str, Any]:
        """Create a job; see :meth:`Client.submit`."""
        body = job_body(upload_id, preset, options, parent_job_id)
        headers = key_headers(idempotency_key)
        return checked(await self._request("POST", "/v1/jobs", json=body, headers=headers))

    async def status(self, job_id: str) -> dict[str, Any]:
        return await self._get(f"/v1/jobs/{job_id}")

    async def wait(
        self, job_id: str, timeout: float = 3600.0, poll: float | None = None
    ) -> dict[str, Any]:
        """Poll until the job ends; see :meth:`Client.wait`."""
        deadline = time.monotonic() + timeout
        while True:
            response = await self._request("GET", f"/v1/jobs/{job_id}")
            job = checked(response)
            if job["status"] in TERMINAL:
                return finished(job)
            delay = poll_delay(response, poll)
            if time.monotonic() + delay > deadline:
                raise TimeoutError(f"job {job_id} still {job['status']} after {timeout} s")
            await self._sleep(delay)

    async def follow(
        self, job_id: str, on_event: EventHandler | None = None, timeout: float = 3600.0
    ) -> dict[str, Any]:
        """Follow the job's event stream until it ends; see :meth:`Client.follow`."""
        import httpx

        deadline = time.monotonic() + timeout
        cursor = Cursor()
        tries = Tries(self.retry)
        while True:
            seen = cursor.last
            try:
                done = await self._read_stream(job_id, cursor, on_event, deadline)
            except httpx.TransportError:
                if cursor.last != seen:
                    tries.restart()
                wait = tries.failed()
                if wait is None:
                    break
                await self._sleep(wait)
                continue
            if done is None:
                break
            if done:
                return finished(await self.status(job_id))
            if time.monotonic() >= deadline:
                raise TimeoutError(f"job {job_id} still running after {timeout} s")
            tries.restart()
            await self._sleep(cursor.pause)
        return await self.wait(job_id, timeout=max(0.0, deadline - time.monotonic()))

    async def _read_stream(
        self, job_id: str, cursor: Cursor, on_event: EventHandler | None, deadline: float
    ) -> bool | None:
        headers = stream_headers(cursor)
        url = f"/v1/jobs/{job_id}/events"
        async with self._http.stream("GET", url, headers=headers) as response:
            if not offers_stream(response):
                await response.aread()
                return None
            parser = EventParser()
            async for line in response.aiter_lines():
                event = parser.feed(line)
                if event is None:
                    continue
                done = stream_step(event, cursor, on_event, deadline)
                if done is not None:
                    return done
        return False

    async def artifacts(self, job_id: str) -> list[dict[str, Any]]:
        items: list[dict[str, Any]] = (await self._get(f"/v1/jobs/{job_id}/artifacts"))["artifacts"]
        return items

    async def download(
        self,
        job_id: str,
        dest: Path,
        *,
        only: Sequence[str] | None = None,
        everything: bool = False,
    ) -> list[Path]:
        """The job's deliverables (or ``only``'s, or every file); see :meth:`Client.download`.
        Files come one after the other (the service's bandwidth, not the client's, bounds)."""
        items = choose(await self.artifacts(job_id), only, everything)
        return [await self.fetch_one(item, dest) for item in items]

    async def fetch_one(self, item: dict[str, Any], dest: Path) -> Path:
        """One listed file, resumable and checked; see :meth:`Client.fetch_one` (presigned
        URLs are not used: every file comes through the API)."""
        target, partial = ready_target(item, dest)
        if target.is_file() and await asyncio.to_thread(verified, target, item):
            return target
        resumed = partial.is_file() and partial.stat().st_size > 0
        await self._resume(item, partial)
        if resumed and not await asyncio.to_thread(verified, partial, item):
            partial.unlink()
            await self._resume(item, partial)
        if not await asyncio.to_thread(verified, partial, item):
            partial.unlink()
            raise ApiError(502, {"detail": f"{item['name']}: SHA-256 mismatch"})
        partial.replace(target)
        return target

    async def _resume(self, item: dict[str, Any], partial: Path) -> None:
        import httpx

        tries = Tries(self.retry, "GET", self._http.base_url.join(item["url"]))
        while True:
            try:
                refused = await self._try(item, partial)
            except httpx.TransportError as error:
                await self._sleep(tries.dropped(error))
                continue
            if refused is None:
                return
            await self._sleep(tries.refused(refused))

    async def _try(self, item: dict[str, Any], partial: Path) -> httpx.Response | None:
        """One try: None when the file was received to its end, the answer to retry else."""
        request = range_request(item, partial)
        if request is None:
            return None
        have, headers = request
        async with self._http.stream("GET", item["url"], headers=headers) as response:
            if response.status_code in self.retry.statuses:
                await response.aread()
                return response
            if response.status_code >= 400:
                await response.aread()
                checked(response)
            append = response.status_code == 206 and range_start(response) == have
            with partial.open("ab" if append else "wb") as out:
                async for chunk in response.aiter_bytes():
                    out.write(chunk)
        return None
