"""Load benchmark of the REST API while a job really runs (run by hand).

    python benchmarks/bench_service.py --out benchmarks/results/service.json

Starts ``dcseg serve`` (embedded mode: the API process plus its local worker process) on a
free port with its own temporary storage folder and SQLite database, uploads a small
``dcseg synth`` scene, creates a job that runs in the embedded worker for the whole benchmark,
and adds ``--list-jobs - 1`` canceled jobs so that ``GET /v1/jobs`` returns a full page. Then,
for ``--duration`` seconds each, ``--clients`` concurrent ``httpx.AsyncClient`` tasks

1. hammer the bare ``GET /healthz`` (no auth, no database), then
2. poll ``GET /v1/jobs/{id}`` and, every fifth request, list ``GET /v1/jobs?page_size=20``
   (bearer auth, rate limiter, database read, JSON and ETag),

and report requests/s, p50/p99 latency, errors and the API process's CPU time per request
(``/proc/<pid>/stat``). The difference between the phases is the API's overhead per poll.
The per-tenant rate limit is set to 10^9 requests/minute (``DCSEG_RATE_LIMIT_PER_MINUTE``) and
the job cap to 1000 so that neither answers 429 and distorts the numbers; uvicorn's access log
is off (``--log-level warning``). Clients, API and worker share the machine's cores.
"""

from __future__ import annotations

import argparse
import asyncio
import io
import json
import os
import platform
import socket
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from importlib.metadata import version
from pathlib import Path
from typing import Any

import httpx

API_KEY = "bench-key-0123456789"
HEADERS = {"Authorization": f"Bearer {API_KEY}"}
LIST_EVERY = 5
"""In the API phase, every fifth request of a client lists jobs; the others poll the job."""

Pick = Callable[[int], tuple[str, str]]
"""Request number of a client -> (endpoint label, path)."""


@dataclass
class Samples:
    """Latencies (seconds) and error count of one endpoint in one phase."""

    latencies: list[float] = field(default_factory=list)
    errors: int = 0
    statuses: dict[int, int] = field(default_factory=dict)


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


def scene_tar(folder: Path, frames: int, size: str) -> bytes:
    """A ``dcseg synth`` scene (capture, masks, vocabulary, ground truth) as a tar archive."""
    command = [sys.executable, "-m", "dcseg", "synth", str(folder), "--frames", str(frames)]
    subprocess.run([*command, "--size", size], check=True, capture_output=True)
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w") as archive:
        for path in sorted(folder.rglob("*")):
            archive.add(path, arcname=path.relative_to(folder).as_posix(), recursive=False)
    return buffer.getvalue()


@contextmanager
def serve(root: Path, port: int) -> Iterator[subprocess.Popen[bytes]]:
    """``dcseg serve`` in embedded mode on ``port`` with storage and SQLite under ``root``."""
    env = {
        **os.environ,
        "OMP_WAIT_POLICY": os.environ.get("OMP_WAIT_POLICY", "PASSIVE"),
        "DCSEG_STORAGE_DIR": str(root / "data"),
        "DCSEG_API_KEYS": f"bench:{API_KEY}",
        "DCSEG_RATE_LIMIT_PER_MINUTE": str(10**9),
        "DCSEG_MAX_RUNNING_JOBS_PER_TENANT": "1000",
        "DCSEG_DEVICE": "cpu",
    }
    env.pop("DCSEG_BROKER_URL", None)
    env.pop("DCSEG_DATABASE_URL", None)
    command = [sys.executable, "-m", "dcseg", "serve", "--port", str(port)]
    log = (root / "serve.log").open("wb")
    process = subprocess.Popen(
        [*command, "--log-level", "warning"], env=env, stdout=log, stderr=subprocess.STDOUT
    )
    try:
        deadline = time.monotonic() + 60
        while True:
            try:
                if httpx.get(f"http://127.0.0.1:{port}/healthz", timeout=2).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            if process.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"dcseg serve did not start; see {root / 'serve.log'}")
            time.sleep(0.2)
        yield process
    finally:
        process.terminate()
        try:
            process.wait(30)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(10)
        log.close()


def start_jobs(http: httpx.Client, archive: bytes, options: dict[str, Any], total: int) -> str:
    """Upload, create the job that runs, and ``total - 1`` canceled ones; the running job's id."""
    headers = {**HEADERS, "Content-Type": "application/x-tar"}
    upload = http.post("/v1/uploads", content=archive, headers=headers)
    upload.raise_for_status()
    body = {"upload_id": upload.json()["id"], "preset": "fast", "options": options}
    created = http.post("/v1/jobs", json=body, headers=HEADERS)
    created.raise_for_status()
    job_id: str = created.json()["id"]
    deadline = time.monotonic() + 60
    while job_status(http, job_id)["status"] == "queued":
        if time.monotonic() > deadline:
            raise RuntimeError("the job did not start within 60 s")
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


async def _client_loop(
    http: httpx.AsyncClient, pick: Pick, end: float, samples: dict[str, Samples]
) -> None:
    count = 0
    while time.perf_counter() < end:
        label, path = pick(count)
        count += 1
        record = samples.setdefault(label, Samples())
        start = time.perf_counter()
        try:
            response = await http.get(path, headers=HEADERS)
            status = response.status_code
        except httpx.HTTPError:
            status = 0
        record.latencies.append(time.perf_counter() - start)
        record.statuses[status] = record.statuses.get(status, 0) + 1
        if status != 200:
            record.errors += 1


async def _hammer(base_url: str, pick: Pick, clients: int, duration: float) -> dict[str, Samples]:
    samples: dict[str, Samples] = {}
    limits = httpx.Limits(max_connections=clients, max_keepalive_connections=clients)
    async with httpx.AsyncClient(base_url=base_url, limits=limits, timeout=30) as http:
        for i in range(clients):  # warm up: open every connection once
            await http.get(pick(i)[1], headers=HEADERS)
        end = time.perf_counter() + duration
        tasks = [_client_loop(http, pick, end, samples) for _ in range(clients)]
        await asyncio.gather(*tasks)
    return samples


def run_phase(
    name: str, base_url: str, pick: Pick, clients: int, duration: float, server_pid: int
) -> dict[str, Any]:
    """``clients`` concurrent clients for ``duration`` s; per-endpoint numbers and server CPU."""
    cpu_before, own_before = process_cpu_s(server_pid), time.process_time()
    started = time.perf_counter()
    samples = asyncio.run(_hammer(base_url, pick, clients, duration))
    elapsed = time.perf_counter() - started
    cpu_after, own_after = process_cpu_s(server_pid), time.process_time()
    total = sum(len(s.latencies) for s in samples.values())
    endpoints = {
        label: {
            "requests": len(s.latencies),
            "requests_per_s": len(s.latencies) / elapsed,
            "p50_ms": 1000 * percentile(s.latencies, 50),
            "p99_ms": 1000 * percentile(s.latencies, 99),
            "mean_ms": 1000 * statistics.fmean(s.latencies) if s.latencies else float("nan"),
            "errors": s.errors,
            "statuses": {str(k): v for k, v in sorted(s.statuses.items())},
        }
        for label, s in sorted(samples.items())
    }
    server_cpu = None if cpu_before is None or cpu_after is None else cpu_after - cpu_before
    return {
        "phase": name,
        "seconds": elapsed,
        "requests": total,
        "requests_per_s": total / elapsed,
        "errors": sum(s.errors for s in samples.values()),
        "api_cpu_s": server_cpu,
        "api_cpu_ms_per_request": None if server_cpu is None else 1000 * server_cpu / total,
        "client_cpu_s": own_after - own_before,
        "endpoints": endpoints,
    }


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


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--clients", type=int, default=16, help="concurrent clients (16)")
    parser.add_argument("--duration", type=float, default=20.0, help="seconds per phase (20)")
    parser.add_argument("--frames", type=int, default=8, help="frames of the synthetic scene")
    parser.add_argument("--size", default="96x72", help="size of the synthetic scene")
    parser.add_argument("--list-jobs", type=int, default=20, help="jobs in the listing (20)")
    parser.add_argument("--out", type=Path, help="write the results as JSON here")
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    args = parse_args(argv)
    # long enough to keep the embedded worker busy for the whole benchmark
    options = {"reconstruct": {"iterations": 3000}, "affinity": {"iterations": 3000}}
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory(prefix="bench-service-") as tmp:
        root = Path(tmp)
        archive = scene_tar(root / "scene", args.frames, args.size)
        port = free_port()
        base_url = f"http://127.0.0.1:{port}"
        with serve(root, port) as server, httpx.Client(base_url=base_url, timeout=30) as http:
            job_id = start_jobs(http, archive, options, args.list_jobs)
            job_path, list_path = f"/v1/jobs/{job_id}", "/v1/jobs?page_size=20"
            listed = http.get(list_path, headers=HEADERS).json()["jobs"]
            job_before = job_status(http, job_id)

            def api(i: int) -> tuple[str, str]:
                if i % LIST_EVERY == LIST_EVERY - 1:
                    return "GET /v1/jobs", list_path
                return "GET /v1/jobs/{id}", job_path

            phases = [
                run_phase(
                    "healthz",
                    base_url,
                    lambda i: ("GET /healthz", "/healthz"),
                    args.clients,
                    args.duration,
                    server.pid,
                ),
                run_phase("api", base_url, api, args.clients, args.duration, server.pid),
            ]
            job_after = job_status(http, job_id)
            http.post(f"{job_path}:cancel", headers=HEADERS)
    result = {
        "benchmark": "service",
        "command": " ".join(["python benchmarks/bench_service.py", *(argv or sys.argv[1:])]),
        "config": {
            "clients": args.clients,
            "duration_s": args.duration,
            "scene": {"frames": args.frames, "size": args.size},
            "job_options": options,
            "jobs_listed": len(listed),
            "list_every": LIST_EVERY,
            "mode": "dcseg serve, embedded worker process, SQLite, one API process",
            "rate_limit_per_minute": 10**9,
            "access_log": False,
        },
        "job_during_benchmark": {"before": job_before, "after": job_after},
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
