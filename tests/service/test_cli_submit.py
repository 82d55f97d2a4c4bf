"""``dcseg submit`` against a real server: a folder (packed on the fly), an archive, an
upload id; arguments that are none of these; and retries made safe by Idempotency-Keys."""

from __future__ import annotations

import tarfile
from typing import Any

import httpx
import pytest

from dcseg.cli import main
from dcseg.client.files import pack_folder
from tests.service.conftest import AUTH_A, KEY_A, tar_bytes
from tests.service.live import Fault, LiveServer, live, live_overrides

__all__ = ["live", "live_overrides"]


@pytest.fixture(autouse=True)
def fast_retries(monkeypatch: pytest.MonkeyPatch) -> None:
    from dcseg.client import RetryPolicy

    policy = RetryPolicy(backoff_s=0.05, max_backoff_s=0.1)
    monkeypatch.setattr("dcseg.client.sync.RetryPolicy", lambda: policy)


def _submit(live: LiveServer, capture: str, *extra: str) -> int:
    return main(["submit", capture, "--url", live.url, "--api-key", KEY_A, *extra])


def _get(live: LiveServer, path: str) -> Any:
    response = httpx.get(f"{live.url}{path}", headers=AUTH_A)
    assert response.status_code == 200, response.text
    return response.json()


def _posts(live: LiveServer, path: str) -> list[dict[str, str]]:
    return [h for method, p, h in live.app.seen if method == "POST" and p == path]


def test_a_folder_is_packed_and_uploaded(live, scene, capsys):
    assert _submit(live, str(scene), "--json") == 0
    job = __import__("json").loads(capsys.readouterr().out)
    upload = _get(live, f"/v1/uploads/{job['upload_id']}")
    assert upload["content_type"] == "application/x-tar"
    assert upload["summary"]["capture"]["frames"] == 4  # the capture is at the root
    [sent] = _posts(live, "/v1/uploads")
    assert sent["idempotency-key"].endswith(".upload")


def test_an_archive_and_an_upload_id(live, scene, tmp_path, capsys):
    archive = tmp_path / "scene.tar"
    archive.write_bytes(tar_bytes(scene))
    assert _submit(live, str(archive)) == 0
    first = _get(live, f"/v1/jobs/{capsys.readouterr().out.strip()}")
    assert _submit(live, first["upload_id"]) == 0
    second = _get(live, f"/v1/jobs/{capsys.readouterr().out.strip()}")
    assert second["upload_id"] == first["upload_id"] and second["id"] != first["id"]
    assert len(_posts(live, "/v1/uploads")) == 1  # the id was not taken for a path


@pytest.mark.parametrize(
    ("capture", "message"),
    [("no-such-folder", "no-such-folder: no such folder or archive"), ("notes.txt", ".tar.gz")],
)
def test_neither_a_capture_nor_an_upload_id(live, tmp_path, monkeypatch, capsys, capture, message):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "notes.txt").write_text("not an archive")
    assert _submit(live, capture) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1
    assert _posts(live, "/v1/uploads") == [] and _posts(live, "/v1/jobs") == []


def test_failed_posts_are_retried_without_a_second_job(live, scene, capsys):
    live.app.plan.append(Fault("/v1/uploads", "status", 503, method="POST"))
    live.app.plan.append(Fault("/v1/jobs", "status", 502, method="POST"))
    assert _submit(live, str(scene)) == 0
    job_id = capsys.readouterr().out.strip()
    assert len(_posts(live, "/v1/uploads")) == 2 and len(_posts(live, "/v1/jobs")) == 2
    keys = {h["idempotency-key"] for h in _posts(live, "/v1/jobs")}
    assert len(keys) == 1  # the same key on both tries
    jobs = _get(live, "/v1/jobs")["jobs"]
    assert [j["id"] for j in jobs] == [job_id]


def test_refused_options_list_their_fields(live, scene, capsys):
    assert _submit(live, str(scene), "--options", "{nope") == 2
    assert "--options is not JSON" in capsys.readouterr().err
    assert _submit(live, str(scene), "--options", '{"affinity": {"margin": 7}}') == 1
    err = capsys.readouterr().err.splitlines()
    assert err[0].startswith("dcseg submit: HTTP 422")
    assert err[1].startswith("  - body.options.affinity.margin: ")


def test_pack_folder_puts_the_files_at_the_root(scene, tmp_path):
    archive = pack_folder(scene, tmp_path / "a.tar")
    with tarfile.open(archive) as tar:
        names = set(tar.getnames())
    expected = {p.relative_to(scene).as_posix() for p in scene.rglob("*")}
    assert names == expected  # relative to the folder: its files at the root
