"""``/viewer/{job_id}``: the page and its files, and the viewer in Chromium against the API
with bearer keys (asked for by the page, sent in a header, never in a URL)."""

from __future__ import annotations

import json
import re
import threading
import uuid
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
import uvicorn

from dcseg.viewer import CONTENT_SECURITY_POLICY
from service.deps import AppState
from service.main import create_app
from tests.dcseg.viewer.browser import browser as browser
from tests.dcseg.viewer.browser import wait_loaded
from tests.scenes.labelled import write_labelled_run
from tests.service.conftest import AUTH_A, KEY_A, assert_problem, free_port, wait_for
from tests.worker.fakes import FakeStage
from worker.execute import execute_job

VIEWER_FILES = ("scene_labelled.ply", "instances.json", "labels.json")


def test_page_names_the_jobs_artifacts_and_holds_no_key(client):
    job_id = str(uuid.uuid4())
    page = client.get(f"/viewer/{job_id}")
    assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
    assert page.headers["content-security-policy"] == CONTENT_SECURITY_POLICY
    assert page.headers["referrer-policy"] == "no-referrer"
    found = re.search(r'type="application/json">(.*?)</script>', page.text)
    assert found is not None
    files = json.loads(found.group(1))["files"]
    base = f"/v1/jobs/{job_id}/artifacts/segment"
    assert files == {
        "scene": f"{base}/scene_labelled.ply",
        "instances": f"{base}/instances.json",
        "labels": f"{base}/labels.json",
    }
    script = client.get("/viewer/static/viewer.js")
    assert script.headers["content-type"].startswith("text/javascript")
    assert_problem(client.get("/viewer/not-a-job"), 404)
    assert_problem(client.get("/viewer/static/index.html"), 404)
    assert not [p for p in client.get("/openapi.json").json()["paths"] if "viewer" in p]


@pytest.fixture
def api(settings, upload_id) -> Iterator[tuple[str, str]]:
    """The API on a real port, serving a finished job whose segment stage holds a labelled
    scene: yields (base URL, job id)."""
    app = create_app(settings)
    server = uvicorn.Server(uvicorn.Config(app, port=free_port(), log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    try:
        wait_for(lambda: server.started, timeout=30)
        port = server.servers[0].sockets[0].getsockname()[1]
        base = f"http://127.0.0.1:{port}"
        state: AppState = app.state.dcseg
        yield base, finished_job(base, upload_id, state, settings.storage_dir)
    finally:
        server.should_exit = True
        thread.join(30)


def finished_job(base: str, upload_id: str, state: AppState, storage: Path) -> str:
    job = httpx.post(f"{base}/v1/jobs", json={"upload_id": upload_id}, headers=AUTH_A)
    job_id: str = job.json()["id"]
    run = write_labelled_run(storage / "labelled")
    files = {name: (run.folder / name).read_bytes() for name in VIEWER_FILES}
    stage = FakeStage("segment", files=files)
    assert execute_job(job_id, state.store, state.settings, stages=[stage]) == "succeeded"
    return job_id


def test_viewer_asks_for_the_key_and_sends_it_only_in_a_header(browser, api):
    base, job_id = api
    page = browser.new_page()
    requests: list[tuple[str, str | None]] = []
    page.on("request", lambda r: requests.append((r.url, r.headers.get("authorization"))))
    page.goto(f"{base}/viewer/{job_id}")
    page.locator("#key-form").wait_for(state="visible")
    assert "401" in (page.locator("#key-message").text_content() or "")
    page.fill("#key-input", "wrong-key-0123456789")
    page.click("#key-form button")
    page.locator("#key-form").wait_for(state="visible")  # refused: asked again
    assert any(auth == "Bearer wrong-key-0123456789" for _, auth in requests)
    page.fill("#key-input", KEY_A)
    page.click("#key-form button")
    wait_loaded(page)
    assert page.locator("#objects .row").all_text_contents() == ["#1 floor", "#2 box", "#3 ball"]
    assert all(KEY_A not in url for url, _ in requests)
    artifact = f"{base}/v1/jobs/{job_id}/artifacts/segment/scene_labelled.ply"
    assert (artifact, f"Bearer {KEY_A}") in requests
    page.close()
