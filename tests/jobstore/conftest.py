"""The job store's tests run on SQLite and on PostgreSQL: the parametrised fixtures of
``tests.service.test_databases`` (a store with tenant ``t`` and upload ``u1``)."""

from __future__ import annotations

from datetime import timedelta

from jobstore.models import Job, Upload
from jobstore.store import Store, new_id
from tests.service import test_databases

postgres_server = test_databases.postgres_server
db_url = test_databases.db_url
store = test_databases.store

LEASE = timedelta(seconds=60)


def add_job(store: Store, parent: str | None = None) -> str:
    """A queued job of tenant ``t`` on upload ``u1`` (added first when missing)."""
    if store.get_upload("u1", "t") is None:
        store.add_upload(
            Upload(id="u1", tenant_id="t", sha256="0" * 64, size=1, content_type="x", summary={})
        )
    job = Job(
        id=new_id(),
        tenant_id="t",
        upload_id="u1",
        parent_job_id=parent,
        status="queued",
        config={"preset": "fast", "options": {}},
        event_seq=0,
    )
    return store.create_job(job).id
