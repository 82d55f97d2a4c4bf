"""On-demand exports: made once in a child process, cached, downloaded like artifacts; limits,
failures, tenancy, and the event loop staying free while an export runs."""

from __future__ import annotations

import hashlib
import json
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from service.exports import fetch_run
from service.main import create_app
from tests.service.conftest import (
    AUTH_A,
    AUTH_B,
    TAR,
    TestClient,
    assert_problem,
    make_settings,
    state_of,
    wait_for,
)
from tests.service.segmented import OBJECTS, run_segmented_job, segment_files

FAKE = "tests.service.fake_export:export_run"


@contextmanager
def _client(tmp_path: Path, **overrides: Any) -> Iterator[TestClient]:
    settings = make_settings(tmp_path, **{"export_wait_s": 60.0, **overrides})
    with TestClient(create_app(settings)) as client:
        client.app.state.exporter.target = FAKE  # type: ignore[attr-defined]
        yield client


@pytest.fixture
def log(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    path = tmp_path / "calls.log"
    monkeypatch.setenv("FAKE_EXPORT_LOG", str(path))
    return path


def _calls(log: Path) -> int:
    return len(log.read_text().splitlines()) if log.exists() else 0


def _job(client: TestClient, scene_tar: bytes) -> str:
    upload = client.post("/v1/uploads", content=scene_tar, headers={**AUTH_A, **TAR}).json()
    return run_segmented_job(client, upload["id"])


@pytest.fixture
def env(tmp_path: Path, scene_tar: bytes, log: Path) -> Iterator[tuple[TestClient, str]]:
    with _client(tmp_path) as client:
        yield client, _job(client, scene_tar)


def test_scene_export_is_made_once_and_downloads_like_an_artifact(env, log):
    client, job = env
    url = f"/v1/jobs/{job}/exports/ply"
    first = client.get(url, headers=AUTH_A)
    assert first.status_code == 200, first.text
    body = first.json()
    assert body["status"] == "succeeded" and body["format"] == "ply" and body["instance"] is None
    names = [f["name"] for f in body["files"]]
    assert names == [f"objects/{k}.ply" for k, *_ in OBJECTS] + ["scene.ply"]
    assert client.get(url, headers=AUTH_A).json() == body
    assert _calls(log) == 1
    item = next(f for f in body["files"] if f["name"] == "objects/2.ply")
    assert item["url"] == f"{url}/objects/2.ply"
    full = client.get(item["url"], headers=AUTH_A)
    assert full.status_code == 200 and hashlib.sha256(full.content).hexdigest() == item["sha256"]
    assert full.headers["etag"] == f'"{item["sha256"]}"' and len(full.content) == item["size"]
    rows = json.loads(full.content)["rows"]
    assert len(rows) == OBJECTS[1][4]
    part = client.get(item["url"], headers={**AUTH_A, "Range": "bytes=2-5"})
    assert part.status_code == 206 and part.content == full.content[2:6]
    etag = full.headers["etag"]
    assert client.get(item["url"], headers={**AUTH_A, "If-None-Match": etag}).status_code == 304
    head = client.head(item["url"], headers=AUTH_A)
    assert head.status_code == 200 and head.headers["content-length"] == str(item["size"])


def test_instance_export_holds_that_object_only(env, log):
    client, job = env
    record = client.get(f"/v1/jobs/{job}/instances/3", headers=AUTH_A).json()
    url = record["links"]["exports"]["glb"]
    assert url == f"/v1/jobs/{job}/instances/3/exports/glb"
    formats = {"ply", "spz", "splat", "glb", "glb-mesh", "obj", "usdz"}
    assert set(record["links"]["exports"]) == formats
    body = client.get(url, headers=AUTH_A).json()
    assert body["instance"] == 3 and [f["name"] for f in body["files"]] == ["objects/3.glb"]
    data = client.get(body["files"][0]["url"], headers=AUTH_A)
    assert data.headers["content-type"] == "model/gltf-binary"
    assert json.loads(data.content)["id"] == 3
    # the scene's and the instance's exports are cached apart
    scene = client.get(f"/v1/jobs/{job}/exports/glb", headers=AUTH_A).json()
    assert len(scene["files"]) == len(OBJECTS) + 1 and _calls(log) == 2


def test_export_files_before_and_outside_the_export_are_404(env):
    client, job = env
    base = f"/v1/jobs/{job}/exports/ply"
    body = assert_problem(client.get(f"{base}/scene.ply", headers=AUTH_A), 404)
    assert "GET " in body["detail"]
    client.get(base, headers=AUTH_A)
    for name in ("nope.ply", "%2e%2e/manifest.json", "objects", "objects/../scene.ply/x"):
        assert_problem(client.get(f"{base}/{name}", headers=AUTH_A), 404)
    # the client resolves "..": this asks for format "manifest.json" (not a format)
    assert_problem(client.get(f"{base}/../manifest.json", headers=AUTH_A), 422)
    assert_problem(client.get(f"/v1/jobs/{job}/instances/1/exports/ply/x", headers=AUTH_A), 404)


@pytest.mark.parametrize("export", ["exports/ply", "instances/2/exports/ply"])
def test_scene_and_instance_export_files_download_alike(env, export):
    """The scene's and an object's export files share one GET and one HEAD implementation."""
    client, job = env
    body = client.get(f"/v1/jobs/{job}/{export}?colour=class", headers=AUTH_A).json()
    url = body["files"][0]["url"]
    assert url.startswith(f"/v1/jobs/{job}/{export}/") and url.endswith("?colour=class")
    whole = client.get(url, headers=AUTH_A)
    etag, size = whole.headers["etag"], len(whole.content)
    part = client.get(url, headers={**AUTH_A, "Range": "bytes=1-4"})
    assert part.status_code == 206 and part.content == whole.content[1:5]
    stale = client.get(url, headers={**AUTH_A, "Range": "bytes=1-4", "If-Range": '"old"'})
    assert stale.status_code == 200 and stale.content == whole.content
    assert client.get(url, headers={**AUTH_A, "If-None-Match": etag}).status_code == 304
    head = client.head(url, headers={**AUTH_A, "Range": "bytes=1-4"})
    assert head.status_code == 200 and head.headers["content-length"] == str(size)
    assert head.headers["etag"] == etag and head.content == b""
    assert client.head(url, headers={**AUTH_A, "If-None-Match": etag}).status_code == 304
    missing = url.replace(body["files"][0]["name"], "nope.ply")
    assert client.head(missing, headers=AUTH_A).status_code == 404
    # another option set is another export, not made yet
    other = url.replace("colour=class", "colour=instance")
    assert "GET " in assert_problem(client.get(other, headers=AUTH_A), 404)["detail"]
    assert client.head(other, headers=AUTH_A).status_code == 404
    bad = client.get(f"/v1/jobs/{job}/{export[:-3]}fbx/x?colour=red", headers=AUTH_A)
    assert [e["path"] for e in assert_problem(bad, 422)["errors"]] == [
        "query.colour",
        "path.format",
    ]


def test_bad_format_instance_tenant_and_state(env):
    client, job = env
    bad = assert_problem(client.get(f"/v1/jobs/{job}/exports/fbx", headers=AUTH_A), 422)
    assert [e["path"] for e in bad["errors"]] == ["path.format"]
    assert_problem(client.get(f"/v1/jobs/{job}/instances/99/exports/ply", headers=AUTH_A), 404)
    assert_problem(client.get(f"/v1/jobs/{job}/instances/0/exports/ply", headers=AUTH_A), 422)
    assert_problem(client.get(f"/v1/jobs/{job}/exports/ply", headers=AUTH_B), 404)
    assert_problem(client.get(f"/v1/jobs/{job}/exports/ply"), 401)
    assert_problem(client.get("/v1/jobs/nope/exports/ply", headers=AUTH_A), 404)
    upload = client.get(f"/v1/jobs/{job}", headers=AUTH_A).json()["upload_id"]
    queued = client.post("/v1/jobs", json={"upload_id": upload}, headers=AUTH_A).json()["id"]
    assert_problem(client.get(f"/v1/jobs/{queued}/exports/ply", headers=AUTH_A), 409)
    assert_problem(client.get(f"/v1/jobs/{queued}/instances/1/exports/ply", headers=AUTH_A), 409)


def test_a_slow_export_answers_202_then_succeeds(tmp_path, scene_tar, log, monkeypatch):
    monkeypatch.setenv("FAKE_EXPORT_MODE", "sleep")
    monkeypatch.setenv("FAKE_EXPORT_SLEEP_S", "2")
    with _client(tmp_path, export_wait_s=0.2) as client:
        job = _job(client, scene_tar)
        url = f"/v1/jobs/{job}/exports/spz"
        first = client.get(url, headers=AUTH_A)
        assert first.status_code == 202, first.text
        assert first.headers["location"] == url and int(first.headers["retry-after"]) >= 1
        assert first.json()["status"] == "running" and first.json()["files"] == []
        deadline = time.monotonic() + 60
        while (again := client.get(url, headers=AUTH_A)).status_code == 202:
            assert time.monotonic() < deadline
            time.sleep(0.2)
        assert again.status_code == 200 and again.json()["status"] == "succeeded"
        assert _calls(log) == 1  # the polls joined the export already being made


def test_the_event_loop_stays_free_while_an_export_runs(tmp_path, scene_tar, monkeypatch):
    monkeypatch.setenv("FAKE_EXPORT_MODE", "sleep")
    monkeypatch.setenv("FAKE_EXPORT_SLEEP_S", "3")
    with _client(tmp_path) as client:
        job = _job(client, scene_tar)
        answers: list[int] = []

        def export(client: TestClient = client, job: str = job) -> None:
            answers.append(client.get(f"/v1/jobs/{job}/exports/ply", headers=AUTH_A).status_code)

        slow = threading.Thread(target=export)
        slow.start()
        time.sleep(0.5)
        started = time.monotonic()
        assert client.get("/healthz").status_code == 200
        assert client.get(f"/v1/jobs/{job}", headers=AUTH_A).status_code == 200
        assert time.monotonic() - started < 1.0 and slow.is_alive()
        slow.join(60)
        assert answers == [200]


def test_time_limit_kills_the_export_and_the_failure_is_cached(
    tmp_path, scene_tar, log, monkeypatch
):
    monkeypatch.setenv("FAKE_EXPORT_MODE", "sleep")
    monkeypatch.setenv("FAKE_EXPORT_SLEEP_S", "30")
    with _client(tmp_path, export_time_limit_s=4.0) as client:
        job = _job(client, scene_tar)
        started = time.monotonic()
        body = assert_problem(client.get(f"/v1/jobs/{job}/exports/glb", headers=AUTH_A), 422)
        assert time.monotonic() - started < 20
        assert (
            body["type"].endswith("export-timed-out")
            and "DCSEG_EXPORT_TIME_LIMIT_S" in body["detail"]
        )
        again = assert_problem(client.get(f"/v1/jobs/{job}/exports/glb", headers=AUTH_A), 422)
        assert again["type"] == body["type"] and _calls(log) == 1
    # the same job under a longer limit is tried again
    monkeypatch.setenv("FAKE_EXPORT_MODE", "")
    with _client(tmp_path, export_time_limit_s=60.0) as client:
        ok = client.get(f"/v1/jobs/{job}/exports/glb", headers=AUTH_A)
        assert ok.status_code == 200 and _calls(log) == 2


def test_an_export_over_the_size_limit_is_discarded(tmp_path, scene_tar):
    with _client(tmp_path, max_export_bytes=64) as client:
        job = _job(client, scene_tar)
        body = assert_problem(client.get(f"/v1/jobs/{job}/exports/ply", headers=AUTH_A), 422)
        assert (
            body["type"].endswith("export-too-large") and "DCSEG_MAX_EXPORT_BYTES" in body["detail"]
        )
        folder = tmp_path / "data" / "jobs" / job / "exports" / "scene" / "ply"
        assert sorted(p.name for p in folder.iterdir()) == ["error.json"]
        leftovers = [p.name for p in folder.parent.iterdir() if p.name.startswith(".tmp")]
        assert leftovers == []


def test_an_export_the_run_cannot_make_names_the_problem_without_storage_paths(
    env, monkeypatch, tmp_path
):
    client, job = env
    monkeypatch.setenv("FAKE_EXPORT_MODE", "invalid")
    body = assert_problem(client.get(f"/v1/jobs/{job}/exports/glb", headers=AUTH_A), 422)
    assert body["type"].endswith("export-failed")
    assert body["errors"] == [{"path": "segment/state", "reason": "no depth under segment"}]
    assert str(tmp_path) not in json.dumps(body)


@pytest.mark.parametrize("mode", ["crash", "raise"])
def test_a_crashing_exporter_is_a_500_with_an_error_id(env, monkeypatch, tmp_path, log, mode):
    client, job = env
    monkeypatch.setenv("FAKE_EXPORT_MODE", mode)
    body = assert_problem(client.get(f"/v1/jobs/{job}/exports/splat", headers=AUTH_A), 500)
    assert body["type"].endswith("export-error") and "internal error" in body["detail"]
    assert str(tmp_path) not in json.dumps(body) and "boom" not in json.dumps(body)
    # not cached: the next request tries again, and succeeds once the exporter does
    monkeypatch.setenv("FAKE_EXPORT_MODE", "")
    assert client.get(f"/v1/jobs/{job}/exports/splat", headers=AUTH_A).status_code == 200
    assert _calls(log) == 2


def test_deleting_the_job_removes_its_exports(env, tmp_path):
    client, job = env
    assert client.get(f"/v1/jobs/{job}/exports/ply", headers=AUTH_A).status_code == 200
    folder = tmp_path / "data" / "jobs" / job / "exports"
    assert folder.is_dir()
    assert client.delete(f"/v1/jobs/{job}", headers=AUTH_A).status_code == 204
    assert not folder.exists()
    assert_problem(client.get(f"/v1/jobs/{job}/exports/ply", headers=AUTH_A), 404)


def test_fake_exporter_partitions_the_labelled_gaussians(env):
    """The fake's per-object rows cover every labelled Gaussian once (the contract's check)."""
    client, job = env
    body = client.get(f"/v1/jobs/{job}/exports/ply", headers=AUTH_A).json()
    rows = [
        json.loads(client.get(f["url"], headers=AUTH_A).content)["rows"]
        for f in body["files"]
        if f["name"].startswith("objects/")
    ]
    flat = np.concatenate(rows)
    assert len(flat) == len(set(flat.tolist())) == sum(n for *_, n in OBJECTS)


class ObjectStorageLike:
    """A storage that is not local (as S3): delegates to another, counting reads."""

    backend = "s3"

    def __init__(self, inner: Any, corrupt: str | None = None) -> None:
        self.inner, self.corrupt, self.reads = inner, corrupt, 0

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)

    def read(self, tenant: str, item: Any, start: int, end: int) -> Iterator[bytes]:
        self.reads += 1
        for chunk in self.inner.read(tenant, item, start, end):
            yield b"x" + chunk[1:] if item.name == self.corrupt else chunk


def test_jobs_in_object_storage_are_fetched_once_then_exported(env, tmp_path, log):
    client, job = env
    state = state_of(client)
    state.storage = ObjectStorageLike(state.storage)
    body = client.get(f"/v1/jobs/{job}/instances/2/exports/ply", headers=AUTH_A).json()
    assert [f["name"] for f in body["files"]] == ["objects/2.ply"]
    fetched = tmp_path / "data" / "jobs" / job / "exports" / "run"
    assert sorted(p.name for p in fetched.iterdir()) == sorted(segment_files())
    reads = state.storage.reads
    assert client.get(f"/v1/jobs/{job}/exports/ply", headers=AUTH_A).status_code == 200
    assert state.storage.reads == reads + 1  # instances.json only: the run is fetched already
    assert _calls(log) == 2


def test_a_corrupt_stored_file_is_not_exported(env, tmp_path):
    client, job = env
    state = state_of(client)
    state.storage = ObjectStorageLike(state.storage, corrupt="segment/scene_labelled.ply")
    with pytest.raises(OSError, match="SHA-256 mismatch"):
        fetch_run(state.storage, "tenant-a", job, tmp_path / "run")
    assert not (tmp_path / "run").exists()
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".tmp-run")] == []


def test_shutdown_kills_a_running_export(tmp_path, scene_tar, monkeypatch):
    monkeypatch.setenv("FAKE_EXPORT_MODE", "sleep")
    monkeypatch.setenv("FAKE_EXPORT_SLEEP_S", "60")
    with _client(tmp_path, export_wait_s=0.5) as client:
        job = _job(client, scene_tar)
        assert client.get(f"/v1/jobs/{job}/exports/glb", headers=AUTH_A).status_code == 202
        exporter = client.app.state.exporter  # type: ignore[attr-defined]
        children = list(exporter._children)
        assert len(children) == 1 and children[0].poll() is None
    started = time.monotonic()
    children[0].wait(10)
    assert children[0].returncode is not None and time.monotonic() - started < 10
    folder = tmp_path / "data" / "jobs" / job / "exports" / "scene" / "glb"
    wait_for(lambda: not any(folder.parent.glob(".tmp-*")), timeout=10)
    assert not folder.exists()  # neither a half-made export nor a failure is kept
