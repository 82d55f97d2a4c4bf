"""Load benchmark of the REST API while a job really runs (run by hand).

    python benchmarks/bench_service.py --out benchmarks/results/service.json
    python benchmarks/bench_service.py --mode deployed \
        --out benchmarks/results/service_deployed.json

``--mode embedded`` (default) starts ``dcseg serve`` (the API process plus its local worker
process) with SQLite. ``--mode deployed`` runs the service as deployed: a fresh PostgreSQL
database (created on ``--postgres-admin-url``, dropped afterwards), an empty Redis database
as the broker (``--redis-url``; the first empty one of ``--redis-dbs``, flushed afterwards),
``--api-processes`` uvicorn worker processes behind one port (``uvicorn --factory --workers``
shares one listening socket) and a separate ``dcseg worker`` process that runs the job.

Both modes upload a small ``dcseg synth`` scene, create a job that runs for the whole
benchmark, and add ``--list-jobs - 1`` canceled jobs so that ``GET /v1/jobs`` returns a full
page. Then, for ``--duration`` seconds each, ``--clients`` concurrent ``httpx.AsyncClient``
tasks run four phases:

1. ``healthz``: the bare ``GET /healthz`` (no auth, no database);
2. ``api``: job polls ``GET /v1/jobs/{id}`` and, every fifth request, a list
   ``GET /v1/jobs?page_size=20`` (bearer auth, rate limiter, database read, JSON and ETag);
3. ``events``: ``GET /v1/jobs/{id}/events`` (SSE) from the start: the latency is the time to
   the first event (replayed from the store), then the client disconnects (so every request
   opens a new connection);
4. ``artifacts``: downloads of the running job's largest artifact so far (its ``validate``
   report, as the job is still reconstructing) through the API;
5. ``artifacts_presigned`` (``--mode deployed --storage s3`` only): the same file by its
   presigned ``download_url``, straight from the S3 server (no API in the path).

It reports requests/s, p50/p99 latency, errors and the API processes' CPU time per request
(``/proc/<pid>/stat``), and the job's status and its worker's CPU seconds across the phases
(evidence that the job really ran meanwhile). The per-tenant rate limit is 10^9 requests a
minute and the job cap 1000 so that neither answers 429 during the load phases; uvicorn's
access log is off. Clients, API and worker share the machine's cores.

In deployed mode a last check starts a second API (same processes count, database and broker)
with ``DCSEG_RATE_LIMIT_PER_MINUTE=--rate-limit`` and ``DCSEG_RATE_LIMIT_URL`` set to the
broker's Redis database, then sends ``--rate-burst`` polls, each on a new connection, within one
clock minute. Each connection's server process is found from ``/proc/net/tcp`` and the
processes' open sockets, so the result shows how many requests each process got and admitted:
a limit shared across the processes admits at most ``--rate-limit`` in total, a per-process
limit up to ``--rate-limit`` per process. Whether the service has a ``rate_limit_url`` setting
at all is recorded too (without it the variable is ignored and the limit is per process).
Every loop is bounded and everything listens on 127.0.0.1; the benchmark stops by itself.
"""

from __future__ import annotations

import argparse
import asyncio
import http.client
import io
import json
import os
import platform
import signal
import socket
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
import uuid
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass, field
from importlib.metadata import version
from pathlib import Path
from typing import Any

import httpx

API_KEY = "bench-key-0123456789"
HEADERS = {"Authorization": f"Bearer {API_KEY}"}
LIST_EVERY = 5
"""In the API phase, every fifth request of a client lists jobs; the others poll the job."""
UNLIMITED = 10**9
"""Requests per minute during the load phases: the limiter never answers 429."""
START_TIMEOUT_S = 120.0
"""How long a server may take to answer ``/healthz`` and the worker to take the job."""
STOP_GRACE_S = 30.0
"""How long a process may take to exit after SIGTERM before its process group is killed."""


@dataclass(frozen=True)
class Target:
    """One request of a client: its label in the results and its path."""

    label: str
    path: str
    first_event: bool = False
    """Server-sent events: measure the time to the first event, then disconnect."""
    auth: bool = True
    """Send the API key (not to presigned object-store URLs, which carry their own)."""


Pick = Callable[[int], Target]
"""Request number of a client -> what to request."""


@dataclass
class Samples:
    """Latencies (seconds) and error count of one endpoint in one phase."""

    latencies: list[float] = field(default_factory=list)
    errors: int = 0
    statuses: dict[int, int] = field(default_factory=dict)


@dataclass
class Server:
    """A running API: its port and the process whose CPU time (with its children's when
    ``children``) is the API's."""

    process: subprocess.Popen[bytes]
    port: int
    children: bool
    worker: subprocess.Popen[bytes] | None = None
    """The separate worker process (deployed); None = the API's own child (embedded)."""

    @property
    def base_url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def api_pids(self) -> list[int]:
        if not self.children:
            return [self.process.pid]
        return [self.process.pid, *child_pids(self.process.pid)]

    def job_pids(self) -> list[int]:
        """The processes that run the job: the worker and its children."""
        if self.worker is None:
            return child_pids(self.process.pid)
        return [self.worker.pid, *child_pids(self.worker.pid)]


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


def percentile(values: list[float], q: float) -> float:
    """The ``q``-th percentile (0-100) by linear interpolation; NaN when empty."""
    if not values:
        return float("nan")
    ordered = sorted(values)
    rank = (len(ordered) - 1) * q / 100.0
    low = int(rank)
    high = min(low + 1, len(ordered) - 1)
    return ordered[low] + (ordered[high] - ordered[low]) * (rank - low)


def process_cpu_s(pid: int) -> float | None:
    """User + system CPU seconds of process ``pid`` (Linux ``/proc``), None elsewhere."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def child_pids(parent: int) -> list[int]:
    """The direct children of ``parent`` (from ``/proc/<pid>/stat``), without
    multiprocessing's resource tracker (it serves no requests and runs no job)."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            command = (entry / "cmdline").read_bytes()
        except OSError:
            continue
        if int(fields[1]) == parent and b"resource_tracker" not in command:
            found.append(int(entry.name))
    return sorted(found)


def total_cpu_s(pids: list[int]) -> float | None:
    values = [process_cpu_s(pid) for pid in pids]
    return None if any(v is None for v in values) else sum(v or 0.0 for v in values)


def scene_tar(folder: Path, frames: int, size: str) -> bytes:
    """A ``dcseg synth`` scene (capture, masks, vocabulary, ground truth) as a tar archive."""
    command = [sys.executable, "-m", "dcseg", "synth", str(folder), "--frames", str(frames)]
    subprocess.run([*command, "--size", size], check=True, capture_output=True)
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w") as archive:
        for path in sorted(folder.rglob("*")):
            archive.add(path, arcname=path.relative_to(folder).as_posix(), recursive=False)
    return buffer.getvalue()


# ----- processes -------------------------------------------------------------------------


def service_env(root: Path, **overrides: str) -> dict[str, str]:
    """The environment of the API and worker processes (storage and keys under ``root``)."""
    env = {
        **os.environ,
        "OMP_WAIT_POLICY": os.environ.get("OMP_WAIT_POLICY", "PASSIVE"),
        "DCSEG_STORAGE_DIR": str(root / "data"),
        "DCSEG_API_KEYS": f"bench:{API_KEY}",
        "DCSEG_RATE_LIMIT_PER_MINUTE": str(UNLIMITED),
        "DCSEG_MAX_RUNNING_JOBS_PER_TENANT": "1000",
        "DCSEG_MAX_STREAMS_PER_TENANT": "1000",  # the events phase opens one per client
        "DCSEG_FAILED_AUTH_PER_MINUTE": str(UNLIMITED),
        "DCSEG_DEVICE": "cpu",
    }
    for name in ("DCSEG_BROKER_URL", "DCSEG_DATABASE_URL", "DCSEG_RATE_LIMIT_URL"):
        env.pop(name, None)
    return env | overrides


@contextmanager
def launched(
    command: list[str], env: dict[str, str], log: Path
) -> Iterator[subprocess.Popen[bytes]]:
    """Run ``command`` in its own process group; SIGTERM at the end, then SIGKILL to the group
    after :data:`STOP_GRACE_S`."""
    with log.open("wb") as out:
        process = subprocess.Popen(
            command, env=env, stdout=out, stderr=subprocess.STDOUT, start_new_session=True
        )
        try:
            yield process
        finally:
            stop(process)


def stop(process: subprocess.Popen[bytes]) -> None:
    if process.poll() is None:
        process.send_signal(signal.SIGTERM)
    try:
        process.wait(STOP_GRACE_S)
    except subprocess.TimeoutExpired:
        pass
    try:  # the group is the one this benchmark created for the process (start_new_session)
        os.killpg(process.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    process.wait(10)


def wait_healthy(server: Server, log: Path) -> None:
    deadline = time.monotonic() + START_TIMEOUT_S
    while True:
        try:
            if httpx.get(f"{server.base_url}/healthz", timeout=2).status_code == 200:
                return
        except httpx.HTTPError:
            pass
        if server.process.poll() is not None or time.monotonic() > deadline:
            raise RuntimeError(f"the API did not start; see {log}")
        time.sleep(0.2)


@contextmanager
def embedded_api(root: Path, port: int) -> Iterator[Server]:
    """``dcseg serve`` in embedded mode on ``port`` with storage and SQLite under ``root``."""
    command = [sys.executable, "-m", "dcseg", "serve", "--port", str(port)]
    log = root / "serve.log"
    with launched([*command, "--log-level", "warning"], service_env(root), log) as process:
        server = Server(process, port, children=False)
        wait_healthy(server, log)
        yield server


@contextmanager
def uvicorn_api(
    env: dict[str, str],
    port: int,
    processes: int,
    log: Path,
    worker: subprocess.Popen[bytes] | None = None,
) -> Iterator[Server]:
    """``processes`` uvicorn workers of ``service.main:create_app`` sharing one port."""
    command = [sys.executable, "-m", "uvicorn", "service.main:create_app", "--factory"]
    command += ["--host", "127.0.0.1", "--port", str(port), "--workers", str(processes)]
    command += ["--log-level", "info", "--no-access-log"]  # info: worker restarts are logged
    with launched(command, env, log) as process:
        server = Server(process, port, children=True, worker=worker)
        wait_healthy(server, log)
        yield server


@contextmanager
def postgres_database(admin_url: str) -> Iterator[str]:
    """A fresh database ``dcseg_bench_<random>`` (dropped afterwards); yields its URL."""
    import psycopg
    from sqlalchemy.engine import make_url

    admin = make_url(admin_url)
    name = f"dcseg_bench_{uuid.uuid4().hex[:12]}"
    dsn = admin.set(drivername="postgresql").render_as_string(hide_password=False)
    with psycopg.connect(dsn, autocommit=True) as conn:
        conn.execute(f'CREATE DATABASE "{name}"')
    try:
        yield admin.set(database=name).render_as_string(hide_password=False)
    finally:
        with psycopg.connect(dsn, autocommit=True) as conn:
            conn.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')


@contextmanager
def redis_database(base_url: str, candidates: list[int]) -> Iterator[str]:
    """The first empty Redis database of ``candidates`` (flushed afterwards); yields its URL."""
    import redis

    for db in candidates:
        client = redis.Redis.from_url(f"{base_url}/{db}")
        if client.dbsize() == 0:
            break
        client.close()
    else:
        raise RuntimeError(f"no empty Redis database among {candidates} at {base_url}")
    try:
        yield f"{base_url}/{db}"
    finally:
        client.flushdb()
        client.close()


@contextmanager
def deployed_stack(
    root: Path, args: argparse.Namespace
) -> Iterator[tuple[dict[str, str], subprocess.Popen[bytes]]]:
    """PostgreSQL, Redis and one ``dcseg worker``; yields the API processes' environment and
    the worker process."""
    with ExitStack() as stack:
        database = stack.enter_context(postgres_database(args.postgres_admin_url))
        broker = stack.enter_context(redis_database(args.redis_url, args.redis_dbs))
        env = service_env(
            root,
            DCSEG_DATABASE_URL=database,
            DCSEG_BROKER_URL=broker,
            DCSEG_RATE_LIMIT_URL=broker,
        )
        if args.storage == "s3":
            env |= object_storage(stack, root)
        worker = [sys.executable, "-m", "dcseg", "worker", "--pool", "solo", "--loglevel"]
        process = stack.enter_context(launched([*worker, "warning"], env, root / "worker.log"))
        yield env, process


def object_storage(stack: ExitStack, root: Path) -> dict[str, str]:
    """A SeaweedFS S3 server (``weed``, from the dev extras) for ``--storage s3``: the
    environment of S3 storage in a new bucket, presigned URLs valid for the whole run."""
    from tests.s3server import new_bucket, weed_server

    (root / "s3").mkdir()
    server = stack.enter_context(weed_server(root / "s3"))
    return server.env(new_bucket()) | {
        "DCSEG_PRESIGN_EXPIRY_S": "3600",
        "DCSEG_SCRATCH_DIR": str(root / "scratch"),
    }


# ----- load ------------------------------------------------------------------------------


def start_jobs(http: httpx.Client, archive: bytes, options: dict[str, Any], total: int) -> str:
    """Upload, create the job that runs, and ``total - 1`` canceled ones; the running job's id."""
    headers = {**HEADERS, "Content-Type": "application/x-tar"}
    upload = http.post("/v1/uploads", content=archive, headers=headers)
    upload.raise_for_status()
    body = {"upload_id": upload.json()["id"], "preset": "fast", "options": options}
    created = http.post("/v1/jobs", json=body, headers=HEADERS)
    created.raise_for_status()
    job_id: str = created.json()["id"]
    deadline = time.monotonic() + START_TIMEOUT_S
    while job_status(http, job_id)["status"] == "queued":
        if time.monotonic() > deadline:
            raise RuntimeError(f"the job did not start within {START_TIMEOUT_S} s")
        time.sleep(0.2)
    for _ in range(total - 1):
        other = http.post("/v1/jobs", json=body, headers=HEADERS)
        other.raise_for_status()
        http.post(f"/v1/jobs/{other.json()['id']}:cancel", headers=HEADERS).raise_for_status()
    return job_id


def job_status(http: httpx.Client, job_id: str) -> dict[str, Any]:
    response = http.get(f"/v1/jobs/{job_id}", headers=HEADERS)
    response.raise_for_status()
    job: dict[str, Any] = response.json()
    return {"status": job["status"], "stage": job["stage"], "progress": job["progress"]}


def largest_artifact(http: httpx.Client, job_id: str) -> dict[str, Any]:
    """The job's largest listed artifact; waits (bounded) until its first stage finished."""
    deadline = time.monotonic() + START_TIMEOUT_S
    while True:
        response = http.get(f"/v1/jobs/{job_id}/artifacts", headers=HEADERS)
        response.raise_for_status()
        listed: list[dict[str, Any]] = response.json()["artifacts"]
        if listed:
            return max(listed, key=lambda a: int(a["size"]))
        if time.monotonic() > deadline:
            raise RuntimeError(f"job {job_id} listed no artifact within {START_TIMEOUT_S} s")
        time.sleep(0.5)


async def _request(http: httpx.AsyncClient, target: Target) -> int:
    """One request; its status (0 = transport error)."""
    try:
        if not target.first_event:
            headers = HEADERS if target.auth else {}
            return (await http.get(target.path, headers=headers)).status_code
        async with http.stream("GET", target.path, headers=HEADERS) as response:
            if response.status_code == 200:
                async for line in response.aiter_lines():
                    if line.startswith("data:"):
                        return 200
                return 0  # the stream ended without an event
            return response.status_code
    except httpx.HTTPError:
        return 0


async def _client_loop(
    http: httpx.AsyncClient, pick: Pick, end: float, samples: dict[str, Samples]
) -> None:
    count = 0
    while time.perf_counter() < end:
        target = pick(count)
        count += 1
        record = samples.setdefault(target.label, Samples())
        start = time.perf_counter()
        status = await _request(http, target)
        record.latencies.append(time.perf_counter() - start)
        record.statuses[status] = record.statuses.get(status, 0) + 1
        if status != 200:
            record.errors += 1


async def _hammer(base_url: str, pick: Pick, clients: int, duration: float) -> dict[str, Samples]:
    samples: dict[str, Samples] = {}
    limits = httpx.Limits(max_connections=clients, max_keepalive_connections=clients)
    async with httpx.AsyncClient(base_url=base_url, limits=limits, timeout=30) as http:
        for i in range(clients):  # warm up: open every connection once
            await _request(http, pick(i))
        end = time.perf_counter() + duration
        tasks = [_client_loop(http, pick, end, samples) for _ in range(clients)]
        await asyncio.gather(*tasks)
    return samples


def endpoint_numbers(s: Samples, elapsed: float) -> dict[str, Any]:
    return {
        "requests": len(s.latencies),
        "requests_per_s": len(s.latencies) / elapsed,
        "p50_ms": 1000 * percentile(s.latencies, 50),
        "p99_ms": 1000 * percentile(s.latencies, 99),
        "mean_ms": 1000 * statistics.fmean(s.latencies) if s.latencies else float("nan"),
        "errors": s.errors,
        "statuses": {str(k): v for k, v in sorted(s.statuses.items())},
    }


def run_phase(
    name: str, server: Server, pick: Pick, clients: int, duration: float
) -> dict[str, Any]:
    """``clients`` concurrent clients for ``duration`` s; per-endpoint numbers and API CPU."""
    pids = server.api_pids()
    cpu_before, own_before = total_cpu_s(pids), time.process_time()
    started = time.perf_counter()
    samples = asyncio.run(_hammer(server.base_url, pick, clients, duration))
    elapsed = time.perf_counter() - started
    cpu_after, own_after = total_cpu_s(pids), time.process_time()
    total = sum(len(s.latencies) for s in samples.values())
    endpoints = {label: endpoint_numbers(s, elapsed) for label, s in sorted(samples.items())}
    server_cpu = None if cpu_before is None or cpu_after is None else cpu_after - cpu_before
    return {
        "phase": name,
        "seconds": elapsed,
        "requests": total,
        "requests_per_s": total / elapsed,
        "errors": sum(s.errors for s in samples.values()),
        "api_processes": len(pids) - 1 if server.children else 1,
        "api_pids": pids,
        "api_cpu_s": server_cpu,
        "api_cpu_ms_per_request": None if server_cpu is None else 1000 * server_cpu / total,
        "client_cpu_s": own_after - own_before,
        "endpoints": endpoints,
    }


def phase_picks(job_id: str, artifact: dict[str, Any]) -> dict[str, Pick]:
    """What each phase requests."""
    job_path, list_path = f"/v1/jobs/{job_id}", "/v1/jobs?page_size=20"
    health = Target("GET /healthz", "/healthz")
    poll = Target("GET /v1/jobs/{id}", job_path)
    listing = Target("GET /v1/jobs", list_path)
    events = Target("GET /v1/jobs/{id}/events", f"{job_path}/events", first_event=True)
    download = Target("GET /v1/jobs/{id}/artifacts/{name}", str(artifact["url"]))
    picks: dict[str, Pick] = {
        "healthz": lambda i: health,
        "api": lambda i: listing if i % LIST_EVERY == LIST_EVERY - 1 else poll,
        "events": lambda i: events,
        "artifacts": lambda i: download,
    }
    if artifact.get("download_url"):  # object storage: the same file, straight from the store
        direct = Target("GET presigned download_url", str(artifact["download_url"]), auth=False)
        picks["artifacts_presigned"] = lambda i: direct
    return picks


def load_phases(server: Server, args: argparse.Namespace, archive: bytes) -> dict[str, Any]:
    """Start the jobs, run every phase while the job runs, then cancel it."""
    # long enough to keep the worker busy for the whole benchmark
    options = {"reconstruct": {"iterations": 3000}, "affinity": {"iterations": 3000}}
    with httpx.Client(base_url=server.base_url, timeout=30) as http:
        job_id = start_jobs(http, archive, options, args.list_jobs)
        artifact = largest_artifact(http, job_id)
        listed = http.get("/v1/jobs?page_size=20", headers=HEADERS).json()["jobs"]
        job_before, job_pids = job_status(http, job_id), server.job_pids()
        job_cpu_before = total_cpu_s(job_pids)
        phases = [
            run_phase(name, server, pick, args.clients, args.duration)
            for name, pick in phase_picks(job_id, artifact).items()
        ]
        job_after, job_cpu_after = job_status(http, job_id), total_cpu_s(job_pids)
        http.post(f"/v1/jobs/{job_id}:cancel", headers=HEADERS)
    return {
        "job_id": job_id,
        "job_options": options,
        "jobs_listed": len(listed),
        "artifact": {k: artifact[k] for k in ("name", "size", "media_type")},
        "job_during_benchmark": {
            "before": job_before,
            "after": job_after,
            "worker_cpu_s": None
            if job_cpu_before is None or job_cpu_after is None
            else job_cpu_after - job_cpu_before,
        },
        "phases": phases,
    }


# ----- the shared rate limit ---------------------------------------------------------------


def _tcp_inode(local_port: int, remote_port: int) -> str | None:
    """The inode of the loopback TCP socket ``local_port -> remote_port`` (``/proc/net``)."""
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        try:
            lines = Path(table).read_text().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            cells = line.split()
            local, remote = int(cells[1].rsplit(":", 1)[1], 16), int(cells[2].rsplit(":", 1)[1], 16)
            if local == local_port and remote == remote_port:
                return cells[9]
    return None


def _pid_holding(inode: str, pids: list[int]) -> int | None:
    target = f"socket:[{inode}]"
    for pid in pids:
        try:
            descriptors = list(Path(f"/proc/{pid}/fd").iterdir())
        except OSError:
            continue
        for descriptor in descriptors:
            try:
                if os.readlink(descriptor) == target:
                    return pid
            except OSError:
                continue
    return None


def poll_on_new_connection(server: Server, path: str, pids: list[int]) -> tuple[int, int | None]:
    """One ``GET`` on a fresh connection: ``(status, pid of the API process that served it)``."""
    conn = http.client.HTTPConnection("127.0.0.1", server.port, timeout=30)
    try:
        conn.request("GET", path, headers=HEADERS)
        response = conn.getresponse()
        response.read()
        assert conn.sock is not None
        inode = _tcp_inode(server.port, conn.sock.getsockname()[1])  # still open: keep-alive
        return response.status, None if inode is None else _pid_holding(inode, pids)
    finally:
        conn.close()


def wait_for_fresh_minute(needed_s: float) -> None:
    """Sleep to the next clock minute unless ``needed_s`` seconds are left in this one (the
    in-process limiter counts per clock minute)."""
    left = 60.0 - time.time() % 60.0
    if left < needed_s:
        time.sleep(left + 0.5)


def rate_limit_check(server: Server, job_id: str, limit: int, burst: int) -> dict[str, Any]:
    """``burst`` polls on new connections within one minute; who answered and who admitted."""
    pids = child_pids(server.process.pid)
    wait_for_fresh_minute(20.0)
    per_process: dict[str, dict[str, int]] = {}
    for _ in range(burst):
        status, pid = poll_on_new_connection(server, f"/v1/jobs/{job_id}", pids)
        counts = per_process.setdefault(str(pid), {"requests": 0, "admitted": 0, "limited": 0})
        outcome = {200: "admitted", 429: "limited"}.get(status, "other")
        counts["requests"] += 1
        counts[outcome] = counts.get(outcome, 0) + 1
    admitted = sum(c["admitted"] for c in per_process.values())
    served_by = [p for p, c in per_process.items() if p != "None" and c["requests"] > limit]
    return {
        "rate_limit_per_minute": limit,
        "requests": burst,
        "admitted": admitted,
        "limited": sum(c["limited"] for c in per_process.values()),
        "api_processes": len(pids),
        "per_process": per_process,
        "shared": admitted <= limit,
        "conclusive": len(served_by) >= 2,
        "rate_limit_url_setting_present": rate_limit_url_known(),
    }


def rate_limit_url_known() -> bool:
    """Whether the service's settings have ``rate_limit_url`` (else the variable is ignored)."""
    from jobstore.settings import Settings

    return "rate_limit_url" in Settings.model_fields


# ----- report ----------------------------------------------------------------------------


def machine() -> dict[str, Any]:
    model = platform.processor()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    packages = ("fastapi", "uvicorn", "starlette", "httpx", "SQLAlchemy", "pydantic")
    return {
        "platform": platform.platform(),
        "python": platform.python_version(),
        "cpu": model,
        "cpu_count": os.cpu_count(),
        "versions": {name: version(name) for name in packages},
    }


def overhead(healthz: dict[str, Any], api: dict[str, Any], label: str) -> dict[str, Any]:
    """How much more a job poll costs than the bare endpoint."""
    bare = healthz["endpoints"]["GET /healthz"]
    poll = api["endpoints"][label]
    cpu_bare, cpu_api = healthz["api_cpu_ms_per_request"], api["api_cpu_ms_per_request"]
    return {
        "p50_ms": poll["p50_ms"] - bare["p50_ms"],
        "mean_ms": poll["mean_ms"] - bare["mean_ms"],
        "server_ms_per_request": 1000 / api["requests_per_s"] - 1000 / healthz["requests_per_s"],
        "api_cpu_ms_per_request": None if cpu_bare is None else cpu_api - cpu_bare,
    }


def print_table(result: dict[str, Any]) -> None:
    header = ("phase", "endpoint", "requests", "req/s", "p50 ms", "p99 ms", "errors", "API CPU ms")
    rows = [header]
    for phase in result["phases"]:
        cpu = phase["api_cpu_ms_per_request"]
        for label, e in phase["endpoints"].items():
            rows.append(
                (
                    phase["phase"],
                    label,
                    str(e["requests"]),
                    f"{e['requests_per_s']:.0f}",
                    f"{e['p50_ms']:.1f}",
                    f"{e['p99_ms']:.1f}",
                    str(e["errors"]),
                    "-" if cpu is None else f"{cpu:.2f}",
                )
            )
    widths = [max(len(row[i]) for row in rows) for i in range(len(header))]
    for row in rows:
        print("  ".join(cell.ljust(width) for cell, width in zip(row, widths, strict=True)))
    extra = result["overhead_per_poll"]
    print(
        f"overhead of GET /v1/jobs/{{id}} over GET /healthz: p50 +{extra['p50_ms']:.1f} ms, "
        f"server time +{extra['server_ms_per_request']:.2f} ms/request, "
        f"API CPU +{extra['api_cpu_ms_per_request'] or float('nan'):.2f} ms/request"
    )
    check = result.get("rate_limit_check")
    if check is not None:
        print(
            f"rate limit {check['rate_limit_per_minute']}/min over {check['api_processes']} "
            f"processes: {check['admitted']} of {check['requests']} admitted "
            f"(shared: {check['shared']}, conclusive: {check['conclusive']}); "
            f"per process {check['per_process']}"
        )


def print_logs(root: Path, lines: int = 40) -> None:
    """The end of every process log (they live in the temporary folder, removed on exit)."""
    for log in sorted(root.glob("*.log")):
        tail = log.read_text(encoding="utf-8", errors="replace").splitlines()[-lines:]
        print(f"----- {log.name} (last {lines} lines)", *tail, sep="\n", file=sys.stderr)


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--mode", choices=["embedded", "deployed"], default="embedded")
    parser.add_argument("--clients", type=int, default=16, help="concurrent clients (16)")
    parser.add_argument("--duration", type=float, default=20.0, help="seconds per phase (20)")
    parser.add_argument("--frames", type=int, default=8, help="frames of the synthetic scene")
    parser.add_argument("--size", default="96x72", help="size of the synthetic scene")
    parser.add_argument("--list-jobs", type=int, default=20, help="jobs in the listing (20)")
    parser.add_argument("--api-processes", type=int, default=2, help="deployed: uvicorn workers")
    parser.add_argument(
        "--postgres-admin-url",
        default="postgresql+psycopg://postgres@127.0.0.1:5432/test",
        help="deployed: a database to connect to for CREATE/DROP DATABASE",
    )
    parser.add_argument("--redis-url", default="redis://127.0.0.1:6379", help="deployed: Redis")
    parser.add_argument(
        "--redis-dbs",
        type=lambda text: [int(x) for x in text.split(",")],
        default=list(range(14, 0, -1)),
        help="deployed: Redis databases to choose an empty one from (14..1)",
    )
    parser.add_argument(
        "--storage",
        choices=["local", "s3"],
        default="local",
        help="deployed: local storage or a SeaweedFS S3 server (adds the presigned phase)",
    )
    parser.add_argument("--rate-limit", type=int, default=10, help="deployed: limit to check")
    parser.add_argument("--rate-burst", type=int, default=30, help="deployed: requests sent")
    parser.add_argument("--out", type=Path, help="write the results as JSON here")
    return parser.parse_args(argv)


def run_embedded(root: Path, args: argparse.Namespace, archive: bytes) -> dict[str, Any]:
    with embedded_api(root, free_port()) as server:
        return load_phases(server, args, archive) | {
            "mode": "dcseg serve, embedded worker process, SQLite, one API process"
        }


def run_deployed(root: Path, args: argparse.Namespace, archive: bytes) -> dict[str, Any]:
    processes = args.api_processes
    with deployed_stack(root, args) as (env, worker):
        with uvicorn_api(env, free_port(), processes, root / "api.log", worker) as server:
            loaded = load_phases(server, args, archive)
        limited_env = env | {"DCSEG_RATE_LIMIT_PER_MINUTE": str(args.rate_limit)}
        with uvicorn_api(limited_env, free_port(), processes, root / "api-limited.log") as server:
            check = rate_limit_check(server, loaded["job_id"], args.rate_limit, args.rate_burst)
    mode = (
        f"uvicorn --workers {processes} (service.main:create_app --factory) behind one port, "
        "PostgreSQL, Redis broker, one separate `dcseg worker --pool solo`"
    )
    if args.storage == "s3":
        mode += ", S3 storage (SeaweedFS `weed server -s3` on this machine), worker scratch"
    return loaded | {"mode": mode, "rate_limit_check": check}


def main(argv: list[str] | None = None) -> dict[str, Any]:
    args = parse_args(argv)
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory(prefix="bench-service-") as tmp:
        root = Path(tmp)
        archive = scene_tar(root / "scene", args.frames, args.size)
        run = run_deployed if args.mode == "deployed" else run_embedded
        try:
            measured = run(root, args, archive)
        except Exception:
            print_logs(root)
            raise
    phases = measured.pop("phases")
    result = {
        "benchmark": "service",
        "command": " ".join(["python benchmarks/bench_service.py", *(argv or sys.argv[1:])]),
        "config": {
            "mode": measured.pop("mode"),
            "clients": args.clients,
            "duration_s": args.duration,
            "scene": {"frames": args.frames, "size": args.size},
            "job_options": measured.pop("job_options"),
            "jobs_listed": measured.pop("jobs_listed"),
            "artifact_downloaded": measured.pop("artifact"),
            "list_every": LIST_EVERY,
            "rate_limit_per_minute": UNLIMITED,
            "access_log": False,
        },
        **measured,
        "phases": phases,
        "overhead_per_poll": overhead(phases[0], phases[1], "GET /v1/jobs/{id}"),
        "machine": machine()
        | {"load_average_before": load_before, "load_average_after": os.getloadavg()},
    }
    print_table(result)
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")
    return result


if __name__ == "__main__":
    main()
