"""Record3D ``.r3d`` captures written in code from the documented layout (real LZFSE buffers)."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import OpenEXR
import pytest

from dcseg.cli import main
from dcseg.config import CaptureOptions
from dcseg.errors import InputError
from dcseg.inputs import RunInputs
from dcseg.io import limits
from dcseg.io.captures import detect_layout, read_capture
from dcseg.io.images import write_image
from dcseg.io.limits import LimitProblem
from dcseg.io.lzfse_buffers import compress
from dcseg.io.validate import validate_inputs
from tests.dcseg.io.arkit_scene import (
    CX,
    CY,
    DEPTH_HEIGHT,
    DEPTH_WIDTH,
    FX,
    FY,
    HEIGHT,
    VIEWS,
    WIDTH,
    assert_views_read,
    colour,
    confidence_map,
    depth_map,
)


def metadata() -> dict[str, Any]:
    k = [FX, 0.0, 0.0, 0.0, FY, 0.0, CX, CY, 1.0]  # column-major, as Record3D stores K
    poses = [[*v.quaternion, *v.translation] for v in VIEWS]
    return {"K": k, "w": WIDTH, "h": HEIGHT, "dw": DEPTH_WIDTH, "dh": DEPTH_HEIGHT,
            "fps": 60, "poses": poses, "initPose": [0, 0, 0, 1, 0, 0, 0]}  # fmt: skip


def write_r3d_folder(root: Path, meta: dict[str, Any] | None = None) -> Path:
    (root / "rgbd").mkdir(parents=True)
    (root / "metadata").write_text(json.dumps(meta or metadata()))
    for i, view in enumerate(VIEWS):
        write_image(root / "rgbd" / f"{i}.jpg", colour(i))
        (root / "rgbd" / f"{i}.depth").write_bytes(compress(depth_map(view).tobytes()))
        (root / "rgbd" / f"{i}.conf").write_bytes(compress(confidence_map().tobytes()))
    return root


def write_r3d_file(folder: Path, path: Path) -> Path:
    with zipfile.ZipFile(path, "w") as zf:
        for file in sorted(folder.rglob("*")):
            zf.write(file, file.relative_to(folder).as_posix())
    return path


@pytest.fixture
def r3d(tmp_path: Path) -> Path:
    return write_r3d_folder(tmp_path / "scan")


def test_folder_is_detected_and_read(r3d: Path) -> None:
    assert detect_layout(r3d) == "record3d"
    capture = read_capture(r3d)
    assert capture.layout == "record3d"
    assert [f.name for f in capture.frames] == ["0", "1", "2"]
    assert capture.frames[1].files["pose"] == "metadata:poses[1]"
    assert capture.frames[0].files["depth"] == "rgbd/0.depth"
    assert_views_read(capture)


def test_r3d_file_is_read_as_a_zip(r3d: Path, tmp_path: Path) -> None:
    capture = read_capture(write_r3d_file(r3d, tmp_path / "scan.r3d"))
    assert capture.root.endswith("scan.r3d")
    assert_views_read(capture)


def test_nan_depth_becomes_invalid(r3d: Path) -> None:
    depth = depth_map(VIEWS[2])
    depth[4, :] = np.nan
    (r3d / "rgbd" / "2.depth").write_bytes(compress(depth.tobytes()))
    frame = read_capture(r3d).frames[2]
    assert np.all(frame.depth[8:10] == 0.0)
    assert np.all(frame.depth[10:] == np.float32(2.0))


@pytest.mark.parametrize("level", [1, 2])
def test_min_confidence_masks_depth(r3d: Path, level: int) -> None:
    kept = read_capture(r3d).frames[0].depth
    masked = read_capture(r3d, CaptureOptions(min_confidence=level)).frames[0]
    low = (confidence_map() < level)[np.arange(HEIGHT) // 2][:, np.arange(WIDTH) // 2]
    assert np.all(masked.depth[low] == 0.0)
    np.testing.assert_array_equal(masked.depth[~low], kept[~low])
    assert masked.files["confidence"] == "rgbd/0.conf"
    assert 0 < int(low.sum()) < low.size


def test_confidence_is_read_only_when_asked(r3d: Path) -> None:
    (r3d / "rgbd" / "0.conf").unlink()
    assert len(read_capture(r3d)) == 3
    with pytest.raises(InputError, match=r"rgbd/0\.conf: missing"):
        read_capture(r3d, CaptureOptions(min_confidence=1))


def _error(root: Path, options: CaptureOptions | None = None) -> str:
    with pytest.raises(InputError) as caught:
        read_capture(root, options or CaptureOptions())
    report = validate_inputs(RunInputs(capture=root), options)
    assert [str(p) for p in report.problems] == [str(p) for p in caught.value.problems]
    return str(caught.value)


@pytest.mark.parametrize(
    ("change", "expected"),
    [
        ({"dw": None}, r"metadata: dw: missing"),
        ({"K": [1.0, 2.0]}, r"metadata: K: must be a 3x3 camera matrix as 9 numbers"),
        ({"w": 0}, r"metadata: w: must be a positive integer"),
        ({"poses": "no"}, r"metadata: poses: must be an array"),
    ],
)
def test_bad_metadata_fields_are_named(
    tmp_path: Path, change: dict[str, Any], expected: str
) -> None:
    meta = metadata()
    for key, value in change.items():
        if value is None:
            del meta[key]
        else:
            meta[key] = value
    assert expected in _error(write_r3d_folder(tmp_path / "scan", meta)).replace("\\", "")


def test_pose_count_mismatch_and_bad_quaternion(tmp_path: Path) -> None:
    meta = metadata()
    meta["poses"] = meta["poses"][:2]
    message = _error(write_r3d_folder(tmp_path / "few", meta))
    assert "metadata: poses: has 2 poses but rgbd/ holds 3 colour images" in message
    assert "metadata: poses: has no pose for rgbd/2.jpg (needs entry 2)" in message
    meta = metadata()
    meta["poses"][1] = [0.0, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0]
    message = _error(write_r3d_folder(tmp_path / "scaled", meta))
    assert "metadata: poses[1]: quaternion (qx, qy, qz, qw) has norm 2, expected 1" in message
    meta["poses"][1] = [0.0, 0.0, 1.0]
    message = _error(write_r3d_folder(tmp_path / "short", meta))
    assert "metadata: poses[1]: must be 7 numbers [qx, qy, qz, qw, tx, ty, tz]" in message


def test_invalid_metadata_json(r3d: Path) -> None:
    (r3d / "metadata").write_text("{not json")
    assert "metadata: invalid JSON" in _error(r3d)


def test_bad_depth_buffers_are_named_together(r3d: Path) -> None:
    small = np.ones((DEPTH_HEIGHT, DEPTH_WIDTH - 2), np.float32)
    (r3d / "rgbd" / "0.depth").write_bytes(compress(small.tobytes()))
    (r3d / "rgbd" / "1.depth").write_bytes(b"bvx2" + bytes(range(200)))
    good = compress(depth_map(VIEWS[2]).tobytes())
    (r3d / "rgbd" / "2.depth").write_bytes(good[: len(good) // 2])
    message = _error(r3d)
    assert (
        "rgbd/0.depth: decompresses to 360 bytes, not the 432 bytes of a 12x9 float32 buffer "
        "stated by the metadata"
    ) in message
    assert "rgbd/1.depth: cannot decompress (corrupt or not LZFSE data)" in message
    # a stream cut in half: the decoder runs out of input mid-block and asks for more room
    assert "rgbd/2.depth: decompresses to more than the 432 bytes" in message


def test_depth_that_expands_beyond_its_size_is_refused(r3d: Path) -> None:
    bomb = compress(np.zeros(DEPTH_WIDTH * DEPTH_HEIGHT * 1000, np.float32).tobytes())
    assert len(bomb) < DEPTH_WIDTH * DEPTH_HEIGHT * 4  # small on disk, 432 kB decoded
    (r3d / "rgbd" / "1.depth").write_bytes(bomb)
    message = _error(r3d)
    assert "rgbd/1.depth: decompresses to more than the 432 bytes of a 12x9 float32" in message


def test_oversized_file_and_empty_file(r3d: Path) -> None:
    (r3d / "rgbd" / "0.depth").write_bytes(bytes(432 + 5000))
    (r3d / "rgbd" / "1.depth").write_bytes(b"")
    message = _error(r3d)
    assert "rgbd/0.depth: compressed file has 5,432 bytes, more than its decoded size" in message
    assert "rgbd/1.depth: file is empty (expected LZFSE-compressed data)" in message


def test_decompressed_size_limit_is_a_limit_problem(
    r3d: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(limits, "MAX_DECOMPRESSED_BYTES", 400)
    report = validate_inputs(RunInputs(capture=r3d))
    assert report.problems and all(isinstance(p, LimitProblem) for p in report.problems)
    assert report.problems[0].limit == "max_decompressed_bytes"  # type: ignore[attr-defined]
    assert str(report.problems[0]) == (
        "rgbd/0.depth: a 12x9 buffer of float32 is 432 bytes, above the limit of 400 bytes; "
        "nothing was decoded"
    )


def test_confidence_errors(r3d: Path) -> None:
    (r3d / "rgbd" / "0.conf").write_bytes(
        compress(np.full(DEPTH_WIDTH * DEPTH_HEIGHT, 7, np.uint8).tobytes())
    )
    (r3d / "rgbd" / "1.conf").write_bytes(compress(bytes(10)))
    message = _error(r3d, CaptureOptions(min_confidence=2))
    assert "rgbd/0.conf: confidence values must be ARKit levels 0, 1 or 2, found 7" in message
    assert "rgbd/1.conf: decompresses to 10 bytes, not the 108 bytes of a 12x9 uint8" in message


def test_missing_parts_and_image_size(r3d: Path) -> None:
    (r3d / "rgbd" / "2.depth").unlink()
    write_image(r3d / "rgbd" / "1.jpg", np.zeros((10, 10, 3), np.uint8))
    message = _error(r3d)
    assert "rgbd/2.depth: missing (colour rgbd/2.jpg has no depth)" in message
    assert "metadata:K: intrinsics are for 24x18 but the image rgbd/1.jpg is 10x10" in message


# --------------------------------------------------------------------------- "EXR + JPG" export


def write_exr(path: Path, depth: np.ndarray, channels: tuple[str, ...] = ("R",)) -> None:
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    path.parent.mkdir(parents=True, exist_ok=True)
    with OpenEXR.File(header, dict.fromkeys(channels, depth)) as exr:
        exr.write(str(path))


def write_exr_export(root: Path, meta: dict[str, Any] | None = None) -> Path:
    meta = meta or metadata()
    root.mkdir(parents=True)
    (root / "metadata.json").write_text(json.dumps(meta))
    for i, view in enumerate(VIEWS):
        write_image(root / "rgb" / f"{i}.jpg", colour(i))
        write_exr(root / "depth" / f"{i}.exr", depth_map(view))
    return root


def test_exr_export_is_detected_and_read(tmp_path: Path) -> None:
    meta = metadata()
    del meta["dw"], meta["dh"]  # the EXR images state their size
    root = write_exr_export(tmp_path / "EXR_RGBD", meta)
    assert detect_layout(root) == "record3d-exr"
    capture = read_capture(root, CaptureOptions(min_confidence=2))  # no confidence: ignored
    assert capture.frames[0].files["depth"] == "depth/0.exr"
    assert capture.frames[2].files["pose"] == "metadata.json:poses[2]"
    assert_views_read(capture)


def test_exr_half_float_and_nan_depth(tmp_path: Path) -> None:
    root = write_exr_export(tmp_path / "EXR_RGBD")
    depth = depth_map(VIEWS[2]).astype(np.float16)
    depth[4, :] = np.nan
    write_exr(root / "depth" / "2.exr", depth)
    frame = read_capture(root).frames[2]
    assert np.all(frame.depth[8:10] == 0.0)
    assert np.all(frame.depth[10:] == np.float32(2.0))


def test_exr_export_errors(tmp_path: Path) -> None:
    meta = metadata()
    meta["poses"] = meta["poses"][:2]
    root = write_exr_export(tmp_path / "EXR_RGBD", meta)
    assert "metadata.json: poses: has 2 poses but rgb/ holds 3 colour images" in _error(root)
    root = write_exr_export(tmp_path / "other")
    (root / "depth" / "0.exr").write_bytes(b"not an exr at all")
    write_exr(root / "depth" / "1.exr", depth_map(VIEWS[1]), channels=("G", "B"))
    (root / "depth" / "2.exr").unlink()
    message = _error(root)
    assert "depth/0.exr: cannot read EXR header (corrupt or not an EXR image)" in message
    assert (
        "depth/1.exr: no depth channel: expected one of R, Y, Z, depth, got ['B', 'G']" in message
    )
    assert "depth/2.exr: missing (colour rgb/2.jpg has no depth)" in message


def test_exr_pixels_count_against_the_validation_budget(tmp_path: Path) -> None:
    root = write_exr_export(tmp_path / "EXR_RGBD")
    colour_px, depth_px = WIDTH * HEIGHT, DEPTH_WIDTH * DEPTH_HEIGHT
    budget = 3 * colour_px + 2 * depth_px + 50  # all colour fits, the third depth does not
    report = validate_inputs(RunInputs(capture=root), max_pixels=budget)
    assert len(report.problems) == 1
    assert isinstance(report.problems[0], LimitProblem)
    assert report.problems[0].path.endswith("depth/2.exr")  # counted from the EXR header
    assert "number 6 of those to decode" in report.problems[0].reason


def test_dcseg_validate_reports_r3d_problems(
    r3d: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    good = write_r3d_file(r3d, tmp_path / "good.r3d")
    fractions = []
    for level in ("0", "1"):
        assert main(["validate", str(good), "--min-confidence", level, "--json"]) == 0
        summary = json.loads(capsys.readouterr().out)["summary"]["capture"]
        assert summary["layout"] == "record3d"
        fractions.append(summary["depth_valid_fraction"])
    assert fractions[1] == pytest.approx(2 / 3)  # rows 0, 3, 6 of 9 have level 0
    (r3d / "rgbd" / "2.conf").unlink()
    bad = write_r3d_file(r3d, tmp_path / "bad.r3d")
    assert main(["validate", str(bad), "--min-confidence", "1"]) == 1
    assert "rgbd/2.conf: missing" in capsys.readouterr().out
