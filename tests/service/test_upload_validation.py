"""Upload validation (:func:`service.uploads.extract_and_validate`) through the API: archive
limits read before extracting, refused formats and names, and the pixel budget summed from
image headers before anything is decoded."""

from __future__ import annotations

import gc
import io
import json
import shutil
import tarfile
import weakref
import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from sqlalchemy import func, select

from dcseg.cli import main
from dcseg.inputs import RunInputs
from dcseg.io import images
from dcseg.io.captures import common
from dcseg.io.limits import LimitProblem
from dcseg.io.validate import validate_inputs
from jobstore.models import Upload
from service.main import create_app
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


def _solid_png(path: Path, size: int) -> None:
    ok, buffer = cv2.imencode(".png", np.zeros((size, size, 3), np.uint8))
    assert ok
    path.write_bytes(buffer.tobytes())


def test_upload_pixel_budget_checked_from_headers_before_decoding(
    tmp_path: Path, scene_copy: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Defect 1: upload validation decoded every frame with only a per-image pixel cap."""
    for rgb in sorted((scene_copy / "rgb").iterdir()):
        _solid_png(rgb, 3000)  # 9 Mpx each, ~30 kB: a tiny file that decodes large
    data = tar_bytes(scene_copy)
    assert len(data) < 2**20

    def no_decode(data: bytes, shown: str) -> Any:
        raise AssertionError(f"{shown} must not be decoded")

    monkeypatch.setattr(images, "_decode", no_decode)
    for client in _client(tmp_path, max_validation_pixels=20_000_000):
        response = client.post("/v1/uploads", content=data, headers={**AUTH_A, **TAR})
        body = assert_problem(response, 422)
        [error] = body["errors"]
        assert error["path"] == "rgb/frame_0002.png"  # 3 x 9 Mpx > 20 Mpx
        assert "decode to more than 20,000,000 pixels in total" in error["reason"]
        assert "nothing was decoded" in error["reason"]
        assert "setting max_validation_pixels" in error["reason"]
        _nothing_stored(client)


def test_validation_holds_one_frame_at_a_time(scene: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Defect 1: validation held every decoded frame of the capture in memory at once."""
    alive: list[weakref.ref[Any]] = []
    most = 0
    real = common._finish_frame

    def tracked(*args: Any, **kwargs: Any) -> Any:
        nonlocal most
        gc.collect()
        most = max(most, sum(ref() is not None for ref in alive))
        frame = real(*args, **kwargs)
        alive.append(weakref.ref(frame))
        return frame

    monkeypatch.setattr(common, "_finish_frame", tracked)
    report = validate_inputs(RunInputs.from_bundle(scene, complete=False))
    assert report.ok, report.problems
    assert len(alive) == 4 and most <= 1


def test_pixel_budget_refuses_decodes_whose_header_is_not_read(
    scene_copy: Path,
) -> None:
    """Defect 1: formats without a header size (BMP here) still count against the budget."""
    manifest = json.loads((scene_copy / "capture.json").read_text())
    for frame in manifest["frames"]:
        image = cv2.imread(str(scene_copy / frame["rgb"]))
        assert image is not None
        bmp = Path(frame["rgb"]).with_suffix(".bmp")
        cv2.imwrite(str(scene_copy / bmp), image)
        frame["rgb"] = bmp.as_posix()
    (scene_copy / "capture.json").write_text(json.dumps(manifest))
    assert validate_inputs(RunInputs(capture=scene_copy)).ok
    report = validate_inputs(RunInputs(capture=scene_copy), max_pixels=64 * 48 * 5)
    reasons = [p.reason for p in report.problems if isinstance(p, LimitProblem)]
    assert reasons and all("not decoded" in r for r in reasons), report.problems


def _unreadable_depth_and_stray_mask(root: Path) -> tuple[str, str]:
    manifest = json.loads((root / "capture.json").read_text())
    first = manifest["frames"][0]
    (root / first["depth"]).write_bytes(b"not a png at all")
    agnostic = root / "masks" / "agnostic"
    shutil.copy(agnostic / f"{first['name']}.json", agnostic / "no_such_frame.json")
    return first["depth"], "mask for frame 'no_such_frame', which the capture lacks"


def test_mask_problems_reported_when_a_frame_is_unreadable(
    client: TestClient, scene_copy: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Defect 5: with one unreadable depth file, masks matching no frame were not reported."""
    depth, stray = _unreadable_depth_and_stray_mask(scene_copy)
    args = ["validate", str(scene_copy), "--agnostic-masks", str(scene_copy / "masks/agnostic")]
    assert main(args) == 1
    out = capsys.readouterr().out
    assert f"{depth}: cannot decode image" in out and stray in out, out
    response = client.post("/v1/uploads", content=tar_bytes(scene_copy), headers={**AUTH_A, **TAR})
    errors = assert_problem(response, 422)["errors"]
    assert {"path": depth, "reason": "cannot decode image (corrupt or not an image)"} in errors
    assert {"path": "agnostic/no_such_frame.json", "reason": stray} in errors, errors
    _nothing_stored(client)
