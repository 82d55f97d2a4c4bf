"""Shutdown of the API and its embedded worker: an open event stream does not hold it, its
waits share one deadline, plain uvicorn exits within it, shutdowns never consume attempts,
and an interrupt never throws away a stage that finished."""

from __future__ import annotations

import asyncio
import contextlib
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from datetime import timedelta
from pathlib import Path
from typing import IO

import httpx
import pytest
from fastapi.concurrency import run_in_threadpool

from jobstore.contract import JobPaths
from jobstore.models import Upload
from jobstore.settings import Settings
from jobstore.store import Store
from service.main import shut_down
from tests.service import test_databases
from tests.service.conftest import (
    AUTH_A,
    KEY_A,
    TAR,
    free_port,
    make_settings,
    tar_bytes,
    wait_ready,
)
from tests.service.conftest import wait_for as wait_until
from tests.worker.conftest import REPO, add_job
from tests.worker.fakes import FakeStage, slow_stages, stuck_stages
from worker.execute import default_worker_id, execute_job, read_manifest, worker_id_prefix
from worker.local import KILL_WAIT_S, EmbeddedWorker

# ----- 1. an open event stream blocks shutdown -----


SERVERS = {
    "dcseg serve": [sys.executable, "-m", "dcseg", "serve"],  # the API image's command
    "plain uvicorn": [str(Path(sys.executable).with_name("uvicorn")), "service.main:app"],
}


def _serve(
    tmp_path: Path, port: int, grace: float, log: Path, server: str
) -> subprocess.Popen[bytes]:
    """The API without a worker on 127.0.0.1:``port``, in its own process group."""
    env = {
        **os.environ,
        "DCSEG_STORAGE_DIR": str(tmp_path / "data"),
        "DCSEG_API_KEYS": f"tenant-a:{KEY_A}",
        "DCSEG_SHUTDOWN_GRACE_S": str(grace),
        "DCSEG_EMBEDDED_WORKER": "off",
        "DCSEG_POLL_INTERVAL_S": "0.1",
        "DCSEG_MAX_STREAM_S": "900",
    }
    for name in ("DCSEG_DATABASE_URL", "DCSEG_BROKER_URL"):
        env.pop(name, None)
    command = [*SERVERS[server], "--host", "127.0.0.1", "--port", str(port)]
    command += ["--log-level", "info"]
    with log.open("wb") as output:
        return subprocess.Popen(
            command,
            env=env,
            cwd=REPO,
            stdout=output,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )


def _queued_job(client: httpx.Client, scene: Path, server: subprocess.Popen[bytes]) -> str:
    wait_ready(client, server)
    upload = client.post("/v1/uploads", content=tar_bytes(scene), headers=TAR).json()
    job = client.post("/v1/jobs", json={"upload_id": upload["id"]}).json()
    return str(job["id"])


def _read_stream(
    client: httpx.Client, job_id: str, lines: list[str], opened: threading.Event
) -> None:
    with contextlib.suppress(httpx.HTTPError):
        with client.stream("GET", f"/v1/jobs/{job_id}/events") as response:
            opened.set()
            for line in response.iter_lines():
                lines.append(line)


@pytest.mark.parametrize("server", sorted(SERVERS))
def test_open_event_stream_does_not_block_shutdown(tmp_path, scene, server):
    """Review 2(d): "an open SSE stream blocks shutdown" (uvicorn waits for open responses
    before the lifespan shutdown runs; with DCSEG_MAX_STREAM_S=900 it hung up to 15 min)."""
    grace = 2.0
    port, log = free_port(), tmp_path / "serve.log"
    process = _serve(tmp_path, port, grace, log, server)
    lines: list[str] = []
    opened = threading.Event()
    try:
        url = f"http://127.0.0.1:{port}"
        with httpx.Client(base_url=url, headers=AUTH_A, timeout=30) as client:
            job_id = _queued_job(client, scene, process)
            reader = threading.Thread(target=_read_stream, args=(client, job_id, lines, opened))
            reader.start()
            assert opened.wait(30), log.read_text()
            wait_until(lambda: any(line.startswith("id:") for line in lines), timeout=30)
            process.send_signal(signal.SIGTERM)
            try:  # generous: asserts that it exits, far below the stream's 900 s lifetime
                process.wait(grace + 30 + KILL_WAIT_S)
            except subprocess.TimeoutExpired:
                pytest.fail(f"{server} did not exit after SIGTERM:\n{log.read_text()[-3000:]}")
            reader.join(30)
            assert not reader.is_alive()
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(process.pid, signal.SIGKILL)
        process.wait(10)
    # a clean shutdown (uvicorn then re-raises the SIGTERM it caught)
    assert "Application shutdown complete" in log.read_text(), log.read_text()[-3000:]
    assert any("shutting down" in line and "Last-Event-ID" in line for line in lines), lines


# ----- 2. shutdown bounded by one deadline -----


class SlowWorker:
    """An embedded worker whose stop takes all the time it is given."""

    def __init__(self, recovery_done: threading.Event, grace: float) -> None:
        self.recovery_done, self.grace = recovery_done, grace
        self.deadline: float | None = None
        self.called_at = 0.0
        self.started_before_recovery_ended = False

    def stop(self, deadline: float | None = None) -> None:
        self.called_at = time.monotonic()
        self.started_before_recovery_ended = not self.recovery_done.is_set()
        self.deadline = deadline
        end = deadline if deadline is not None else self.called_at + self.grace
        time.sleep(max(0.0, end - time.monotonic()))


def test_shutdown_waits_share_one_deadline():
    """Review 2(d): "shutdown is not bounded by DCSEG_SHUTDOWN_GRACE_S" (the recovery wait,
    then the worker stop, each took the whole grace) and "housekeeping.cancel() is neither
    awaited nor bounded"."""
    grace = 2.0
    release, recovery_done = threading.Event(), threading.Event()
    cleaned: list[str] = []

    async def blocked_recovery() -> None:  # a pass blocked in the database, deaf to cancel
        blocked = asyncio.ensure_future(run_in_threadpool(release.wait, 60))
        while not blocked.done():
            with contextlib.suppress(asyncio.CancelledError):
                await asyncio.shield(blocked)
        recovery_done.set()

    async def housekeeping() -> None:
        try:
            await asyncio.sleep(3600)
        finally:
            await asyncio.sleep(0.05)  # cleaning up after the cancel takes a moment
            cleaned.append("housekeeping")

    async def scenario() -> tuple[float, SlowWorker, bool]:
        recovery = asyncio.create_task(blocked_recovery())
        tidy = asyncio.create_task(housekeeping())
        await asyncio.sleep(0.05)
        worker = SlowWorker(recovery_done, grace)
        begun = time.monotonic()
        await shut_down([recovery, tidy], worker, grace)  # type: ignore[arg-type]
        still_blocked = not recovery.done()
        release.set()
        await recovery
        return begun, worker, still_blocked

    begun, worker, still_blocked = asyncio.run(scenario())
    assert worker.started_before_recovery_ended
    assert worker.called_at < begun + grace  # the waits run side by side, not one by one ...
    assert worker.deadline is not None  # ... to one deadline, set when the shutdown began
    assert begun + grace <= worker.deadline <= worker.called_at + grace
    assert still_blocked  # the blocked pass was not waited for past the deadline
    assert cleaned == ["housekeeping"]  # the cancelled housekeeping was awaited


# ----- 3. shutdowns consume attempts -----


def _held(store: Store, job_id: str, worker: str) -> None:
    assert store.claim_job(job_id, worker, timedelta(seconds=60)) is not None


postgres_server = test_databases.postgres_server
db_url = test_databases.db_url  # parametrised: SQLite and PostgreSQL


@pytest.fixture
def db_store(db_url: str) -> Iterator[Store]:
    """A store on SQLite and PostgreSQL with the upload ``u1`` of tenant ``t``."""
    store = Store(db_url)
    store.init_schema()
    store.ensure_tenant("t")
    upload = Upload(id="u1", tenant_id="t", sha256="0" * 64, size=1, content_type="x", summary={})
    store.add_upload(upload)
    yield store
    store.close()


def test_release_attempts_of_gives_back_the_attempts_of_one_process_only(db_store):
    """Review 2(a): the parent of a killed worker gives back the attempt of the job it held
    (worker ids are host:pid:thread), once, and no other worker's."""
    store = db_store
    mine, other, similar, wild = (add_job(store) for _ in range(4))
    _held(store, mine, "host:12:345")
    _held(store, other, "host:99:345")
    _held(store, similar, "host:123:345")  # "host:12" must not match "host:123"
    _held(store, wild, "ho_t:12:345")  # nor may "ho_t" (a LIKE wildcard) match "host"
    assert store.release_attempts_of("ho_t:12") == [wild]
    assert store.release_attempts_of("host:12") == [mine]
    assert store.release_attempts_of("host:12") == []  # given back once only
    assert [store.get_job(j).attempts for j in (mine, other, similar, wild)] == [0, 1, 1, 0]
    assert set(store.requeue_stale(timedelta(seconds=60))) == {mine, wild}  # lease expired


def test_shutdown_that_kills_the_worker_does_not_consume_an_attempt(store, settings):
    """Review 2(a): "EmbeddedWorker.stop() SIGKILLs the child after the grace ... the attempt
    is then never released, so three slow restarts fail the job as 'worker died 3 times'"."""
    job_id = add_job(store)
    grace = settings.model_copy(update={"shutdown_grace_s": 0.5})
    for _ in range(settings.max_attempts + 1):  # more shutdowns than attempts
        worker = EmbeddedWorker(grace, mode="process", stages=stuck_stages)
        worker.start()
        try:
            wait_until(lambda: store.get_job(job_id).message == "stuck: started", timeout=60)
        finally:
            worker.stop()  # the stuck stage never reaches a report: the child is killed
        job = store.get_job(job_id)
        assert job.status == "running" and job.attempts == 0, (job.status, job.attempts)
        assert store.requeue_running() == [job_id]  # what the next start does
    assert store.get_job(job_id).status == "queued"


def test_clean_shutdown_gives_the_attempt_back_once(store, settings):
    """Review 2(a) (no double count): a child that stops by itself already gave its attempt
    back; the parent's release must not take back an earlier crash's attempt too."""
    job_id = add_job(store)
    _held(store, job_id, "crashed-worker")  # an earlier run died: one attempt counted
    assert store.requeue_stale(timedelta(0)) == [job_id]
    worker = EmbeddedWorker(settings, mode="process", stages=slow_stages)
    worker.start()
    try:
        wait_until(lambda: store.get_job(job_id).stage == "slow", timeout=60)  # running it
    finally:
        worker.stop()  # reports every 0.1 s: interrupted at the next one, exits by itself
    assert store.get_job(job_id).attempts == 1


def test_worker_id_prefix_names_this_process():
    """The parent gives back attempts by the ``host:pid`` prefix of its child's worker ids."""
    assert default_worker_id().startswith(worker_id_prefix(os.getpid()) + ":")


# ----- 4. an interrupt discards a finished stage -----


def test_interrupt_after_a_stage_finished_keeps_the_stage(store, settings: Settings):
    """Review 2(a): "a stage that finished after its last progress report is thrown away if
    the shutdown flag is set in that window" (check() after stage.run raised Interrupted)."""
    job_id = add_job(store)
    stop = threading.Event()
    first = FakeStage("one", on_end=stop.set)  # the shutdown comes after its last report
    second = FakeStage("two")
    status = execute_job(job_id, store, settings, stages=[first, second], interrupt=stop.is_set)
    assert status == "interrupted"
    paths = JobPaths(settings.storage_dir, job_id)
    assert [s["name"] for s in read_manifest(paths)["stages"]] == ["one"]
    assert (paths.output / "one" / "out.txt").read_bytes() == b"hello"
    assert second.runs == 0
    assert store.get_job(job_id).attempts == 0  # still not counted
    resumed = execute_job(job_id, store, settings, stages=[first, second])
    assert resumed == "succeeded" and first.runs == 1 and second.runs == 1


# ----- 5. plain uvicorn exits within the shutdown grace -----


LONG_JOB = {"reconstruct": {"iterations": 100_000, "holdout": 0}}


QUICK_JOB = {"reconstruct": {"iterations": 1, "holdout": 0}, "affinity": {"iterations": 1}}
"""Ends within seconds; the worker then idles."""


def _start_uvicorn(
    tmp_path: Path, port: int, grace: float, log: IO[bytes]
) -> subprocess.Popen[bytes]:
    """Plain uvicorn serving ``dcseg serve``'s app, in its own process group, with its
    embedded worker."""
    env = {
        **os.environ,
        "DCSEG_STORAGE_DIR": str(tmp_path / "data"),
        "DCSEG_API_KEYS": f"tenant-a:{KEY_A}",
        "DCSEG_SWEEP_INTERVAL_S": "0.3",
        "DCSEG_SHUTDOWN_GRACE_S": str(grace),
        "DCSEG_POLL_INTERVAL_S": "0.1",
        "DCSEG_DEVICE": "cpu",
    }
    for name in ("DCSEG_DATABASE_URL", "DCSEG_BROKER_URL"):
        env.pop(name, None)
    script = Path(sys.executable).with_name("uvicorn")
    command = [str(script), "dcseg.cli.serve:create_app", "--factory"]
    command += ["--host", "127.0.0.1", "--port", str(port)]
    command += ["--log-level", "warning"]
    return subprocess.Popen(
        command, env=env, cwd=REPO, stdout=log, stderr=subprocess.STDOUT, start_new_session=True
    )


def _submit(url: str, scene: Path, server: subprocess.Popen[bytes], log: Path, busy: bool) -> str:
    """Upload the scene and submit a job; ``busy``: a long job, returned once it reconstructs;
    otherwise a one-step job, returned once it ended (the worker then idles)."""
    with httpx.Client(base_url=url, headers=AUTH_A, timeout=30) as client:
        wait_ready(client, server, log)
        upload = client.post("/v1/uploads", content=tar_bytes(scene), headers=TAR).json()
        options = LONG_JOB if busy else QUICK_JOB
        body = {"upload_id": upload["id"], "options": options}
        job_id: str = client.post("/v1/jobs", json=body).json()["id"]

        def reached() -> bool:
            job = client.get(f"/v1/jobs/{job_id}").json()
            if not busy:
                return bool(job["status"] in ("succeeded", "failed"))
            assert job["status"] in ("queued", "running"), job
            return "reconstruct: step" in (job["progress"]["message"] or "")

        wait_until(reached, timeout=120, every=0.1)
    return job_id


def _signal_and_wait(
    process: subprocess.Popen[bytes], target: str, bound: float, log: Path
) -> None:
    """SIGTERM to the server (or its whole process group); fail unless it exits in ``bound``."""
    try:
        if target == "process group":  # Ctrl-C in a terminal, `timeout`, some init systems
            os.killpg(process.pid, signal.SIGTERM)
        else:
            process.send_signal(signal.SIGTERM)
        try:
            process.wait(bound)
        except subprocess.TimeoutExpired:
            pytest.fail(f"uvicorn did not exit after SIGTERM:\n{log.read_text()[-3000:]}")
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(process.pid, signal.SIGKILL)
        process.wait(10)


@pytest.mark.parametrize(
    ("target", "busy"),
    [("process group", False), ("process group", True), ("server only", True)],
    ids=["group-idle", "group-busy", "server-busy"],
)
def test_uvicorn_exits_within_the_shutdown_grace(tmp_path, scene, target, busy):
    """Defect 3: "`uvicorn service.main:app` sent SIGTERM ... never exited"; shutdown must end
    within a bounded time (``DCSEG_SHUTDOWN_GRACE_S``) whatever the embedded worker does (the
    cause: the old stop flag, a multiprocessing Event, deadlocked ``set()`` once the idle child
    waiting on it had died of the same signal), and an interrupted job stays resumable."""
    grace = 3.0
    port = free_port()
    log = tmp_path / "uvicorn.log"
    with log.open("wb") as output:
        process = _start_uvicorn(tmp_path, port, grace, output)
        try:
            job_id = _submit(f"http://127.0.0.1:{port}", scene, process, log, busy)
            time.sleep(1.0)  # past a few sweep intervals, as in the report
        finally:  # generous margin: this asserts that it exits, not how fast
            _signal_and_wait(process, target, grace + 60, log)
    if not busy:
        return
    store = Store(f"sqlite:///{(tmp_path / 'data' / 'dcseg.db').resolve()}")
    try:
        job = store.get_job(job_id)
    finally:
        store.close()
    # interrupted: its lease was expired, so the API's own sweep may already have requeued it
    assert job is not None and job.status in ("running", "queued"), log.read_text()[-3000:]
    finished = read_manifest(JobPaths(tmp_path / "data", job_id))["stages"]
    assert [s["name"] for s in finished] == ["validate"]  # kept for the resumed run


# ----- 6. an interrupted run uses no attempt -----


def test_attempts_interrupted_run_is_not_counted(db_store, tmp_path):
    """Defect 1: a run stopped by a worker shutdown is no crash; it must not use up an attempt."""
    store = db_store
    settings = make_settings(tmp_path, database_url=store.url, heartbeat_s=0.1)
    (settings.storage_dir / "uploads" / "u1" / "data").mkdir(parents=True)
    job_id = add_job(store)
    for _ in range(4):  # more shutdowns than the cap allows crashes
        status = execute_job(
            job_id, store, settings, stages=[FakeStage("one")], interrupt=lambda: True
        )
        assert status == "interrupted"
        assert store.get_job(job_id).attempts == 0
        assert store.requeue_running() == [job_id]
    assert execute_job(job_id, store, settings, stages=[FakeStage("one")]) == "succeeded"
