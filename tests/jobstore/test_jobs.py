"""Jobs as the API creates them (:mod:`jobstore.store.jobs`): the per-tenant cap holds under
concurrent requests. On SQLite and PostgreSQL.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

from jobstore.models import Job
from service.deps import AppState
from service.problems import ApiProblem
from service.routes.jobs import _new_job
from service.schemas import JobCreate
from tests.service.conftest import make_settings
from tests.worker.fakes import RecordingQueue


def test_tenant_job_cap_is_atomic_under_concurrent_posts(store, tmp_path, monkeypatch):
    """Defect 2: per-tenant job cap is check-then-insert in two transactions."""
    cap, callers = 2, 6
    settings = make_settings(tmp_path, database_url=store.url, max_running_jobs_per_tenant=cap)
    state = AppState(settings=settings, store=store, queue=RecordingQueue())
    barrier = threading.Barrier(callers)
    insert: Callable[..., Job] = store.create_job

    def create_together(job: Job, **kwargs: Any) -> Job:
        barrier.wait(timeout=30)  # every caller has passed any check made before the insert
        return insert(job, **kwargs)

    monkeypatch.setattr(store, "create_job", create_together)
    accepted, refused = [], []

    def post() -> None:
        try:
            accepted.append(_new_job(state, "t", JobCreate(upload_id="u1")).id)
        except ApiProblem as problem:
            refused.append(problem)

    threads = [threading.Thread(target=post) for _ in range(callers)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert len(accepted) == cap and store.count_active("t") == cap
    assert len(refused) == callers - cap
    assert all(p.status == 429 and "the limit is 2" in p.detail for p in refused)
