"""A Python SDK generated from ``openapi/openapi.json`` runs a job against a live server.

``openapi-python-client`` (pinned in the dev extra) generates the client into ``tmp_path``;
the test imports it and, through it only, uploads a capture, creates a job, polls it while
fake stages run it to the end, lists and downloads its artifacts, reads its events into the
generated event models and reads a problem. So the document's operationIds, models, enums and
``Problem`` are what SDK users get.

Skipped only when the generator is not installed, and never under CI (CI installs the dev
extras, so a missing generator fails there).
"""

from __future__ import annotations

import importlib
import io
import os
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest

from service.openapi import DEFAULT_PATH
from tests.service.conftest import KEY_A, zip_bytes
from tests.service.live import LiveServer, execute, live, live_overrides, run_stages
from tests.service.test_openapi_document import sse_events

__all__ = ["live", "live_overrides"]  # fixtures

PACKAGE = "dcseg_sdk"
CONFIG = f"""\
project_name_override: dcseg-sdk
package_name_override: {PACKAGE}
post_hooks: []
content_type_overrides:
  application/zip: application/octet-stream
  application/x-tar: application/octet-stream
  application/gzip: application/octet-stream
  application/x-gzip: application/octet-stream
"""
"""No post hooks (the generated code is imported, not formatted). The archive media types
are generated as binary bodies (the generator skips operations whose body type it does not
know; the generated call sends the last declared type, ``application/zip``)."""

STAGES = {"validate": {"report.json": b"{}"}, "segment": {"instances.json": b"[]"}}


def _require_generator() -> None:
    if os.environ.get("CI"):
        importlib.import_module("openapi_python_client")
    else:
        pytest.importorskip("openapi_python_client")


@pytest.fixture
def sdk(tmp_path: Path) -> Iterator[ModuleType]:
    """The generated package, imported from ``tmp_path`` (and forgotten afterwards)."""
    _require_generator()
    config = tmp_path / "sdk.yaml"
    config.write_text(CONFIG, encoding="utf-8")
    out = tmp_path / "generated" / PACKAGE
    command = [sys.executable, "-m", "openapi_python_client", "generate"]
    command += ["--path", str(DEFAULT_PATH), "--config", str(config)]
    command += ["--output-path", str(out), "--meta", "none"]
    result = subprocess.run(command, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "Warning" not in result.stdout, result.stdout  # no operation or model left out
    sys.path.insert(0, str(out.parent))
    try:
        yield importlib.import_module(PACKAGE)
    finally:
        sys.path.remove(str(out.parent))
        for name in [n for n in sys.modules if n.split(".")[0] == PACKAGE]:
            del sys.modules[name]


def _api(name: str) -> Any:
    return importlib.import_module(f"{PACKAGE}.api.{name}")


def test_generated_client_runs_a_job(sdk: ModuleType, live: LiveServer, scene: Path) -> None:
    models = importlib.import_module(f"{PACKAGE}.models")
    types = importlib.import_module(f"{PACKAGE}.types")
    client = sdk.AuthenticatedClient(
        base_url=live.url, token=KEY_A, raise_on_unexpected_status=True
    )
    with client:
        run_a_job(models, types, client, scene, live)


def run_a_job(models: Any, types: Any, client: Any, scene: Path, live: LiveServer) -> None:
    """Upload, create, poll to the end, list and download, read a problem: via the SDK."""
    archive = types.File(payload=io.BytesIO(zip_bytes(scene)), file_name="scene.zip")
    upload = _api("uploads.create_upload").sync(client=client, body=archive)
    assert isinstance(upload, models.UploadPublic), upload

    job = _api("jobs.create_job").sync(client=client, body=models.JobCreate(upload_id=upload.id))
    assert isinstance(job, models.JobPublic), job
    assert job.status == models.JobPublicStatus.QUEUED and job.upload_id == upload.id

    statuses = poll_while_running(client, job.id, live)
    assert statuses[-1] == models.JobPublicStatus.SUCCEEDED
    assert set(statuses) <= set(models.JobPublicStatus)

    listing = _api("artifacts.list_artifacts").sync(client=client, job_id=job.id)
    assert isinstance(listing, models.ArtifactsPublic)
    names = sorted(a.name for a in listing.artifacts)
    assert names == ["segment/instances.json", "validate/report.json"]
    download = _api("artifacts.download_artifact").sync_detailed(
        client=client, job_id=job.id, name="segment/instances.json"
    )
    assert download.status_code == 200 and download.content == b"[]"

    stream = _api("jobs.stream_job_events").sync_detailed(client=client, job_id=job.id)
    assert stream.status_code == 200 and isinstance(stream.parsed, str)
    event_models = {
        "status": models.StatusEvent,
        "progress": models.ProgressEvent,
        "log": models.LogEvent,
        "completed": models.CompletedEvent,
    }
    events = [event_models[e["event"]].from_dict(e) for e in sse_events(stream.parsed)]
    assert {type(e) for e in events} >= {models.StatusEvent, models.ProgressEvent}
    assert events[-1].data.status == models.CompletedEventDataStatus.SUCCEEDED

    missing = _api("jobs.get_job").sync(client=client, job_id="nope")
    assert isinstance(missing, models.Problem), missing
    assert missing.status == 404 and missing.type_ == "urn:dcseg:problem:not-found"


def poll_while_running(client: Any, job_id: str, live: LiveServer) -> list[Any]:
    """Run the job's fake stages on a thread while the generated ``getJob`` polls it to a
    terminal status; every status seen, in order."""
    get_job = _api("jobs.get_job")
    terminal = {"succeeded", "failed", "canceled"}
    runner = threading.Thread(target=execute, args=(live, job_id, run_stages(STAGES)))
    runner.start()
    seen: list[Any] = []
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        job = get_job.sync(client=client, job_id=job_id)
        seen.append(job.status)
        if job.status.value in terminal:
            break
        time.sleep(0.05)
    runner.join(30)
    assert seen and seen[-1].value in terminal, seen
    return seen
