"""Derived jobs (``parent_job_id``) reuse their parent's finished stages: an intact one is
linked, one whose files vanished is run again. On SQLite and PostgreSQL."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from jobstore.contract import JobPaths
from jobstore.settings import Settings
from jobstore.store import Store
from tests.service import test_databases
from tests.service.conftest import make_settings
from tests.worker.conftest import add_job
from tests.worker.fakes import FakeStage
from worker.execute import execute_job, read_manifest

# the parametrised SQLite/PostgreSQL fixtures, in place of tests/worker/conftest.py's store
postgres_server = test_databases.postgres_server
db_url = test_databases.db_url
store = test_databases.store


@pytest.fixture
def worker_env(store: Store, tmp_path: Path) -> Settings:
    """Settings whose storage holds the fixture upload ``u1`` (an empty capture)."""
    settings = make_settings(tmp_path, database_url=store.url, heartbeat_s=0.1)
    (settings.storage_dir / "uploads" / "u1" / "data").mkdir(parents=True)
    return settings


def test_derived_job_redoes_stage_whose_parent_files_vanished(store, worker_env):
    """Defect 5: a parent job deleted while a derived job links its files yields an empty
    stage marked done."""
    parent = add_job(store)
    assert execute_job(parent, store, worker_env, stages=[FakeStage("one")]) == "succeeded"
    shutil.rmtree(JobPaths(worker_env.storage_dir, parent).output / "one")  # manifest remains
    child, stage = add_job(store, parent=parent), FakeStage("one")
    assert execute_job(child, store, worker_env, stages=[stage]) == "succeeded"
    assert stage.runs == 1
    paths = JobPaths(worker_env.storage_dir, child)
    assert set(read_manifest(paths)["stages"][0]["files"]) == {"one/out.txt"}
    assert (paths.output / "one" / "out.txt").read_bytes() == b"hello"


def test_derived_job_reuses_intact_parent_stage(store, worker_env):
    """Defect 5 (no regression): an intact parent stage is still linked, not recomputed."""
    parent = add_job(store)
    assert execute_job(parent, store, worker_env, stages=[FakeStage("one")]) == "succeeded"
    child, stage = add_job(store, parent=parent), FakeStage("one")
    assert execute_job(child, store, worker_env, stages=[stage]) == "succeeded"
    assert stage.runs == 0
    assert read_manifest(JobPaths(worker_env.storage_dir, child))["stages"][0]["details"] == {
        "reused": True
    }
