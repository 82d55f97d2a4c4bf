"""The end-to-end steps of scripts/compose_test.sh against a running compose stack.

Runs jobs through the API with the project's client (upload a synthetic scan, follow, download,
check every file's SHA-256 against the listing), then the faults: a worker killed during
reconstruction, Redis and PostgreSQL restarted during a job, the API restarted while clients
follow a job. Prints each step and its time; exits 1 naming the failing step.

    python scripts/compose_e2e.py --api http://127.0.0.1:8000 --key KEY \
        --compose "docker-compose -p dcsegtest -f docker/compose.yaml" --work /tmp/e2e
"""

from __future__ import annotations

import argparse
import shlex
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from dcseg.client import Client
from dcseg.client.files import sha256_of
from dcseg.client.retry import RetryPolicy

JOB_TIMEOUT_S = 900.0
"""Longest wait for one job (the stack runs on the CPU; a job takes about a minute)."""

OPTIONS: dict[str, Any] = {"reconstruct": {"iterations": 300}, "affinity": {"iterations": 300}}
"""Job options on top of the ``fast`` preset: short training, the stack is what is tested."""


@dataclass
class Stack:
    """The compose project under test and the client that talks to its API."""

    client: Client
    compose: list[str]
    work: Path
    jobs: dict[str, str] = field(default_factory=dict)
    """Finished jobs by step name, checked again after the faults."""
    listings: dict[str, dict[str, str]] = field(default_factory=dict)
    """Each finished job's listed SHA-256 by path."""

    def container(self, service: str, index: int = 1) -> str:
        """The id of the ``index``-th container of a compose service."""
        out = run([*self.compose, "ps", "-q", service]).split()
        if len(out) < index:
            raise RuntimeError(f"service {service} has {len(out)} container(s), not {index}")
        return sorted(out)[index - 1]

    def sql(self, query: str) -> str:
        """One value from the stack's PostgreSQL (psql in its container)."""
        pg = self.container("postgres")
        return run(["docker", "exec", pg, "psql", "-U", "dcseg", "-d", "dcseg", "-tAc", query])


def say(text: str) -> None:
    sys.stdout.write(text + "\n")
    sys.stdout.flush()


def run(cmd: list[str], timeout: float = 300.0) -> str:
    """Run ``cmd``; its stdout, or RuntimeError with its stderr."""
    result = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, check=False)
    if result.returncode != 0:
        raise RuntimeError(f"{shlex.join(cmd)} exited {result.returncode}: {result.stderr[-2000:]}")
    return result.stdout.strip()


def submit(stack: Stack, upload_id: str) -> str:
    job = stack.client.submit(upload_id, preset="fast", options=OPTIONS or None)
    return str(job["id"])


def wait_until(what: str, check: Callable[[], bool], timeout: float = 300.0) -> None:
    """Poll ``check`` every half second until it holds; TimeoutError naming ``what``."""
    deadline = time.monotonic() + timeout
    while not check():
        if time.monotonic() > deadline:
            raise TimeoutError(f"{what}: not after {timeout:.0f} s")
        time.sleep(0.5)


def in_stage(stack: Stack, job_id: str, stage: str) -> Callable[[], bool]:
    def check() -> bool:
        job = stack.client.status(job_id)
        if job["status"] in {"failed", "canceled", "succeeded"}:
            raise RuntimeError(f"job {job_id} ended ({job['status']}) before stage {stage} ran")
        return job["status"] == "running" and job.get("stage") == stage

    return check


def download_and_check(stack: Stack, name: str, job_id: str) -> int:
    """Download every listed file of ``job_id``; compare each SHA-256 with the listing (and
    with the listing of an earlier download of the same job). Returns the file count."""
    listing = {item["name"]: item["sha256"] for item in stack.client.artifacts(job_id)}
    if not listing:
        raise RuntimeError(f"job {job_id} lists no artifacts")
    dest = stack.work / f"download-{name}-{time.monotonic_ns()}"
    paths = stack.client.download(job_id, dest, everything=True)
    got = {p.relative_to(dest).as_posix(): sha256_of(p) for p in paths}
    wrong = sorted(p for p in listing if got.get(p) != listing[p])
    if wrong or len(got) != len(listing):
        raise RuntimeError(f"job {job_id}: {len(wrong)} file(s) differ from the listing: {wrong}")
    before = stack.listings.setdefault(name, listing)
    if before != listing:
        raise RuntimeError(f"job {job_id}: the listing changed since the first download")
    return len(listing)


def step_capture(stack: Stack) -> str:
    """A synthetic 8-frame 160x120 scan, uploaded; returns the upload id."""
    scan = stack.work / "scan"
    run([sys.executable, "-m", "dcseg", "synth", str(scan), "--frames", "8", "--size", "160x120"])
    upload = stack.client.upload(scan, idempotency_key="compose-test-scan")
    return str(upload["id"])


def step_job(stack: Stack, upload_id: str) -> None:
    """One job end to end: follow its event stream, download, check, one export."""
    job_id = submit(stack, upload_id)
    events: list[str] = []
    stack.client.follow(job_id, on_event=lambda e: events.append(e.type), timeout=JOB_TIMEOUT_S)
    count = download_and_check(stack, "job", job_id)
    files = stack.client.download_export(job_id, "glb", stack.work / "glb")
    glbs = [p for p in files if p.suffix == ".glb"]
    if not glbs or any(p.read_bytes()[:4] != b"glTF" for p in glbs):
        raise RuntimeError(f"the glb export of job {job_id} holds no GLB file: {files}")
    stack.jobs["job"] = job_id
    say(f"  job {job_id}: {len(events)} events, {count} files checked, glb export ok")


def step_kill_worker(stack: Stack, upload_id: str) -> None:
    """``docker kill`` the worker running a job's reconstruction; the other finishes it."""
    job_id = submit(stack, upload_id)
    wait_until(f"job {job_id} reconstructing", in_stage(stack, job_id, "reconstruct"))
    host = stack.sql(f"select split_part(worker, ':', 1) from jobs where id = '{job_id}'")
    victim = next(c for c in run(["docker", "ps", "-q", "--no-trunc"]).split() if c[:12] == host)
    run(["docker", "kill", victim])
    say(f"  killed worker {host} during reconstruct of job {job_id}")
    stack.client.follow(job_id, timeout=JOB_TIMEOUT_S)
    after = stack.sql(f"select split_part(worker, ':', 1) from jobs where id = '{job_id}'")
    if after == host:
        raise RuntimeError(f"job {job_id} finished on the killed worker {host}")
    run(["docker", "start", victim])
    download_and_check(stack, "killed", job_id)
    stack.jobs["killed"] = job_id
    say(f"  job {job_id} finished on {after}; worker {host} started again")


def step_restart_stores(stack: Stack, upload_id: str) -> None:
    """Restart Redis, then PostgreSQL, during a job; it must end (succeeded or failed with a
    reason), never hang."""
    job_id = submit(stack, upload_id)
    wait_until(f"job {job_id} running", in_stage(stack, job_id, "reconstruct"))
    for service in ("redis", "postgres"):
        run(["docker", "restart", stack.container(service)])
        say(f"  restarted {service} during job {job_id}")
    status = ended(stack, job_id)
    if status["status"] == "succeeded":
        download_and_check(stack, "stores", job_id)
        stack.jobs["stores"] = job_id
    elif not status.get("error"):
        raise RuntimeError(f"job {job_id} {status['status']} without a reason")
    say(f"  job {job_id}: {status['status']} {status.get('error') or ''}".rstrip())


def step_restart_api(stack: Stack, upload_id: str) -> None:
    """Restart the API while a client follows a job and another polls; both carry on."""
    job_id = submit(stack, upload_id)
    wait_until(f"job {job_id} running", in_stage(stack, job_id, "reconstruct"))
    outcome: dict[str, Any] = {}

    def follow() -> None:
        try:
            outcome["job"] = stack.client.follow(job_id, timeout=JOB_TIMEOUT_S)
        except Exception as error:  # reported by the step
            outcome["error"] = error

    thread = threading.Thread(target=follow, daemon=True)
    thread.start()
    time.sleep(1.0)
    run(["docker", "restart", stack.container("api")])
    say(f"  restarted the API while following job {job_id}")
    for name in stack.jobs:  # idempotent calls retried across the restart
        stack.client.status(stack.jobs[name])
    thread.join(JOB_TIMEOUT_S)
    if thread.is_alive() or "error" in outcome:
        raise RuntimeError(f"following job {job_id} across the restart: {outcome.get('error')}")
    download_and_check(stack, "api", job_id)
    stack.jobs["api"] = job_id


def step_nothing_lost(stack: Stack, _: str) -> None:
    """Every finished job is still there, succeeded, with the same files."""
    for name, job_id in stack.jobs.items():
        if stack.client.status(job_id)["status"] != "succeeded":
            raise RuntimeError(f"job {job_id} ({name}) is no longer succeeded")
        download_and_check(stack, name, job_id)
    say(f"  {len(stack.jobs)} jobs still succeeded with their files")


def ended(stack: Stack, job_id: str) -> dict[str, Any]:
    """The job once it is terminal (polling; JOB_TIMEOUT_S)."""
    result: dict[str, Any] = {}

    def done() -> bool:
        result.update(stack.client.status(job_id))
        return result["status"] in {"succeeded", "failed", "canceled"}

    wait_until(f"job {job_id} ended", done, JOB_TIMEOUT_S)
    return result


STEPS: list[tuple[str, Callable[[Stack, str], None]]] = [
    ("job end to end", step_job),
    ("worker killed during reconstruction", step_kill_worker),
    ("redis and postgres restarted during a job", step_restart_stores),
    ("api restarted while clients follow a job", step_restart_api),
    ("nothing lost", step_nothing_lost),
]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--api", required=True)
    parser.add_argument("--key", required=True)
    parser.add_argument("--compose", required=True, help="the compose command, as one string")
    parser.add_argument("--work", type=Path, required=True)
    args = parser.parse_args(argv)
    retry = RetryPolicy(attempts=40, total_s=240.0, max_backoff_s=5.0)
    with Client(args.api, api_key=args.key, retry=retry) as client:
        stack = Stack(client, shlex.split(args.compose), args.work)
        name = "upload a synthetic scan"
        try:
            start = time.monotonic()
            upload_id = step_capture(stack)
            say(f"compose-test: {name}: ok ({time.monotonic() - start:.0f} s)")
            for name, step in STEPS:
                start = time.monotonic()
                step(stack, upload_id)
                say(f"compose-test: {name}: ok ({time.monotonic() - start:.0f} s)")
        except Exception as error:
            say(f"compose-test: FAILED at '{name}': {type(error).__name__}: {error}")
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
