"""A small Python client of the dcseg REST API (httpx).

Example:
    >>> with Client("http://127.0.0.1:8000", api_key="key") as client:  # doctest: +SKIP
    ...     upload = client.upload(Path("scene.tar"))
    ...     job = client.submit(upload["id"], preset="fast")
    ...     client.wait(job["id"], timeout=3600)
    ...     client.download(job["id"], Path("out"))
"""

from __future__ import annotations

import hashlib
import time
from collections.abc import Iterator
from pathlib import Path, PurePosixPath
from types import TracebackType
from typing import Any

import httpx

__all__ = ["ApiError", "Client", "JobFailed", "TERMINAL"]

TERMINAL = frozenset({"succeeded", "failed", "canceled"})
"""Job statuses that never change again."""

_ARCHIVE_TYPES = {
    ".zip": "application/zip",
    ".tar": "application/x-tar",
    ".tgz": "application/gzip",
    ".gz": "application/gzip",
}


class ApiError(RuntimeError):
    """The API answered with a problem (RFC 9457); ``problem`` holds its body."""

    def __init__(self, status: int, problem: dict[str, Any]) -> None:
        self.status = status
        self.problem = problem
        detail = problem.get("detail") or problem.get("title") or "error"
        super().__init__(f"HTTP {status}: {detail}")


class JobFailed(RuntimeError):
    """A job ended ``failed`` or ``canceled``; ``job`` holds its last representation."""

    def __init__(self, job: dict[str, Any]) -> None:
        self.job = job
        super().__init__(f"job {job['id']} {job['status']}: {job.get('error')}")


def _file_chunks(path: Path, size: int = 1 << 20) -> Iterator[bytes]:
    with path.open("rb") as handle:
        while chunk := handle.read(size):
            yield chunk


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    for chunk in _file_chunks(path):
        digest.update(chunk)
    return digest.hexdigest()


class Client:
    """Talks to one dcseg service with one API key (None when the service has no keys)."""

    def __init__(
        self,
        base_url: str,
        api_key: str | None = None,
        *,
        timeout: float = 60.0,
        transport: httpx.BaseTransport | None = None,
    ) -> None:
        headers = {"Authorization": f"Bearer {api_key}"} if api_key else {}
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

    def _json(self, response: httpx.Response) -> dict[str, Any]:
        if response.status_code >= 400:
            try:
                problem = response.json()
            except ValueError:
                problem = {"detail": response.text}
            raise ApiError(response.status_code, problem)
        body: dict[str, Any] = response.json()
        return body

    def upload(self, path: Path) -> dict[str, Any]:
        """Upload a capture archive (.zip, .tar, .tar.gz); returns the upload resource."""
        content_type = _ARCHIVE_TYPES.get(path.suffix.lower())
        if content_type is None:
            raise ValueError(f"{path}: expected a .zip, .tar or .tar.gz archive")
        response = self._http.post(
            "/v1/uploads",
            params={"sha256": _sha256(path)},
            content=_file_chunks(path),
            headers={"Content-Type": content_type},
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
        """Create a job; returns its representation (status ``queued``)."""
        body: dict[str, Any] = {"preset": preset, "options": options or {}}
        if upload_id is not None:
            body["upload_id"] = upload_id
        if parent_job_id is not None:
            body["parent_job_id"] = parent_job_id
        headers = {"Idempotency-Key": idempotency_key} if idempotency_key else {}
        return self._json(self._http.post("/v1/jobs", json=body, headers=headers))

    def status(self, job_id: str) -> dict[str, Any]:
        return self._json(self._http.get(f"/v1/jobs/{job_id}"))

    def cancel(self, job_id: str) -> dict[str, Any]:
        return self._json(self._http.post(f"/v1/jobs/{job_id}:cancel"))

    def wait(
        self, job_id: str, timeout: float = 3600.0, poll: float | None = None
    ) -> dict[str, Any]:
        """Poll until the job ends (honouring ``Retry-After``); raise JobFailed unless it
        succeeded, TimeoutError after ``timeout`` seconds."""
        deadline = time.monotonic() + timeout
        while True:
            response = self._http.get(f"/v1/jobs/{job_id}")
            job = self._json(response)
            if job["status"] in TERMINAL:
                if job["status"] != "succeeded":
                    raise JobFailed(job)
                return job
            delay = poll if poll is not None else float(response.headers.get("Retry-After", 2))
            if time.monotonic() + delay > deadline:
                raise TimeoutError(f"job {job_id} still {job['status']} after {timeout} s")
            time.sleep(delay)

    def artifacts(self, job_id: str) -> list[dict[str, Any]]:
        items: list[dict[str, Any]] = self._json(self._http.get(f"/v1/jobs/{job_id}/artifacts"))[
            "artifacts"
        ]
        return items

    def _fetch(self, url: str, partial: Path) -> str:
        """Download ``url`` through the API into ``partial``; its SHA-256."""
        digest = hashlib.sha256()
        with self._http.stream("GET", url, timeout=None) as response:
            if response.status_code >= 400:
                response.read()
                self._json(response)
            with partial.open("wb") as out:
                for chunk in response.iter_bytes():
                    digest.update(chunk)
                    out.write(chunk)
        return digest.hexdigest()

    def _fetch_presigned(self, item: dict[str, Any], partial: Path) -> str | None:
        """Download the artifact's presigned ``download_url`` straight from the object store
        (no API key is sent there); None when it has none or it fails (expired, unreachable,
        corrupted): the caller then downloads through the API."""
        url = item.get("download_url")
        if not url:
            return None
        digest = hashlib.sha256()
        try:
            with (
                httpx.stream("GET", url, timeout=self._http.timeout) as response,
                partial.open("wb") as out,
            ):
                if response.status_code != 200:
                    return None
                for chunk in response.iter_bytes():
                    digest.update(chunk)
                    out.write(chunk)
        except httpx.HTTPError:
            return None
        found = digest.hexdigest()
        return found if found == item["sha256"] else None

    def download(self, job_id: str, dest: Path) -> list[Path]:
        """Download every artifact into ``dest`` (sub-folders per stage), checking SHA-256:
        from its presigned ``download_url`` when the server offers one, else (or when that
        fails) through the API."""
        written: list[Path] = []
        for item in self.artifacts(job_id):
            relative = PurePosixPath(item["name"])
            if relative.is_absolute() or ".." in relative.parts:
                raise ApiError(500, {"detail": f"unsafe artifact name {item['name']!r}"})
            target = dest.joinpath(*relative.parts)
            target.parent.mkdir(parents=True, exist_ok=True)
            partial = target.with_name(target.name + ".part")
            digest = self._fetch_presigned(item, partial) or self._fetch(item["url"], partial)
            if digest != item["sha256"]:
                partial.unlink()
                raise ApiError(500, {"detail": f"{item['name']}: SHA-256 mismatch"})
            partial.replace(target)
            written.append(target)
        return written


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
