"""S3 storage against a real S3 server (SeaweedFS, see tests/s3server.py): uploads, stage
outputs and manifests live in the bucket under the tenant's prefix; artifacts are served
through the API (Range, ETag) and by presigned URL; deleting removes the objects; quotas are
counted from the bucket; the worker's scratch folder is bounded and cleaned."""

from __future__ import annotations

import hashlib
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from jobstore.s3 import S3Storage
from jobstore.settings import Settings
from service.exports import cache_root
from service.main import create_app
from tests.s3server import S3Server, s3_settings
from tests.scenes.runs import make_run
from tests.service.conftest import AUTH_A, AUTH_B, TAR, TestClient, assert_problem, state_of
from tests.service.segmented import run_segmented_job
from tests.worker.fakes import FakeStage
from worker.execute import execute_job
from worker.stage import StageContext, StageOutcome

pytestmark = pytest.mark.integration


class CopyStage:
    """Reads stage ``one``'s file from the workspace and writes it reversed."""

    name = "two"

    def key(self, config: dict[str, Any]) -> dict[str, Any]:
        return {}

    def run(self, ctx: StageContext, out: Path) -> StageOutcome:
        assert ctx.output_root is not None
        data = (ctx.output_root / "one" / "out.txt").read_bytes()
        (out / "sub").mkdir()
        (out / "sub" / "rev.bin").write_bytes(data[::-1])
        ctx.progress("two", 1.0, "two: done")
        return StageOutcome("done", "two: done")


PAYLOAD = bytes(range(256)) * 64


@pytest.fixture
def s3(s3_server: S3Server, tmp_path: Path) -> Settings:
    settings: Settings = s3_settings(s3_server, tmp_path)
    return settings


@pytest.fixture
def client(s3: Settings) -> Iterator[TestClient]:
    with TestClient(create_app(s3)) as test_client:
        yield test_client


def _storage(client: TestClient) -> S3Storage:
    storage = state_of(client).storage
    assert isinstance(storage, S3Storage)
    return storage


def _keys(storage: S3Storage, prefix: str = "") -> list[str]:
    return sorted(item["Key"] for item in storage.objects(storage.prefix + prefix))


def _run_job(client: TestClient, scene_tar: bytes, stages: list[Any] | None = None) -> str:
    response = client.post("/v1/uploads", content=scene_tar, headers={**AUTH_A, **TAR})
    assert response.status_code == 201, response.text
    upload_id = response.json()["id"]
    response = client.post("/v1/jobs", json={"upload_id": upload_id}, headers=AUTH_A)
    assert response.status_code == 202, response.text
    job_id: str = response.json()["id"]
    state = state_of(client)
    stages = stages or [FakeStage("one", files={"out.txt": PAYLOAD}), CopyStage()]
    result = execute_job(job_id, state.store, state.settings, stages=stages, storage=state.storage)
    assert result == "succeeded", state.store.get_job(job_id)
    return job_id


def test_upload_and_outputs_live_in_the_bucket_under_the_tenant(client, scene_tar, s3):
    job_id = _run_job(client, scene_tar)
    storage = _storage(client)
    keys = _keys(storage)
    assert keys and all(k.startswith("tenants/tenant-a/") for k in keys)
    assert sum(k.endswith("/archive") for k in keys) == 1
    stage_keys = [k for k in keys if f"jobs/{job_id}/stages/" in k]
    assert [k.rsplit("/", 1)[1] for k in stage_keys] == ["00-one.json", "01-two.json"]
    manifest = storage.manifest("tenant-a", job_id)
    for stage in manifest["stages"]:
        for name, info in stage["files"].items():
            assert "/attempts/" in info["key"] and info["key"].endswith(name)
            body = storage.client.get_object(
                Bucket=storage.bucket, Key=storage.key("tenant-a", info["key"])
            )["Body"].read()
            assert hashlib.sha256(body).hexdigest() == info["sha256"]
    # nothing of the job on the API's disk, and the worker's scratch folder is gone
    assert not (s3.storage_dir / "jobs").exists()
    assert not (s3.scratch_dir / job_id).exists()


def test_artifacts_proxied_with_range_and_etag_and_presigned(client, scene_tar):
    job_id = _run_job(client, scene_tar)
    listing = client.get(f"/v1/jobs/{job_id}/artifacts", headers=AUTH_A).json()["artifacts"]
    assert [a["name"] for a in listing] == ["one/out.txt", "two/sub/rev.bin"]
    item = listing[0]
    assert item["sha256"] == hashlib.sha256(PAYLOAD).hexdigest()
    full = client.get(item["url"], headers=AUTH_A)
    assert full.status_code == 200 and full.content == PAYLOAD
    assert full.headers["etag"] == f'"{item["sha256"]}"'
    part = client.get(item["url"], headers={**AUTH_A, "Range": "bytes=10-19"})
    assert part.status_code == 206 and part.content == PAYLOAD[10:20]
    assert part.headers["content-range"] == f"bytes 10-19/{len(PAYLOAD)}"
    cached = client.get(item["url"], headers={**AUTH_A, "If-None-Match": full.headers["etag"]})
    assert cached.status_code == 304
    assert item["download_url"] and "tenants/tenant-a/" in item["download_url"]
    assert item["download_url_expires_at"] is not None
    direct = httpx.get(item["download_url"])
    assert direct.status_code == 200 and direct.content == PAYLOAD
    assert client.get(f"/v1/jobs/{job_id}/artifacts", headers=AUTH_B).status_code == 404


def test_presigned_urls_expire(s3_server, tmp_path, scene_tar):
    settings = s3_settings(s3_server, tmp_path, presign_expiry_s=1)
    with TestClient(create_app(settings)) as client:
        job_id = _run_job(client, scene_tar)
        listing = client.get(f"/v1/jobs/{job_id}/artifacts", headers=AUTH_A).json()
        url = listing["artifacts"][0]["download_url"]
        deadline = time.monotonic() + 60
        while httpx.get(url).status_code == 200:
            assert time.monotonic() < deadline, "the presigned URL never expired"
            time.sleep(0.5)
        assert httpx.get(url).status_code == 403
        # the proxied download still works
        assert client.get(listing["artifacts"][0]["url"], headers=AUTH_A).status_code == 200


def test_deleting_removes_objects_and_quota_counts_the_bucket(client, scene_tar, s3):
    job_id = _run_job(client, scene_tar)
    storage = _storage(client)
    state = state_of(client)
    used = storage.tenant_bytes(state.store, "tenant-a")
    sizes = sum(int(o["Size"]) for o in storage.objects(storage.tenant_prefix("tenant-a")))
    assert used == sizes > len(scene_tar)
    assert client.delete(f"/v1/jobs/{job_id}", headers=AUTH_A).status_code == 204
    assert not [k for k in _keys(storage) if f"/jobs/{job_id}/" in k]
    uploads = [k for k in _keys(storage) if k.endswith("/archive")]
    assert len(uploads) == 1
    upload = uploads[0].split("/")[-2]
    assert client.delete(f"/v1/uploads/{upload}", headers=AUTH_A).status_code == 204
    assert _keys(storage, "tenants/tenant-a/") == []
    assert storage.tenant_bytes(state.store, "tenant-a") == 0


def test_quota_from_the_bucket_refuses_uploads(s3_server, tmp_path, scene_tar):
    settings = s3_settings(s3_server, tmp_path, tenant_storage_quota_bytes=len(scene_tar) + 10)
    with TestClient(create_app(settings)) as client:
        first = client.post("/v1/uploads", content=scene_tar, headers={**AUTH_A, **TAR})
        assert first.status_code == 201, first.text
        second = client.post("/v1/uploads", content=scene_tar, headers={**AUTH_A, **TAR})
        body = assert_problem(second, 507)
        assert body["used"] == len(scene_tar)


@pytest.mark.parametrize("room", [100, "inputs + 100"])
def test_scratch_limit_fails_the_job_naming_the_setting(client, scene_tar, s3, room):
    response = client.post("/v1/uploads", content=scene_tar, headers={**AUTH_A, **TAR})
    upload_id = response.json()["id"]
    job = client.post("/v1/jobs", json={"upload_id": upload_id}, headers=AUTH_A).json()
    state = state_of(client)
    upload = state.store.get_upload(upload_id, "tenant-a")
    assert upload is not None and upload.stored_bytes is not None
    inputs = upload.size + upload.stored_bytes
    limit = inputs + 100 if room == "inputs + 100" else 100  # too small for the stage's output
    settings = s3.model_copy(update={"scratch_max_bytes": limit})
    # the archive is deleted once extracted: the stage's output must exceed it to overflow
    stage = FakeStage("one", files={"out.txt": b"x" * (upload.size + 1000)})
    result = execute_job(job["id"], state.store, settings, stages=[stage], storage=state.storage)
    assert result == "failed" and stage.runs == (1 if room == "inputs + 100" else 0)
    failed = state.store.get_job(job["id"])
    assert failed is not None and failed.error is not None
    error = failed.error
    assert error["type"] == "scratch-full" and "DCSEG_SCRATCH_MAX_BYTES" in error["detail"]
    assert not (settings.scratch_dir / job["id"]).exists()
    assert state.storage.manifest("tenant-a", job["id"])["stages"] == []


def test_a_corrupted_object_is_refused_on_fetch(client, scene_tar):
    state = state_of(client)
    storage = _storage(client)
    job_id = _run_job(client, scene_tar, [FakeStage("one", files={"out.txt": PAYLOAD})])
    info = storage.manifest("tenant-a", job_id)["stages"][0]["files"]["one/out.txt"]
    storage.client.put_object(
        Bucket=storage.bucket, Key=storage.key("tenant-a", info["key"]), Body=b"x" * len(PAYLOAD)
    )
    # a derived job fetching the (corrupted) parent stage runs the stage itself instead
    child = client.post("/v1/jobs", json={"parent_job_id": job_id}, headers=AUTH_A).json()
    one = FakeStage("one", files={"out.txt": PAYLOAD})
    result = execute_job(child["id"], state.store, state.settings, stages=[one], storage=storage)
    assert result == "succeeded" and one.runs == 1


def test_a_derived_job_reuses_the_parents_stage_from_the_bucket(client, scene_tar):
    state = state_of(client)
    storage = _storage(client)
    job_id = _run_job(client, scene_tar)
    child = client.post("/v1/jobs", json={"parent_job_id": job_id}, headers=AUTH_A).json()
    one = FakeStage("one", files={"out.txt": PAYLOAD})
    result = execute_job(
        child["id"], state.store, state.settings, stages=[one, CopyStage()], storage=storage
    )
    assert result == "succeeded" and one.runs == 0
    stages = storage.manifest("tenant-a", child["id"])["stages"]
    assert stages[0]["details"] == {"reused": True}
    assert all(f"jobs/{child['id']}/attempts/" in i["key"] for i in stages[0]["files"].values())


class _Recording(httpx.BaseTransport):
    """The API's transport, remembering the paths asked for."""

    def __init__(self, inner: httpx.BaseTransport) -> None:
        self.inner, self.paths = inner, []  # type: ignore[var-annotated]

    def handle_request(self, request: httpx.Request) -> httpx.Response:
        self.paths.append(request.url.path)
        return self.inner.handle_request(request)


@pytest.mark.parametrize("expiry_s", [300, 1])
def test_the_client_follows_presigned_urls_and_falls_back(
    s3_server,
    tmp_path,
    scene_tar,
    expiry_s,
):
    from dcseg.client import Client
    from tests.service.conftest import KEY_A

    settings = s3_settings(s3_server, tmp_path, presign_expiry_s=expiry_s)
    with TestClient(create_app(settings)) as test_client:
        job_id = _run_job(test_client, scene_tar)
        transport = _Recording(test_client._transport)
        with Client("http://testserver", KEY_A, transport=transport) as client:
            if expiry_s == 1:  # every presigned URL has expired by the time it is used
                listing = client.artifacts(job_id)
                url = listing[0]["download_url"]
                deadline = time.monotonic() + 60
                while httpx.get(url).status_code == 200:
                    assert time.monotonic() < deadline
                    time.sleep(0.5)
                client.artifacts = lambda job_id: listing  # type: ignore[method-assign,assignment]
            files = client.download(job_id, tmp_path / "out")
        assert (tmp_path / "out" / "one" / "out.txt").read_bytes() == PAYLOAD
        assert (tmp_path / "out" / "two" / "sub" / "rev.bin").read_bytes() == PAYLOAD[::-1]
        assert len(files) == 2
        proxied = [p for p in transport.paths if "/artifacts/" in p]
        assert len(proxied) == (2 if expiry_s == 1 else 0)


def test_the_viewers_frame_json_is_read_from_the_bucket(client, scene_tar, s3, tmp_path):
    """Without a frame.json of its own the job's is derived from the segment stage's poses,
    fetched from the bucket into the exports' copy of the run; a job's own is read as stored."""
    run = make_run(tmp_path / "run")  # +z up poses in state/
    files = {p.relative_to(run).as_posix(): p.read_bytes() for p in run.rglob("*") if p.is_file()}
    upload = client.post("/v1/uploads", content=scene_tar, headers={**AUTH_A, **TAR}).json()
    derived = run_segmented_job(client, upload["id"], files=files)
    frame = client.get(f"/viewer/{derived}/frame.json", headers=AUTH_A)
    assert frame.status_code == 200 and frame.json()["world"]["up_axis"] == "+z"
    assert (cache_root(s3, derived) / "run" / "state" / "views.json").is_file()
    own = run_segmented_job(client, upload["id"], files={**files, "frame.json": b'{"up": 1}'})
    assert client.get(f"/viewer/{own}/frame.json", headers=AUTH_A).content == b'{"up": 1}'
    assert not (cache_root(s3, own) / "run").exists()  # nothing fetched but the file
