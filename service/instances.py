"""A finished job's segmented objects, read from its ``segment/instances.json`` artifact.

The artifact is immutable once the job succeeded, so nothing is cached: each request reads the
file the manifest names through the job's storage (:func:`service.artifacts.find_artifact` and
``Storage.read``, as downloads do), local or object storage alike.
"""

from __future__ import annotations

import base64
import hashlib
import json
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from jobstore.blobstore import Storage
from jobstore.models import Job
from service.artifacts import find_artifact
from service.problems import ApiProblem

INSTANCES = "segment/instances.json"
"""The artifact listing a job's objects (``dcseg.io.exports``)."""
LABELS = "segment/labels.json"
"""The artifact holding the vocabulary the labels come from."""


@dataclass(frozen=True)
class Filter:
    """Which instances a listing returns."""

    labels: tuple[str, ...] = ()
    """Class names; empty = every instance (unlabelled ones included)."""
    min_score: float | None = None

    def keeps(self, record: dict[str, Any]) -> bool:
        if self.labels and record.get("label") not in self.labels:
            return False
        return self.min_score is None or float(record.get("score", 0.0)) >= self.min_score

    def digest(self) -> str:
        raw = json.dumps([sorted(self.labels), self.min_score]).encode()
        return hashlib.sha256(raw).hexdigest()[:16]


@dataclass(frozen=True)
class JobFiles:
    """The stored files of one succeeded job of a tenant."""

    storage: Storage
    tenant: str
    job_id: str

    def read_json(self, name: str) -> dict[str, Any] | None:
        """The artifact ``name`` parsed, read like downloads (None when the job has none)."""
        found = find_artifact(self.storage, self.tenant, self.job_id, name)
        if found is None:
            return None
        data = b"".join(self.storage.read(self.tenant, found.item, 0, found.size - 1))
        body: dict[str, Any] = json.loads(data)
        return body


def finished_job(storage: Storage, tenant: str, job: Job | None, job_id: str) -> JobFiles:
    """The files of a succeeded job; 404 when it is unknown, 409 when it has not succeeded."""
    if job is None:
        raise ApiProblem(404, f"no job {job_id!r}", slug="not-found", job_id=job_id)
    if job.status != "succeeded":
        raise ApiProblem(
            409,
            f"job {job_id} is {job.status}; its instances exist once it has succeeded",
            slug="job-unfinished",
            job_id=job_id,
        )
    return JobFiles(storage, tenant, job_id)


def read_instances(files: JobFiles) -> dict[str, Any]:
    """The job's ``instances.json``; 404 when the segment stage was skipped (no masks)."""
    body = files.read_json(INSTANCES)
    if body is None:
        raise ApiProblem(
            404,
            f"job {files.job_id} has no instances (its segment stage was skipped: the upload"
            " held no masks)",
            slug="no-instances",
            job_id=files.job_id,
        )
    return body


def vocabulary(files: JobFiles, records: Sequence[dict[str, Any]]) -> set[str]:
    """The class names of the job (``labels.json``, else those its instances carry)."""
    body = files.read_json(LABELS)
    if body is None:
        return {str(r["label"]) for r in records if r.get("label") is not None}
    return {str(item["name"]) for item in body.get("labels", [])}


def check_labels(wanted: Sequence[str], known: set[str]) -> None:
    """422 naming ``query.label`` for a class the job's vocabulary does not hold."""
    unknown = [name for name in wanted if name not in known]
    if not unknown:
        return
    choices = ", ".join(sorted(known)) or "none"
    reason = f"is not a class of this job (classes: {choices})"
    items = [{"path": "query.label", "reason": f"{name!r} {reason}"} for name in unknown]
    raise ApiProblem(
        422,
        "; ".join(f"{i['path']}: {i['reason']}" for i in items),
        slug="validation-error",
        title="Request validation failed",
        errors=items,
    )


def find_instance(records: Sequence[dict[str, Any]], job_id: str, k: int) -> dict[str, Any]:
    found = next((r for r in records if int(r["id"]) == k), None)
    if found is None:
        raise ApiProblem(404, f"job {job_id} has no instance {k}", slug="not-found", job_id=job_id)
    return found


def page(
    records: Sequence[dict[str, Any]], keep: Filter, after: int | None, size: int
) -> tuple[list[dict[str, Any]], bool]:
    """Up to ``size`` kept records with an id above ``after`` (by id), and whether more follow."""
    kept = sorted((r for r in records if keep.keeps(r)), key=lambda r: int(r["id"]))
    if after is not None:
        kept = [r for r in kept if int(r["id"]) > after]
    return kept[:size], len(kept) > size


def encode_token(last_id: int, keep: Filter) -> str:
    raw = json.dumps({"a": last_id, "f": keep.digest()}).encode()
    return base64.urlsafe_b64encode(raw).decode().rstrip("=")


def decode_token(token: str, keep: Filter) -> int:
    """The last id of the previous page; 400 when the token is not one this API issued for
    the same filter."""
    try:
        data = json.loads(base64.urlsafe_b64decode((token + "=" * (-len(token) % 4)).encode()))
        after, digest = int(data["a"]), str(data["f"])
    except (ValueError, KeyError, TypeError):
        raise _bad_token("page_token is not a token this API issued") from None
    if digest != keep.digest():
        raise _bad_token("page_token was issued for other filters (label, min_score)")
    return after


def _bad_token(detail: str) -> ApiProblem:
    return ApiProblem(
        400,
        detail,
        slug="bad-page-token",
        errors=[{"path": "query.page_token", "reason": detail}],
    )


def extent(record: dict[str, Any]) -> list[float]:
    """The size of an instance's axis-aligned box, per world axis (metres)."""
    low, high = record.get("bbox_min", []), record.get("bbox_max", [])
    return [round(float(b) - float(a), 6) for a, b in zip(low, high, strict=True)]
