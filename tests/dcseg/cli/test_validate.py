"""`dcseg validate` on a synthetic scene, and on corrupted copies of it."""

from __future__ import annotations

import json
import shutil
import tarfile
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pytest

from dcseg.cli import main
from dcseg.inputs import RunInputs
from dcseg.io.images import read_image
from dcseg.io.validate import validate_inputs

pytest.importorskip("pybullet", reason="the synthetic scene generator needs pybullet")


@pytest.fixture(scope="module")
def scene(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("synth") / "scene"
    assert main(["synth", str(out), "--frames", "4", "--size", "64x48", "--seed", "3"]) == 0
    return out


@pytest.fixture
def copy(scene: Path, tmp_path: Path) -> Path:
    target = tmp_path / "scene"
    shutil.copytree(scene, target)
    return target


def paths_of(root: Path) -> RunInputs:
    return RunInputs(
        capture=root,
        agnostic_masks=root / "masks" / "agnostic",
        semantic_masks=root / "masks" / "semantic",
        vocabulary=root / "vocabulary.txt",
        ground_truth=root / "gt" / "points.ply",
    )


def cli_args(root: Path) -> list[str]:
    p = paths_of(root)
    return [
        "validate",
        str(root),
        "--agnostic-masks",
        str(p.agnostic_masks),
        "--semantic-masks",
        str(p.semantic_masks),
        "--vocabulary",
        str(p.vocabulary),
        "--gt",
        str(p.ground_truth),
    ]


def first_stem(root: Path) -> str:
    manifest = json.loads((root / "capture.json").read_text())
    return str(manifest["frames"][0]["name"])


def test_synthetic_scene_passes(scene: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(cli_args(scene)) == 0
    out = capsys.readouterr().out
    assert "frames: 4" in out and "resolution: 64x48" in out
    assert "OK: no problems found" in out
    report = validate_inputs(paths_of(scene))
    assert report.ok
    assert report.summary["agnostic_masks"]["frames"] == 4
    assert report.summary["semantic_masks"]["classes_present"]
    assert report.summary["ground_truth"]["labelled_points"] > 0


def test_masks_named_with_a_part_after_the_frame_pass(copy: Path) -> None:
    """``<frame>.segm.png`` and ``<frame>-label.png`` name their frames (the Amazon Picking
    Challenge and YCB-Video write them so); a stem with another frame's name does not."""
    stem = first_stem(copy)
    agnostic, semantic = copy / "masks" / "agnostic", copy / "masks" / "semantic"
    (agnostic / f"{stem}.json").rename(agnostic / f"{stem}.segm.json")
    (semantic / f"{stem}.png").rename(semantic / f"{stem}-label.png")
    report = validate_inputs(paths_of(copy))
    assert report.ok, report.problems
    assert report.summary["agnostic_masks"]["frames"] == 4
    (agnostic / f"{stem}.segm.json").rename(agnostic / f"{stem}.segm2.json")
    report = validate_inputs(paths_of(copy))
    assert [p.reason for p in report.problems] == [
        f"mask for frame '{stem}.segm2', which the capture lacks"
    ]


def test_two_mask_files_of_one_frame_are_named(copy: Path) -> None:
    """``<frame>.png`` and ``<frame>-label.png`` both claim the frame: validation says so, as
    the run's reader does."""
    stem = first_stem(copy)
    semantic = copy / "masks" / "semantic"
    shutil.copy(semantic / f"{stem}.png", semantic / f"{stem}-label.png")
    report = validate_inputs(paths_of(copy))
    assert [p.reason for p in report.problems] == [
        f"frame {stem!r} has several masks: semantic/{stem}.png, semantic/{stem}-label.png"
    ]


def test_json_report(scene: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main([*cli_args(scene), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["ok"] is True and report["problems"] == []


def corrupt_image(root: Path) -> str:
    target = root / "rgb" / f"{first_stem(root)}.png"
    target.write_bytes(b"not a png at all")
    return "cannot decode"


def missing_depth(root: Path) -> str:
    (root / "depth" / f"{first_stem(root)}.png").unlink()
    return "missing"


def depth_size_mismatch(root: Path) -> str:
    cv2.imwrite(str(root / "depth" / f"{first_stem(root)}.png"), np.ones((10, 10), np.uint16))
    return "does not match colour size"


def non_rigid_pose(root: Path) -> str:
    manifest = json.loads((root / "capture.json").read_text())
    manifest["frames"][1]["c2w"][0][0] = 3.0
    (root / "capture.json").write_text(json.dumps(manifest))
    return "not a rigid transform"


def mask_without_frame(root: Path) -> str:
    folder = root / "masks" / "agnostic"
    shutil.copy(folder / f"{first_stem(root)}.json", folder / "no_such_frame.json")
    return "mask for frame 'no_such_frame', which the capture lacks"


def class_beyond_vocabulary(root: Path) -> str:
    path = root / "masks" / "semantic" / f"{first_stem(root)}.png"
    classes = read_image(path).copy()
    classes[0, 0] = 200
    cv2.imwrite(str(path), classes)
    return "200"


def mask_aspect_mismatch(root: Path) -> str:
    path = root / "masks" / "semantic" / f"{first_stem(root)}.png"
    cv2.imwrite(str(path), np.zeros((10, 40), np.uint8))
    return "different aspect ratio"


def empty_capture(root: Path) -> str:
    manifest = json.loads((root / "capture.json").read_text())
    manifest["frames"] = []
    (root / "capture.json").write_text(json.dumps(manifest))
    return "empty"


CORRUPTIONS: list[Callable[[Path], str]] = [
    corrupt_image,
    missing_depth,
    depth_size_mismatch,
    non_rigid_pose,
    mask_without_frame,
    class_beyond_vocabulary,
    mask_aspect_mismatch,
    empty_capture,
]


@pytest.mark.parametrize("corrupt", CORRUPTIONS, ids=[c.__name__ for c in CORRUPTIONS])
def test_corrupted_variant_fails_with_reason(
    copy: Path, corrupt: Callable[[Path], str], capsys: pytest.CaptureFixture[str]
) -> None:
    expected = corrupt(copy)
    assert main(cli_args(copy)) == 1
    out = capsys.readouterr().out
    assert "problem(s):" in out
    assert expected in out, out


def test_every_problem_listed_at_once(copy: Path) -> None:
    # Masks are cross-checked against the listed frame names even when a frame is unreadable.
    reasons = [
        corrupt_image(copy),
        non_rigid_pose(copy),
        class_beyond_vocabulary(copy),
        mask_without_frame(copy),
    ]
    report = validate_inputs(paths_of(copy))
    text = "\n".join(str(p) for p in report.problems)
    for reason in reasons:
        assert reason in text, text


def test_archive_entry_escaping_folder(tmp_path: Path, scene: Path) -> None:
    archive = tmp_path / "capture.tar"
    with tarfile.open(archive, "w") as tar:
        tar.add(scene, arcname="scene")
        tar.add(scene / "capture.json", arcname="../evil.json")
    report = validate_inputs(RunInputs(capture=archive))
    assert not report.ok
    assert any("../evil.json" in str(p) for p in report.problems)
    assert not (tmp_path.parent / "evil.json").exists()


def test_archive_capture_passes(tmp_path: Path, scene: Path) -> None:
    archive = shutil.make_archive(str(tmp_path / "capture"), "zip", scene.parent, scene.name)
    report = validate_inputs(RunInputs(capture=Path(archive)))
    assert report.ok, report.problems
    assert report.summary["capture"]["frames"] == 4


def test_semantic_masks_need_vocabulary(scene: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["validate", str(scene), "--semantic-masks", str(scene / "masks" / "semantic")])
    assert code == 2
    assert "--vocabulary" in capsys.readouterr().err
