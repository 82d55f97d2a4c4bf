"""Issue 17 (service hardening): archive and upload validation limits, through the API."""

from __future__ import annotations

import io
import tarfile
import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import func, select

from service.main import create_app
from service.models import Upload
from tests.service.conftest import (
    AUTH_A,
    TAR,
    TestClient,
    assert_problem,
    make_settings,
    state_of,
    tar_bytes,
    zip_bytes,
)

ZIP = {"Content-Type": "application/zip"}


def _client(tmp_path: Path, **overrides: Any) -> Iterator[TestClient]:
    with TestClient(create_app(make_settings(tmp_path, **overrides))) as client:
        yield client


@pytest.fixture
def small_caps(tmp_path: Path) -> Iterator[TestClient]:
    yield from _client(tmp_path, max_archive_entries=10)


def _nothing_stored(client: TestClient) -> None:
    state = state_of(client)
    uploads = state.settings.storage_dir / "uploads"
    assert not uploads.exists() or list(uploads.iterdir()) == []
    with state.store.session() as s:
        assert s.scalar(select(func.count()).select_from(Upload)) == 0


def test_zip_central_directory_count_checked_before_reading(
    small_caps: TestClient, scene: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Defect 2: zipfile.ZipFile() read the whole central directory before the entry cap."""
    data = zip_bytes(scene)
    assert len(zipfile.ZipFile(io.BytesIO(data)).infolist()) > 10

    def boom(*args: Any, **kwargs: Any) -> None:
        raise AssertionError("zipfile.ZipFile must not be constructed")

    monkeypatch.setattr(zipfile, "ZipFile", boom)
    response = small_caps.post("/v1/uploads", content=data, headers={**AUTH_A, **ZIP})
    body = assert_problem(response, 422)
    assert body["errors"] == [
        {
            "path": "upload",
            "reason": "archive has more than 10 entries (setting max_archive_entries, "
            "environment DCSEG_MAX_ARCHIVE_ENTRIES)",
        }
    ]
    _nothing_stored(small_caps)


def test_tar_bz2_upload_is_refused(client: TestClient, scene: Path) -> None:
    """Defect 3: bz2 / xz archives were accepted; only tar and gzip are supported."""
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w:bz2") as tf:
        tf.add(scene, arcname=".")
    response = client.post("/v1/uploads", content=buffer.getvalue(), headers={**AUTH_A, **TAR})
    body = assert_problem(response, 422)
    assert "bzip2-compressed archives are not supported" in body["detail"]
    _nothing_stored(client)


def test_tar_non_utf8_entry_name_answers_422_not_500(client: TestClient, scene: Path) -> None:
    """Defect 4: a non-UTF-8 tar entry name made the upload (and later GETs) answer 500."""

    def latin1(tf: tarfile.TarFile) -> None:
        info = tarfile.TarInfo("masks/agnostic/caf\udce9.json")
        info.size = 2
        tf.addfile(info, io.BytesIO(b"[]"))

    data = tar_bytes(scene, extra=latin1)
    assert b"caf\xe9.json" in data
    response = client.post("/v1/uploads", content=data, headers={**AUTH_A, **TAR})
    body = assert_problem(response, 422)
    assert body["errors"] == [
        {
            "path": "upload",
            "reason": "archive entry 'masks/agnostic/caf\\xe9.json' has a name that is not "
            "valid UTF-8",
        }
    ]
    _nothing_stored(client)
    assert client.get("/v1/jobs", headers=AUTH_A).status_code == 200
