"""S3-compatible object storage (AWS S3, SeaweedFS, MinIO, Ceph RGW, R2) behind
:class:`jobstore.blobstore.Storage`.

Keys, under ``<DCSEG_S3_PREFIX>tenants/<tenant>/`` (the tenant URL-quoted)::

    uploads/<upload_id>/archive                       the validated archive as uploaded
    direct-uploads/<upload_id>.json                   a presigned multipart upload in progress
    jobs/<job_id>/attempts/<attempt>/<stage>/<path>   a stage's files, one folder per run
    jobs/<job_id>/stages/<index>-<stage>.json         the stage's manifest entry (committed last)

A stage is finished only when its manifest object exists; the manifest names the stage's
objects with their size and SHA-256. Objects are written under the run's own ``attempt``
folder, so a worker whose lease expired never overwrites a newer run's files, and the
manifest object is written with ``If-None-Match: *``: the first run to finish a stage wins.
"""

from __future__ import annotations

import hashlib
import json
import logging
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any
from urllib.parse import quote

from jobstore.blobstore import CHUNK, StoredFile, manifest_files

if TYPE_CHECKING:
    from jobstore.settings import Settings
    from jobstore.store import Store

logger = logging.getLogger(__name__)


class IntegrityError(ValueError):
    """A fetched object's size or SHA-256 differs from what its manifest recorded."""


def _client(settings: Settings, endpoint: str | None) -> Any:
    import boto3
    from botocore.config import Config

    def secret(value: Any) -> str | None:
        return None if value is None else str(value.get_secret_value())

    return boto3.client(
        "s3",
        endpoint_url=endpoint,
        region_name=settings.s3_region,
        aws_access_key_id=secret(settings.s3_access_key_id),
        aws_secret_access_key=secret(settings.s3_secret_access_key),
        config=Config(
            s3={"addressing_style": "path"},
            signature_version="s3v4",
            retries={"max_attempts": 5, "mode": "standard"},
        ),
    )


def is_missing(error: Exception) -> bool:
    """Whether a botocore ``ClientError`` says the object or bucket does not exist."""
    code = str(getattr(error, "response", {}).get("Error", {}).get("Code", ""))
    return code in {"404", "NoSuchKey", "NoSuchBucket", "NotFound", "NoSuchUpload"}


def is_precondition_failed(error: Exception) -> bool:
    code = str(getattr(error, "response", {}).get("Error", {}).get("Code", ""))
    return code in {"PreconditionFailed", "412", "ConditionalRequestConflict"}


class S3Storage:
    """A bucket holding every tenant's uploads and job outputs (``DCSEG_STORAGE_BACKEND=s3``)."""

    backend = "s3"

    def __init__(
        self, client: Any, bucket: str, prefix: str, presigner: Any, expiry_s: int
    ) -> None:
        self.client, self.bucket, self.prefix = client, bucket, prefix
        self.presigner, self.expiry_s = presigner, expiry_s

    @classmethod
    def from_settings(cls, settings: Settings) -> S3Storage:
        client = _client(settings, settings.s3_endpoint_url)
        public = settings.s3_public_endpoint_url
        presigner = _client(settings, public) if public else client
        return cls(
            client, settings.s3_bucket, settings.s3_prefix, presigner, settings.presign_expiry_s
        )

    # ----- keys and object primitives -----

    def tenant_prefix(self, tenant: str) -> str:
        return f"{self.prefix}tenants/{quote(tenant, safe='')}/"

    def key(self, tenant: str, relative: str) -> str:
        return self.tenant_prefix(tenant) + relative

    def setup(self) -> None:
        """Create the bucket unless it exists (API startup)."""
        from botocore.exceptions import ClientError

        try:
            self.client.head_bucket(Bucket=self.bucket)
        except ClientError as error:
            if not is_missing(error):
                raise
            self.client.create_bucket(Bucket=self.bucket)
            logger.info("created bucket %s", self.bucket)

    def objects(self, prefix: str) -> Iterator[dict[str, Any]]:
        """Every object under the absolute key ``prefix`` (``Key``, ``Size``, ...)."""
        pages = self.client.get_paginator("list_objects_v2").paginate(
            Bucket=self.bucket, Prefix=prefix
        )
        for page in pages:
            yield from page.get("Contents", [])

    def delete_prefix(self, prefix: str) -> None:
        batch: list[dict[str, str]] = []
        for item in self.objects(prefix):
            batch.append({"Key": item["Key"]})
            if len(batch) == 1000:
                self.client.delete_objects(Bucket=self.bucket, Delete={"Objects": batch})
                batch = []
        if batch:
            self.client.delete_objects(Bucket=self.bucket, Delete={"Objects": batch})

    def put_file(self, key: str, path: Path) -> None:
        self.client.upload_file(str(path), self.bucket, key)

    def put_json(self, key: str, data: Any, *, only_new: bool = False) -> bool:
        """Write a JSON object; with ``only_new`` only if the key does not exist yet (False
        when it did: another writer came first)."""
        from botocore.exceptions import ClientError

        body = json.dumps(data, indent=2, sort_keys=True).encode()
        extra = {"IfNoneMatch": "*"} if only_new else {}
        try:
            self.client.put_object(
                Bucket=self.bucket, Key=key, Body=body, ContentType="application/json", **extra
            )
        except ClientError as error:
            if only_new and is_precondition_failed(error):
                return False
            raise
        return True

    def get_json(self, key: str) -> Any | None:
        from botocore.exceptions import ClientError

        try:
            body = self.client.get_object(Bucket=self.bucket, Key=key)["Body"].read()
        except ClientError as error:
            if is_missing(error):
                return None
            raise
        return json.loads(body)

    def fetch(self, key: str, dest: Path, size: int, sha256: str) -> None:
        """Download ``key`` to ``dest``, checking its size and SHA-256 (IntegrityError)."""
        dest.parent.mkdir(parents=True, exist_ok=True)
        digest, written = hashlib.sha256(), 0
        body = self.client.get_object(Bucket=self.bucket, Key=key)["Body"]
        with dest.open("wb") as out:
            for chunk in body.iter_chunks(CHUNK):
                digest.update(chunk)
                written += len(chunk)
                out.write(chunk)
        if written != size or digest.hexdigest() != sha256:
            dest.unlink()
            raise IntegrityError(
                f"object {key} has {written} bytes with SHA-256 {digest.hexdigest()}; "
                f"its manifest says {size} bytes with {sha256}"
            )

    # ----- presigned multipart uploads (POST /v1/direct-uploads) -----

    def direct_key(self, tenant: str, upload_id: str) -> str:
        return self.key(tenant, f"direct-uploads/{upload_id}/archive")

    def start_multipart(self, tenant: str, upload_id: str, parts: int) -> tuple[str, list[str]]:
        """Start a multipart upload of the direct upload's archive; its id and one presigned
        ``PUT`` URL per part (valid for ``DCSEG_PRESIGN_EXPIRY_S``)."""
        key = self.direct_key(tenant, upload_id)
        started = self.client.create_multipart_upload(Bucket=self.bucket, Key=key)
        multipart_id = str(started["UploadId"])
        urls = [
            str(
                self.presigner.generate_presigned_url(
                    "upload_part",
                    Params={
                        "Bucket": self.bucket,
                        "Key": key,
                        "UploadId": multipart_id,
                        "PartNumber": number,
                    },
                    ExpiresIn=self.expiry_s,
                )
            )
            for number in range(1, parts + 1)
        ]
        return multipart_id, urls

    def complete_multipart(
        self, tenant: str, upload_id: str, multipart_id: str, parts: list[tuple[int, str]]
    ) -> None:
        """Join the parts (``(number, etag)``); botocore's ClientError when S3 refuses."""
        self.client.complete_multipart_upload(
            Bucket=self.bucket,
            Key=self.direct_key(tenant, upload_id),
            UploadId=multipart_id,
            MultipartUpload={"Parts": [{"PartNumber": n, "ETag": e} for n, e in parts]},
        )

    def abort_multipart(self, tenant: str, upload_id: str, multipart_id: str) -> None:
        from botocore.exceptions import ClientError

        try:
            self.client.abort_multipart_upload(
                Bucket=self.bucket, Key=self.direct_key(tenant, upload_id), UploadId=multipart_id
            )
        except ClientError as error:
            if not is_missing(error):
                raise

    def download(self, key: str, dest: Path, limit: int) -> tuple[int, str]:
        """Download ``key`` to ``dest``; ``(size, sha256)``; ValueError past ``limit`` bytes."""
        digest, written = hashlib.sha256(), 0
        body = self.client.get_object(Bucket=self.bucket, Key=key)["Body"]
        with dest.open("wb") as out:
            for chunk in body.iter_chunks(CHUNK):
                written += len(chunk)
                if written > limit:
                    raise ValueError(f"more than {limit} bytes")
                digest.update(chunk)
                out.write(chunk)
        return written, digest.hexdigest()

    # ----- the Storage interface -----

    def check(self) -> None:
        self.client.head_bucket(Bucket=self.bucket)

    def keep_upload(self, tenant: str, upload_id: str, tmp: Path) -> None:
        self.put_file(self.key(tenant, f"uploads/{upload_id}/archive"), tmp / "archive")

    def remove_upload(self, tenant: str, upload_id: str) -> None:
        self.delete_prefix(self.key(tenant, f"uploads/{upload_id}/"))

    def remove_job(self, tenant: str, job_id: str) -> None:
        self.delete_prefix(self.key(tenant, f"jobs/{job_id}/"))

    def manifest(self, tenant: str, job_id: str) -> dict[str, Any]:
        stages = []
        for item in self.objects(self.key(tenant, f"jobs/{job_id}/stages/")):
            entry = self.get_json(item["Key"])
            if isinstance(entry, dict):
                stages.append(entry)
        stages.sort(key=lambda entry: int(entry.get("index", 0)))
        return {"version": 1, "job_id": job_id, "stages": stages}

    def files(self, tenant: str, job_id: str) -> list[StoredFile]:
        return [
            StoredFile(name, int(info["size"]), str(info["sha256"]), key=str(info["key"]))
            for name, info in manifest_files(self.manifest(tenant, job_id))
        ]

    def read(self, tenant: str, item: StoredFile, start: int, end: int) -> Iterator[bytes]:
        assert item.key is not None
        response = self.client.get_object(
            Bucket=self.bucket, Key=self.key(tenant, item.key), Range=f"bytes={start}-{end}"
        )
        yield from response["Body"].iter_chunks(CHUNK)

    def presign(self, tenant: str, item: StoredFile) -> str | None:
        assert item.key is not None
        url: str = self.presigner.generate_presigned_url(
            "get_object",
            Params={"Bucket": self.bucket, "Key": self.key(tenant, item.key)},
            ExpiresIn=self.expiry_s,
        )
        return url

    def tenant_bytes(self, store: Store, tenant: str) -> int:
        return sum(int(item["Size"]) for item in self.objects(self.tenant_prefix(tenant)))
