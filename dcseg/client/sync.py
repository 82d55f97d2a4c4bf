"""The blocking client of the dcseg REST API (httpx), with retries and resumable downloads.

Example:
    >>> with Client("http://127.0.0.1:8000", api_key="key") as client:  # doctest: +SKIP
    ...     upload = client.upload(Path("scene.tar"))
    ...     job = client.submit(upload["id"], preset="fast")
    ...     client.follow(job["id"], timeout=3600)
    ...     client.download(job["id"], Path("out"))
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any

from dcseg.client.downloads import fetch_presigned, resume
from dcseg.client.errors import ApiError, checked
from dcseg.client.events import Cursor, ServerEvent, parse_events
from dcseg.client.files import (
    file_chunks,
    pack_folder,
    ready_target,
    sha256_of,
    verified,
)
from dcseg.client.retry import RetryPolicy, replayable
from dcseg.client.selection import choose, select
from dcseg.client.shared import (
    TERMINAL,
    EventHandler,
    Tries,
    auth_headers,
    export_url,
    finished,
    job_body,
    key_headers,
    offers_stream,
    poll_delay,
    stream_headers,
    stream_step,
    upload_headers,
)

if TYPE_CHECKING:  # imported where used: the CLI's argument parser imports this module
    import httpx

__all__ = ["Client", "TERMINAL"]


class Client:
    """Talks to one dcseg service with one API key (None when the service has no keys).

    Args:
        timeout: seconds for connecting and between received bytes (not for a whole
            download or an upload's processing).
        retry: when requests are tried again (:class:`RetryPolicy`): GET, HEAD, PUT and
            DELETE, and POSTs with an ``Idempotency-Key``, on connection errors and resets,
            502/503/504 and 429 (honouring ``Retry-After``); any request whose connection
            could not be opened (nothing was sent).
        sleep: how the client waits between tries (tests pass a recorder).
    """

    def __init__(
        self,
        base_url: str,
        api_key: str | None = None,
        *,
        timeout: float = 60.0,
        retry: RetryPolicy | None = None,
        transport: httpx.BaseTransport | None = None,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        import httpx

        headers = auth_headers(api_key)
        self.retry = retry or RetryPolicy()
        self._sleep = sleep
        self._http = httpx.Client(
            base_url=base_url, headers=headers, timeout=timeout, transport=transport
        )

    def __enter__(self) -> Client:
        return self

    def __exit__(
        self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def close(self) -> None:
        self._http.close()

    # -- requests -------------------------------------------------------------------------

    def _request(
        self,
        method: str,
        url: str,
        *,
        body: Callable[[], Any] | None = None,
        headers: dict[str, str] | None = None,
        **kwargs: Any,
    ) -> httpx.Response:
        """One request under the retry policy; the last response (any status) or
        NetworkError. ``body`` makes the request's content afresh for every try."""
        import httpx

        retried = replayable(method, headers)
        tries = Tries(self.retry, method, self._http.base_url.join(url))
        while True:
            try:
                content = body() if body is not None else None
                response = self._http.request(
                    method, url, content=content, headers=headers, **kwargs
                )
            except httpx.TransportError as error:
                self._sleep(tries.dropped(error, retried))
                continue
            wait = tries.answered(response, retried)
            if wait is None:
                return response
            self._sleep(wait)

    def _json(self, response: httpx.Response) -> dict[str, Any]:
        return checked(response)

    def _get(self, url: str, **kwargs: Any) -> dict[str, Any]:
        return self._json(self._request("GET", url, **kwargs))

    # -- uploads and jobs -----------------------------------------------------------------

    def upload(self, path: Path, *, idempotency_key: str | None = None) -> dict[str, Any]:
        """Upload a capture: an archive (.zip, .tar, .tar.gz) or a folder (packed into a tar
        in a temporary file first); returns the upload resource. With ``idempotency_key`` a
        failed try is sent again (the service answers a repeat with the first upload)."""
        if path.is_dir():
            import tempfile

            with tempfile.TemporaryDirectory(prefix="dcseg-upload-") as tmp:
                archive = pack_folder(path, Path(tmp) / f"{path.name or 'capture'}.tar")
                return self.upload(archive, idempotency_key=idempotency_key)
        expected = "a folder or a .zip, .tar or .tar.gz archive"
        headers = upload_headers(path, idempotency_key, expected)
        response = self._request(
            "POST",
            "/v1/uploads",
            params={"sha256": sha256_of(path)},
            body=lambda: file_chunks(path),
            headers=headers,
            timeout=None,
        )
        return self._json(response)

    def submit(
        self,
        upload_id: str | None = None,
        *,
        preset: str = "fast",
        options: dict[str, Any] | None = None,
        parent_job_id: str | None = None,
        idempotency_key: str | None = None,
    ) -> dict[str, Any]:
        """Create a job; returns its representation (status ``queued``). With
        ``idempotency_key`` a failed try is sent again without creating a second job."""
        body = job_body(upload_id, preset, options, parent_job_id)
        headers = key_headers(idempotency_key)
        return self._json(self._request("POST", "/v1/jobs", json=body, headers=headers))

    def status(self, job_id: str) -> dict[str, Any]:
        return self._get(f"/v1/jobs/{job_id}")

    def cancel(self, job_id: str) -> dict[str, Any]:
        return self._json(self._request("POST", f"/v1/jobs/{job_id}:cancel"))

    def wait(
        self,
        job_id: str,
        timeout: float = 3600.0,
        poll: float | None = None,
        on_event: EventHandler | None = None,
    ) -> dict[str, Any]:
        """Poll until the job ends (honouring ``Retry-After``); raise JobFailed unless it
        succeeded, TimeoutError after ``timeout`` seconds. ``on_event`` receives each
        poll's progress as a ``progress`` event, and the end as a ``completed`` one."""
        deadline = time.monotonic() + timeout
        while True:
            response = self._request("GET", f"/v1/jobs/{job_id}")
            job = self._json(response)
            if on_event is not None and job.get("progress"):
                on_event(ServerEvent("progress", job["progress"]))
            if job["status"] in TERMINAL:
                if on_event is not None:
                    on_event(ServerEvent("completed", {"status": job["status"]}))
                return finished(job)
            delay = poll_delay(response, poll)
            if time.monotonic() + delay > deadline:
                raise TimeoutError(f"job {job_id} still {job['status']} after {timeout} s")
            self._sleep(delay)

    def follow(
        self, job_id: str, on_event: EventHandler | None = None, timeout: float = 3600.0
    ) -> dict[str, Any]:
        """Follow the job's event stream until it ends; returns the job when it succeeded,
        raises JobFailed when it failed or was canceled, TimeoutError after ``timeout`` s.

        A dropped stream is reopened with ``Last-Event-ID`` (nothing is missed or repeated),
        under the retry policy (its count starts again once events arrive); when the stream
        cannot be had (refused, or the policy gives up) the job is polled (:meth:`wait`).
        """
        import httpx

        deadline = time.monotonic() + timeout
        cursor = Cursor()
        tries = Tries(self.retry)
        while True:
            seen = cursor.last
            try:
                done = self._read_stream(job_id, cursor, on_event, deadline)
            except httpx.TransportError:
                if cursor.last != seen:
                    tries.restart()
                wait = tries.failed()
                if wait is None:
                    break
                self._sleep(wait)
                continue
            if done is None:
                break  # no stream: poll
            if done:
                return finished(self.status(job_id))
            if time.monotonic() >= deadline:
                raise TimeoutError(f"job {job_id} still running after {timeout} s")
            tries.restart()
            self._sleep(cursor.pause)
        remaining = max(0.0, deadline - time.monotonic())
        return self.wait(job_id, timeout=remaining, on_event=on_event)

    def _read_stream(
        self, job_id: str, cursor: Cursor, on_event: EventHandler | None, deadline: float
    ) -> bool | None:
        """Read one connection of the event stream from ``cursor.last`` on: True when the
        ``completed`` event came, False when the stream ended before, None when the service
        offers no stream."""
        headers = stream_headers(cursor)
        with self._http.stream("GET", f"/v1/jobs/{job_id}/events", headers=headers) as response:
            if not offers_stream(response):
                response.read()
                return None
            for event in parse_events(response.iter_lines()):
                done = stream_step(event, cursor, on_event, deadline)
                if done is not None:
                    return done
        return False

    # -- artifacts and exports ------------------------------------------------------------

    def artifacts(self, job_id: str) -> list[dict[str, Any]]:
        items: list[dict[str, Any]] = self._get(f"/v1/jobs/{job_id}/artifacts")["artifacts"]
        return items

    def choose(
        self, job_id: str, *, only: Sequence[str] | None = None, everything: bool = False
    ) -> list[dict[str, Any]]:
        """The listed artifacts a download fetches (see :meth:`download`)."""
        return choose(self.artifacts(job_id), only, everything)

    def download(
        self,
        job_id: str,
        dest: Path,
        *,
        only: Sequence[str] | None = None,
        everything: bool = False,
    ) -> list[Path]:
        """Download the job's deliverables into ``dest`` (sub-folders per stage), checking
        SHA-256: the segment stage's results without its ``state/`` (every file of a job that
        did not segment; :data:`dcseg.client.selection.DELIVERABLES`).

        Args:
            only: glob patterns on the listed paths instead (``instances.json`` matches
                ``segment/instances.json``, ``masks`` every file under ``segment/masks/``);
                ValueError naming the patterns that match nothing, before anything is
                downloaded.
            everything: every file of every stage (``state/`` caches included).
        """
        return self.fetch(self.choose(job_id, only=only, everything=everything), dest)

    def instances(
        self,
        job_id: str,
        *,
        label: str | Sequence[str] | None = None,
        min_score: float | None = None,
        page_size: int = 100,
    ) -> list[dict[str, Any]]:
        """Every object of a succeeded job (following the pages), optionally of the classes
        ``label`` and scored at least ``min_score``."""
        params: dict[str, Any] = {"page_size": page_size}
        if label is not None:
            params["label"] = [label] if isinstance(label, str) else list(label)
        if min_score is not None:
            params["min_score"] = min_score
        found: list[dict[str, Any]] = []
        while True:
            body = self._get(f"/v1/jobs/{job_id}/instances", params=params)
            found += body["instances"]
            if not body.get("next_page_token"):
                return found
            params["page_token"] = body["next_page_token"]

    def instance(self, job_id: str, k: int) -> dict[str, Any]:
        """One object: class, score, size, box, visibility and export links per format."""
        return self._get(f"/v1/jobs/{job_id}/instances/{k}")

    def export(
        self,
        job_id: str,
        fmt: str,
        *,
        instance: int | None = None,
        timeout: float = 3600.0,
        poll: float | None = None,
    ) -> dict[str, Any]:
        """The export of the scene (or of object ``instance``) in ``fmt``, waiting while the
        service makes it (202, honouring ``Retry-After``); TimeoutError after ``timeout`` s."""
        url = export_url(job_id, fmt, instance)
        deadline = time.monotonic() + timeout
        while True:
            response = self._request("GET", url)
            body = self._json(response)
            if response.status_code != 202:
                return body
            delay = poll_delay(response, poll)
            if time.monotonic() + delay > deadline:
                raise TimeoutError(f"the {fmt} export of job {job_id} not ready after {timeout} s")
            self._sleep(delay)

    def download_export(
        self,
        job_id: str,
        fmt: str,
        dest: Path,
        *,
        instance: int | None = None,
        only: Sequence[str] | None = None,
        timeout: float = 3600.0,
    ) -> list[Path]:
        """Download an export's files (see :meth:`export`) into ``dest``, checking SHA-256."""
        files = self.export(job_id, fmt, instance=instance, timeout=timeout)["files"]
        return self.fetch(select(files, only), dest)

    def fetch(self, items: Sequence[dict[str, Any]], dest: Path) -> list[Path]:
        """Download listed files (``{name, url, sha256[, size, download_url]}``) into ``dest``."""
        return [self.fetch_one(item, dest) for item in items]

    def fetch_one(self, item: dict[str, Any], dest: Path) -> Path:
        """One listed file to ``dest/<name>``: kept when already there with its SHA-256,
        else through ``<name>.part``, resumed from its size (``Range``) after a dropped
        connection or an interrupted earlier run, checked, then renamed."""
        target, partial = ready_target(item, dest)
        if target.is_file() and verified(target, item):
            return target
        if not fetch_presigned(item, partial, self._http.timeout):
            resumed = partial.is_file() and partial.stat().st_size > 0
            resume(self, item, partial)
            if not verified(partial, item) and resumed:  # the old part was not of this file
                partial.unlink()
                resume(self, item, partial)
            if not verified(partial, item):
                partial.unlink()
                raise ApiError(502, {"detail": f"{item['name']}: SHA-256 mismatch"})
        partial.replace(target)
        return target
