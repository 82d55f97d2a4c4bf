"""The Python client and ``dcseg download`` on instances and exports: paging, filters,
``only=``, exports made on demand (202 polled), and the failures each reports."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from dcseg import client as client_module
from dcseg.cli import main
from dcseg.client import ApiError, Client, matches, select
from dcseg.export import FORMATS as EXPORT_FORMATS
from service.exports import FORMATS
from service.main import create_app
from tests.service.conftest import AUTH_A, KEY_A, TAR, TestClient, make_settings
from tests.service.segmented import instance_records, run_segmented_job, segment_files

FAKE = "tests.service.fake_export:export_run"


@pytest.fixture
def served(tmp_path: Path, scene_tar: bytes) -> Iterator[tuple[TestClient, str]]:
    settings = make_settings(tmp_path, export_wait_s=0.2)
    with TestClient(create_app(settings)) as test_client:
        test_client.app.state.exporter.target = FAKE  # type: ignore[attr-defined]
        upload = test_client.post("/v1/uploads", content=scene_tar, headers={**AUTH_A, **TAR})
        yield test_client, run_segmented_job(test_client, upload.json()["id"])


def _api(test_client: TestClient) -> Client:
    """A dcseg client talking to the in-process app through the test client's transport."""
    return Client(str(test_client.base_url), KEY_A, transport=test_client._transport)


@pytest.fixture
def api(served: tuple[TestClient, str]) -> Iterator[Client]:
    with _api(served[0]) as client:
        yield client


def test_instances_follow_the_pages_and_filter(api, served):
    _, job = served
    every = api.instances(job, page_size=2)
    assert [i["id"] for i in every] == [r["id"] for r in instance_records()]
    assert [i["id"] for i in api.instances(job, label="chair")] == [1, 3]
    assert [i["id"] for i in api.instances(job, label=["chair", "lamp"], min_score=0.5)] == [1, 5]
    with pytest.raises(ApiError) as refused:
        api.instances(job, label="sofa")
    assert refused.value.status == 422
    assert refused.value.problem["errors"][0]["path"] == "query.label"


def test_one_instance_and_an_unknown_one(api, served):
    _, job = served
    item = api.instance(job, 5)
    assert item["label"] == "lamp" and set(item["links"]["exports"]) == set(FORMATS)
    with pytest.raises(ApiError) as missing:
        api.instance(job, 42)
    assert missing.value.status == 404


def test_download_only_some_artifacts(api, served, tmp_path):
    _, job = served
    dest = tmp_path / "out"
    files = api.download(job, dest, only=["instances.json", "scene_labelled.ply"])
    names = sorted(p.relative_to(dest).as_posix() for p in files)
    assert names == ["segment/instances.json", "segment/scene_labelled.ply"]
    assert (dest / "segment" / "scene_labelled.ply").read_bytes() == segment_files()[
        "scene_labelled.ply"
    ]
    with pytest.raises(ValueError, match="'nope.json'"):
        api.download(job, tmp_path / "none", only=["labels.json", "nope.json"])
    assert not (tmp_path / "none").exists()  # nothing fetched when one name matches nothing


def test_export_download_waits_for_a_slow_export(api, served, tmp_path, monkeypatch):
    _, job = served
    monkeypatch.setenv("FAKE_EXPORT_MODE", "sleep")
    monkeypatch.setenv("FAKE_EXPORT_SLEEP_S", "1.5")
    files = api.download_export(job, "glb", tmp_path / "obj", instance=3)
    assert [p.relative_to(tmp_path / "obj").as_posix() for p in files] == ["objects/3.glb"]
    assert json.loads(files[0].read_text())["id"] == 3
    with pytest.raises(TimeoutError):
        api.export(job, "spz", timeout=0.1, poll=0.05)


def test_export_failures_are_api_errors(api, served, monkeypatch):
    _, job = served
    monkeypatch.setenv("FAKE_EXPORT_MODE", "invalid")
    with pytest.raises(ApiError) as failed:
        api.export(job, "ply", instance=2)
    assert failed.value.status == 422 and failed.value.problem["type"].endswith("export-failed")


def test_name_matching():
    items = [{"name": n} for n in ("reconstruct/scene.ply", "segment/scene.ply", "segment/x.json")]
    assert matches("segment/scene_labelled.ply", "scene_labelled.ply")
    assert not matches("segment/scene_labelled.ply", "labelled.ply")
    assert [i["name"] for i in select(items, ["scene.ply"])] == [
        "reconstruct/scene.ply",
        "segment/scene.ply",
    ]
    assert [i["name"] for i in select(items, ["segment/scene.ply"])] == ["segment/scene.ply"]
    assert select(items, None) == items
    with pytest.raises(ValueError, match="there are: reconstruct/scene.ply"):
        select(items, ["x"])


@pytest.fixture
def cli(served: tuple[TestClient, str], monkeypatch: pytest.MonkeyPatch) -> str:
    """``dcseg download`` talks to the in-process app; returns the job id."""
    test_client, job = served

    def connect(url: Any, key: Any) -> Client:
        return _api(test_client)

    monkeypatch.setattr(client_module, "client_from_args", connect)
    return job


def test_cli_download_only(cli, tmp_path, capsys):
    dest = tmp_path / "out"
    argv = ["download", cli, str(dest), "--only", "instances.json,scene_labelled.ply"]
    assert main(argv) == 0
    printed = sorted(Path(p).relative_to(dest).as_posix() for p in capsys.readouterr().out.split())
    assert printed == ["segment/instances.json", "segment/scene_labelled.ply"]


def test_cli_download_instance_export(cli, tmp_path, capsys):
    dest = tmp_path / "out"
    assert main(["download", cli, str(dest), "--instance", "2", "--format", "glb"]) == 0
    printed = capsys.readouterr().out.split()
    assert [Path(p).relative_to(dest).as_posix() for p in printed] == ["objects/2.glb"]
    assert json.loads(Path(printed[0]).read_text())["id"] == 2
    assert main(["download", cli, str(tmp_path / "scene"), "--format", "ply"]) == 0
    assert len(capsys.readouterr().out.split()) == len(instance_records()) + 1


@pytest.mark.parametrize(
    ("argv", "code", "message"),
    [
        (["--instance", "3"], 2, "--instance needs --format"),
        (["--only", "nope.json"], 2, "'nope.json'"),
        (["--instance", "99", "--format", "glb"], 4, "HTTP 404"),  # 4: not found
    ],
)
def test_cli_refusals(cli, tmp_path, capsys, argv, code, message):
    assert main(["download", cli, str(tmp_path / "out"), *argv]) == code
    assert message in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("argv", [["--instance", "0", "--format", "ply"], ["--format", "fbx"]])
def test_cli_bad_arguments_exit_2(cli, tmp_path, argv):
    with pytest.raises(SystemExit) as stopped:
        main(["download", cli, str(tmp_path / "out"), *argv])
    assert stopped.value.code == 2


def test_the_service_offers_every_export_format():
    assert tuple(FORMATS) == tuple(EXPORT_FORMATS)
