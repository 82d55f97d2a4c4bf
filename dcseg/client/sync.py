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
from collections.abc import Iterator, Sequence
from pathlib import Path, PurePosixPath
from types import TracebackType
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # imported where used: the CLI's argument parser imports this module
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
        import httpx

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

    def download(self, job_id: str, dest: Path, *, only: Sequence[str] | None = None) -> list[Path]:
        """Download the job's artifacts into ``dest`` (sub-folders per stage), checking SHA-256.

        Args:
            only: artifact names to fetch; an entry matches a name ending in it on a ``/``
                boundary (``instances.json`` is ``segment/instances.json``). ValueError
                naming the entries that match nothing, before anything is downloaded.
        """
        return self._fetch_all(select(self.artifacts(job_id), only), dest)

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
            body = self._json(self._http.get(f"/v1/jobs/{job_id}/instances", params=params))
            found += body["instances"]
            if not body.get("next_page_token"):
                return found
            params["page_token"] = body["next_page_token"]

    def instance(self, job_id: str, k: int) -> dict[str, Any]:
        """One object: class, score, size, box, visibility and export links per format."""
        return self._json(self._http.get(f"/v1/jobs/{job_id}/instances/{k}"))

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
        base = f"/v1/jobs/{job_id}"
        url = (
            f"{base}/exports/{fmt}"
            if instance is None
            else f"{base}/instances/{instance}/exports/{fmt}"
        )
        deadline = time.monotonic() + timeout
        while True:
            response = self._http.get(url)
            body = self._json(response)
            if response.status_code != 202:
                return body
            delay = poll if poll is not None else float(response.headers.get("Retry-After", 2))
            if time.monotonic() + delay > deadline:
                raise TimeoutError(f"the {fmt} export of job {job_id} not ready after {timeout} s")
            time.sleep(delay)

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
        return self._fetch_all(select(files, only), dest)

    def _fetch_all(self, items: Sequence[dict[str, Any]], dest: Path) -> list[Path]:
        return [self._fetch(item, dest) for item in items]

    def _fetch(self, item: dict[str, Any], dest: Path) -> Path:
        """Stream one listed file (``{name, url, sha256}``) to ``dest/<name>`` via a ``.part``."""
        relative = PurePosixPath(item["name"])
        if relative.is_absolute() or ".." in relative.parts:
            raise ApiError(500, {"detail": f"unsafe file name {item['name']!r}"})
        target = dest.joinpath(*relative.parts)
        target.parent.mkdir(parents=True, exist_ok=True)
        partial = target.with_name(target.name + ".part")
        digest = self._fetch_presigned(item, partial) or self._stream(item["url"], partial)
        if digest != item["sha256"]:
            partial.unlink()
            raise ApiError(500, {"detail": f"{item['name']}: SHA-256 mismatch"})
        partial.replace(target)
        return target

    def _stream(self, url: str, partial: Path) -> str:
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
        import httpx

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


def matches(name: str, entry: str) -> bool:
    """Whether ``entry`` names ``name``: equal, or its trailing ``/``-separated part."""
    entry = entry.strip("/")
    return name == entry or name.endswith("/" + entry)


def select(items: Sequence[dict[str, Any]], only: Sequence[str] | None) -> list[dict[str, Any]]:
    """The listed files ``only`` names (all when None); ValueError naming unmatched entries."""
    if only is None:
        return list(items)
    missing = [e for e in only if not any(matches(i["name"], e) for i in items)]
    if missing:
        names = ", ".join(i["name"] for i in items) or "none"
        raise ValueError(f"no file named {', '.join(map(repr, missing))} (there are: {names})")
    return [i for i in items if any(matches(i["name"], e) for e in only)]


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
