"""Upload records: kept, read, deleted when no job uses them, and counted for quotas."""

from __future__ import annotations

from datetime import datetime

from sqlalchemy import func, select

from jobstore.models import Job, Upload
from jobstore.store.engine import StoreBase


class UploadInUse(Exception):
    """An upload still referenced by jobs cannot be deleted (answered with 409)."""


class UploadsMixin(StoreBase):
    """Upload rows (their files live in :mod:`jobstore.blobstore`)."""

    def add_upload(self, upload: Upload) -> Upload:
        with self.session() as s:
            s.add(upload)
        return upload

    def get_upload(self, upload_id: str, tenant: str) -> Upload | None:
        with self.session() as s:
            upload = s.get(Upload, upload_id)
        return upload if upload is not None and upload.tenant_id == tenant else None

    def delete_upload(self, upload_id: str, tenant: str | None) -> Upload | None:
        """Delete an upload record (of ``tenant``, or of anyone when None); ``UploadInUse``
        while jobs refer to it. The row lock and the job's foreign key order this against a
        job being created for it: one of the two fails cleanly."""
        with self.session() as s:
            upload = s.get(Upload, upload_id, with_for_update=True)
            if upload is None or (tenant is not None and upload.tenant_id != tenant):
                return None
            jobs = s.scalar(select(func.count()).where(Job.upload_id == upload_id)) or 0
            if jobs:
                raise UploadInUse(f"{jobs} job(s) use this upload; delete them first")
            s.delete(upload)
        return upload

    def unused_uploads(self, created_before: datetime) -> list[str]:
        """Ids of uploads created before ``created_before`` that no job refers to."""
        used = select(Job.id).where(Job.upload_id == Upload.id).exists()
        query = select(Upload.id).where(Upload.created_at < created_before, ~used)
        with self.session() as s:
            return list(s.scalars(query.order_by(Upload.created_at)))

    def tenant_storage(self, tenant: str) -> tuple[int, list[str]]:
        """The bytes of the tenant's stored uploads and the ids of its jobs (their outputs are
        measured from their manifests)."""
        stored = func.coalesce(Upload.stored_bytes, Upload.size)
        with self.session() as s:
            used = s.scalar(select(func.sum(stored)).where(Upload.tenant_id == tenant)) or 0
            jobs = list(s.scalars(select(Job.id).where(Job.tenant_id == tenant)))
        return int(used), jobs
