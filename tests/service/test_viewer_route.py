"""``/viewer/{job_id}``: the page and its files, and the viewer in Chromium against the API
with bearer keys (asked for by the page, sent in a header, never in a URL)."""

from __future__ import annotations

import json
import re
import threading
import uuid
from collections.abc import Iterator

import httpx
import numpy as np
import pytest
import uvicorn
from playwright.sync_api import Browser, Page

from dcseg.viewer import CONTENT_SECURITY_POLICY
from service.deps import AppState
from service.main import create_app
from tests.dcseg.viewer.browser import browser as browser
from tests.dcseg.viewer.browser import viewer_call, wait_loaded
from tests.dcseg.viewer.posed import Z_TO_Y, run_with_poses
from tests.scenes.labelled import labelled_run as labelled_run
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
def server(settings) -> Iterator[tuple[str, AppState]]:
    """The API on a real port: yields (base URL, its state)."""
    app = create_app(settings)
    server = uvicorn.Server(uvicorn.Config(app, port=free_port(), log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    try:
        wait_for(lambda: server.started, timeout=30)
        port = server.servers[0].sockets[0].getsockname()[1]
        yield f"http://127.0.0.1:{port}", app.state.dcseg
    finally:
        server.should_exit = True
        thread.join(30)


@pytest.fixture
def api(server, settings, upload_id) -> tuple[str, str]:
    """The API serving a finished job whose segment stage holds a labelled scene:
    (base URL, job id)."""
    base, state = server
    run = write_labelled_run(settings.storage_dir / "labelled")
    files = {name: (run.folder / name).read_bytes() for name in VIEWER_FILES}
    return base, finished_job(base, upload_id, state, files)


def finished_job(base: str, upload_id: str, state: AppState, files: dict[str, bytes]) -> str:
    """A job of ``upload_id`` whose segment stage wrote ``files``."""
    job = httpx.post(f"{base}/v1/jobs", json={"upload_id": upload_id}, headers=AUTH_A)
    job_id: str = job.json()["id"]
    stage = FakeStage("segment", files=files)
    assert execute_job(job_id, state.store, state.settings, stages=[stage]) == "succeeded"
    return job_id


def open_with_key(browser: Browser, url: str) -> Page:
    """The viewer at ``url``, given tenant A's key when it asks, once it has loaded."""
    page = browser.new_page()
    page.goto(url)
    page.locator("#key-form").wait_for(state="visible")
    page.fill("#key-input", KEY_A)
    page.click("#key-form button")
    wait_loaded(page)
    return page


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


def test_the_camera_takes_the_jobs_up_axis_from_its_frame_json(
    browser, server, upload_id, labelled_run, tmp_path
):
    base, state = server
    seen = {}
    for name, turn in (("y", Z_TO_Y), ("z", np.eye(4))):
        run = run_with_poses(labelled_run, tmp_path / name, turn)
        paths = [p for p in run.rglob("*") if p.is_file()]  # state/ included: the poses
        files = {p.relative_to(run).as_posix(): p.read_bytes() for p in paths}
        job_id = finished_job(base, upload_id, state, files)
        page = open_with_key(browser, f"{base}/viewer/{job_id}")
        seen[name] = viewer_call(page, "(v) => [v.camera.up.toArray(), v.upSource]")
        assert page.locator("#up").input_value() == f"+{name}"
        page.close()
    assert seen == {"y": [[0, 1, 0], "frame.json"], "z": [[0, 0, 1], "frame.json"]}
