"""Fixtures of the service tests: a tiny synthetic capture, archives of it, and a test client
on a fresh SQLite store with two tenants and no worker (jobs are driven by the tests)."""

from __future__ import annotations

import io
import shutil
import socket
import subprocess
import tarfile
import time
import warnings
import zipfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, Literal, cast

import httpx
import pytest

from jobstore.settings import Settings
from service.deps import AppState
from service.main import create_app

with warnings.catch_warnings():
    # starlette deprecates driving TestClient with httpx in favour of httpx2; same behaviour.
    warnings.filterwarnings("ignore", message=".*httpx2.*")
    from fastapi.testclient import TestClient as TestClient

KEY_A = "key-a-0123456789"
KEY_B = "key-b-0123456789"
AUTH_A = {"Authorization": f"Bearer {KEY_A}"}
AUTH_B = {"Authorization": f"Bearer {KEY_B}"}
TAR = {"Content-Type": "application/x-tar"}


@pytest.fixture(scope="session")
def scene(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 4-frame 64x48 synthetic capture with masks, vocabulary and ground truth."""
    from dcseg.cli import main

    out = tmp_path_factory.mktemp("synth") / "scene"
    assert main(["synth", str(out), "--frames", "4", "--size", "64x48"]) == 0
    return out


@pytest.fixture
def scene_copy(scene: Path, tmp_path: Path) -> Path:
    """A copy of the scene the test may damage."""
    return Path(shutil.copytree(scene, tmp_path / "scene"))


def tar_bytes(
    folder: Path,
    mode: Literal["w", "w:gz"] = "w",
    extra: Callable[[tarfile.TarFile], None] | None = None,
) -> bytes:
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode=mode) as tf:
        for path in sorted(folder.rglob("*")):
            tf.add(path, arcname=path.relative_to(folder).as_posix(), recursive=False)
        if extra is not None:
            extra(tf)
    return buffer.getvalue()


def zip_bytes(folder: Path, top: str = "") -> bytes:
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as zf:
        for path in sorted(folder.rglob("*")):
            if path.is_file():
                zf.write(path, top + path.relative_to(folder).as_posix())
    return buffer.getvalue()


@pytest.fixture(scope="session")
def scene_tar(scene: Path) -> bytes:
    return tar_bytes(scene)


def make_settings(root: Path, **overrides: Any) -> Settings:
    values: dict[str, Any] = {
        "storage_dir": root / "data",
        "database_url": None,
        "broker_url": None,
        "api_keys": f"tenant-a:{KEY_A},tenant-b:{KEY_B}",
        "embedded_worker": "off",
        "poll_interval_s": 0.05,
        "heartbeat_s": 0.2,
        "max_upload_bytes": 4 * 2**20,
    }
    values.update(overrides)
    if values["storage_dir"] is None:  # DCSEG_STORAGE_DIR or the default, as a server reads it
        del values["storage_dir"]
    # a loaded 2-core CI machine: let SQLite writers wait most of the stale-lease window
    values.setdefault("sqlite_busy_timeout_s", 2.5 * values["heartbeat_s"])
    return Settings(**values)


@pytest.fixture
def settings(tmp_path: Path) -> Settings:
    return make_settings(tmp_path)


StorageSettings = Callable[..., Settings]
"""``(**overrides) -> Settings`` of :func:`make_settings` in the storage folder under test."""


@pytest.fixture(params=["absolute", "relative"])
def storage_settings(
    request: pytest.FixtureRequest, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> StorageSettings:
    """Settings with the storage folder absolute (``tmp_path/data``) and, as a second run of
    the test, relative as a server started with ``DCSEG_STORAGE_DIR=dcseg-data`` (or the
    default ``./dcseg-data``) has it: resolved against the working directory, ``tmp_path``."""
    if request.param == "relative":
        monkeypatch.chdir(tmp_path)
        monkeypatch.setenv("DCSEG_STORAGE_DIR", "dcseg-data")

    def make(**overrides: Any) -> Settings:
        if request.param == "absolute":
            return make_settings(tmp_path, **overrides)
        settings = make_settings(tmp_path, storage_dir=None, **overrides)
        assert settings.storage_dir == Path("dcseg-data")  # relative, as given
        return settings

    return make


@pytest.fixture
def client(settings: Settings) -> Iterator[TestClient]:
    with TestClient(create_app(settings)) as test_client:
        yield test_client


@pytest.fixture
def make_client(tmp_path: Path) -> Iterator[Any]:
    """``make_client(**settings)``: a started TestClient with those setting overrides."""
    stack: list[TestClient] = []

    def make(**overrides: Any) -> TestClient:
        client = TestClient(create_app(make_settings(tmp_path, **overrides)))
        client.__enter__()
        stack.append(client)
        return client

    yield make
    for client in reversed(stack):
        client.__exit__(None, None, None)


@pytest.fixture
def upload_id(client: TestClient, scene_tar: bytes) -> str:
    response = client.post("/v1/uploads", content=scene_tar, headers={**AUTH_A, **TAR})
    assert response.status_code == 201, response.text
    upload: str = response.json()["id"]
    return upload


def assert_problem(response: Any, status: int) -> dict[str, Any]:
    """The response is an RFC 9457 problem with ``status``; returns its body."""
    assert response.status_code == status, response.text
    assert response.headers["content-type"].startswith("application/problem+json")
    body: dict[str, Any] = response.json()
    assert body["status"] == status
    assert {"type", "title", "detail", "instance"} <= set(body)
    return body


def wait_for(predicate: Callable[[], Any], timeout: float = 60.0, every: float = 0.05) -> Any:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(every)
    raise AssertionError(f"condition not met within {timeout} s")


def reachable(host: str, port: int) -> bool:
    """Whether a TCP connection to ``host:port`` opens within 2 s (a service is listening)."""
    try:
        with socket.create_connection((host, port), 2):
            return True
    except OSError:
        return False


def free_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def stop_process(process: subprocess.Popen[Any], sig: int, grace: float) -> None:
    """Send ``sig``; kill the process if it has not exited after ``grace`` seconds."""
    process.send_signal(sig)
    try:
        process.wait(grace)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait(5)


def state_of(client: Any) -> AppState:
    """The running app's state (store, queue, settings) behind a TestClient."""
    return cast(AppState, client.app.state.dcseg)


def wait_ready(client: Any, server: subprocess.Popen[Any], log: Path | None = None) -> None:
    """Wait until a server subprocess answers ``/readyz`` with 200 (fails if it exits)."""

    def ready() -> bool:
        assert server.poll() is None, log.read_text() if log is not None else "server exited"
        try:
            return bool(client.get("/readyz").status_code == 200)
        except httpx.TransportError:
            return False

    wait_for(ready, timeout=60, every=0.1)
