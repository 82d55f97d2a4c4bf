"""A real HTTP server (uvicorn in a thread) over the service app, behind an ASGI middleware
that injects faults: answers 503/429 with ``Retry-After``, drops connections mid-body, and a
restart of the server. The client tests run against it as against a deployed service."""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
import pytest
import uvicorn
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from service.main import create_app
from tests.service.conftest import AUTH_A, TAR, free_port, make_settings, wait_for
from tests.worker.fakes import FakeStage
from worker.execute import execute_job


class Dropped(Exception):
    """Raised inside the app to make uvicorn close the connection mid-response."""


@dataclass
class Fault:
    """One planned fault on requests whose path contains ``path`` (and of ``method``)."""

    path: str
    kind: str
    """``status`` (answer ``status`` with ``headers``, the app not called), ``drop`` (send the
    response's first ``after`` body bytes, then close the connection), ``ignore-range`` (the
    app sees no ``Range`` header: a whole 200 answer)."""
    status: int = 503
    headers: dict[str, str] = field(default_factory=dict)
    after: int = 0
    method: str = "GET"
    times: int = 1
    then: Callable[[], None] | None = None
    """Runs in a thread when the fault fires (e.g. restarting the server)."""
    pause_s: float = 0.0
    """A ``drop`` waits this long before closing (a restart begun by ``then`` has closed the
    listening socket by then, so the client's next try finds the server down)."""


@dataclass
class Faults:
    """The ASGI middleware; ``plan`` holds the faults still to fire, ``seen`` every request
    as ``(method, path, headers)``."""

    app: ASGIApp
    plan: list[Fault] = field(default_factory=list)
    seen: list[tuple[str, str, dict[str, str]]] = field(default_factory=list)

    def _take(self, scope: Scope) -> Fault | None:
        for fault in self.plan:
            if fault.path in scope["path"] and scope["method"] == fault.method:
                fault.times -= 1
                if fault.times <= 0:
                    self.plan.remove(fault)
                if fault.then is not None:
                    threading.Thread(target=fault.then, daemon=True).start()
                return fault
        return None

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = {k.decode().lower(): v.decode() for k, v in scope["headers"]}
        self.seen.append((scope["method"], scope["path"], headers))
        fault = self._take(scope)
        if fault is None:
            await self.app(scope, receive, send)
        elif fault.kind == "status":
            await _answer(send, fault.status, fault.headers)
        elif fault.kind == "ignore-range":
            kept = [(k, v) for k, v in scope["headers"] if k.lower() != b"range"]
            await self.app({**scope, "headers": kept}, receive, send)
        else:
            await self.app(scope, receive, _dropping(send, fault.after, fault.pause_s))


async def _answer(send: Send, status: int, headers: dict[str, str]) -> None:
    body = b'{"type": "about:blank", "title": "injected", "status": %d}' % status
    raw = [(k.lower().encode(), v.encode()) for k, v in headers.items()]
    raw.append((b"content-type", b"application/problem+json"))
    await send({"type": "http.response.start", "status": status, "headers": raw})
    await send({"type": "http.response.body", "body": body})


def _dropping(send: Send, after: int, pause_s: float) -> Send:
    sent = 0

    async def wrapped(message: Message) -> None:
        nonlocal sent
        if message["type"] == "http.response.body":
            body = message.get("body", b"")
            if sent + len(body) >= after:
                await send({**message, "body": body[: after - sent], "more_body": True})
                await asyncio.sleep(pause_s)
                raise Dropped(f"connection dropped after {after} bytes")
            sent += len(body)
        await send(message)

    return wrapped


class LiveServer:
    """uvicorn serving ``app`` on ``port`` in a thread; :meth:`restart` stops and starts it."""

    def __init__(self, app: Faults, port: int) -> None:
        self.app, self.port = app, port
        self.url = f"http://127.0.0.1:{port}"
        self.server: uvicorn.Server | None = None
        self.thread: threading.Thread | None = None
        self.restarts = 0

    def start(self) -> None:
        config = uvicorn.Config(self.app, host="127.0.0.1", port=self.port, log_level="critical")
        self.server = uvicorn.Server(config)
        self.thread = threading.Thread(target=self.server.run, daemon=True)
        self.thread.start()
        wait_for(lambda: self.server is not None and self.server.started, timeout=30)

    def stop(self) -> None:
        if self.server is not None and self.thread is not None:
            self.server.should_exit = True
            self.thread.join(30)
            self.server = self.thread = None

    def restart(self, down_s: float = 0.5) -> None:
        """Stop, stay down ``down_s`` (clients get connection errors), start again."""
        self.stop()
        self.restarts += 1
        time.sleep(down_s)
        self.start()


@pytest.fixture
def live_overrides() -> dict[str, Any]:
    """Settings of the :func:`live` server (a test module may define its own)."""
    return {}


@pytest.fixture
def live(tmp_path: Path, live_overrides: dict[str, Any]) -> Iterator[LiveServer]:
    settings = make_settings(tmp_path, **live_overrides)
    server = LiveServer(Faults(create_app(settings)), free_port())
    server.start()
    try:
        yield server
    finally:
        server.stop()


def queued_job(live: LiveServer, scene_tar: bytes) -> str:
    """A job created over HTTP (upload, then job), not yet run."""
    with httpx.Client(base_url=live.url, headers=AUTH_A) as http:
        upload = http.post("/v1/uploads", content=scene_tar, headers=TAR)
        assert upload.status_code == 201, upload.text
        job = http.post("/v1/jobs", json={"upload_id": upload.json()["id"]})
        assert job.status_code == 202, job.text
    job_id: str = job.json()["id"]
    return job_id


def execute(live: LiveServer, job_id: str, stages: list[Any]) -> str:
    """Run the job's ``stages`` (FakeStage) as the worker would; its final status."""
    state = live.app.app.state.dcseg  # type: ignore[attr-defined]
    return execute_job(job_id, state.store, state.settings, stages=stages, storage=state.storage)


def finished_job(live: LiveServer, scene_tar: bytes, stages: list[Any]) -> str:
    """A succeeded job whose ``stages`` (FakeStage) wrote their files, created over HTTP."""
    job_id = queued_job(live, scene_tar)
    assert execute(live, job_id, stages) == "succeeded"
    return job_id


def run_stages(blobs: dict[str, dict[str, bytes]]) -> list[FakeStage]:
    """FakeStages writing ``blobs`` (stage name -> files), one progress step each."""
    return [FakeStage(name, files=files, steps=1) for name, files in blobs.items()]
