"""Fixtures of the worker tests: a store with one tenant, one upload and helpers to add jobs."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from service.models import Job, Upload
from service.settings import Settings
from service.store import Store, new_id
from tests.service.conftest import scene  # noqa: F401 (the shared synthetic capture fixture)


@pytest.fixture
def settings(tmp_path: Path) -> Settings:
    return Settings(
        storage_dir=tmp_path / "data",
        database_url=None,
        broker_url=None,
        api_keys="",
        heartbeat_s=0.1,
        poll_interval_s=0.05,
    )


@pytest.fixture
def store(settings: Settings) -> Iterator[Store]:
    settings.storage_dir.mkdir(parents=True)
    store = Store(settings.db_url)
    store.init_schema()
    store.ensure_tenant("t")
    upload = Upload(id="u1", tenant_id="t", sha256="0" * 64, size=1, content_type="x", summary={})
    store.add_upload(upload)
    (settings.storage_dir / "uploads" / "u1" / "data").mkdir(parents=True)
    yield store
    store.close()


def add_job(store: Store, parent: str | None = None, options: dict[str, Any] | None = None) -> str:
    job = Job(
        id=new_id(),
        tenant_id="t",
        upload_id="u1",
        parent_job_id=parent,
        status="queued",
        config={"preset": "fast", "options": options or {}},
        event_seq=0,
    )
    return store.create_job(job).id
