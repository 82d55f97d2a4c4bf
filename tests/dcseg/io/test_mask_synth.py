"""End to end: a ``dcseg synth`` scene's masks converted into each accepted format read back
equal to the originals, and ``dcseg validate`` names the format it detected per folder."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pycocotools.mask as mask_util
import pytest

from dcseg.cli import main
from dcseg.inputs import RunInputs
from dcseg.io.mask_formats import detect_masks
from dcseg.io.masks import decode_masks, read_agnostic_masks
from dcseg.io.semantic import read_semantic_maps, read_vocabulary
from dcseg.io.validate import validate_inputs
from dcseg.types import SemanticMap
from tests.dcseg.io.mask_files import write_json, write_palette_png, write_panoptic_png

pytest.importorskip("pybullet", reason="the synthetic scene generator needs pybullet")


@pytest.fixture(scope="module")
def scene(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("synth") / "scene"
    args = ["synth", str(out), "--frames", "6", "--size", "64x48", "--noise", "clean"]
    assert main(args) == 0
    return out


def originals(scene: Path) -> dict[str, SemanticMap]:
    return read_semantic_maps(
        scene / "masks" / "semantic", read_vocabulary(scene / "vocabulary.txt")
    )


def inputs(scene: Path, agnostic: Path, semantic: Path) -> RunInputs:
    return RunInputs(scene, agnostic, semantic, scene / "vocabulary.txt")


def test_class_maps_as_palette_pngs(scene: Path, tmp_path: Path) -> None:
    maps = originals(scene)
    for name, m in maps.items():
        write_palette_png(tmp_path / "sem" / f"{name}.png", np.where(m.classes < 0, 255, m.classes))
    vocabulary = read_vocabulary(scene / "vocabulary.txt")
    read = read_semantic_maps(tmp_path / "sem", vocabulary)
    assert sorted(read) == sorted(maps)
    for name, m in maps.items():
        np.testing.assert_array_equal(read[name].classes, m.classes)
    report = validate_inputs(inputs(scene, scene / "masks" / "agnostic", tmp_path / "sem"))
    assert report.ok, report.problems
    assert report.summary["semantic_masks"]["format"] == "per-frame: palette PNG x6"
    assert report.summary["agnostic_masks"]["format"] == "per-frame: SAM JSON x6"


def write_coco_panoptic(scene: Path, folder: Path) -> None:
    """The scene's class maps as COCO panoptic: one segment per class present, id = class +
    1000 (G channel used), category ids = vocabulary index + 1, named in ``categories``."""
    vocabulary = read_vocabulary(scene / "vocabulary.txt")
    annotations = []
    for i, (name, m) in enumerate(sorted(originals(scene).items())):
        ids = np.where(m.classes < 0, 0, m.classes + 1000)
        write_panoptic_png(folder / "panoptic" / f"{name}.png", ids)
        segments = [
            {"id": int(c) + 1000, "category_id": int(c) + 1, "isthing": 0}
            for c in np.unique(m.classes)
            if c >= 0
        ]
        annotations.append({"image_id": i, "file_name": f"{name}.png", "segments_info": segments})
    categories = [{"id": i + 1, "name": n, "isthing": 0} for i, n in enumerate(vocabulary.names)]
    write_json(folder / "panoptic.json", {"annotations": annotations, "categories": categories})


def test_class_maps_as_coco_panoptic(scene: Path, tmp_path: Path) -> None:
    """The class maps read back unchanged and every segment is one agnostic mask."""
    maps = originals(scene)
    vocabulary = read_vocabulary(scene / "vocabulary.txt")
    write_coco_panoptic(scene, tmp_path / "pan")
    read = read_semantic_maps(tmp_path / "pan", vocabulary)
    masks = read_agnostic_masks(tmp_path / "pan")
    for name, m in maps.items():
        np.testing.assert_array_equal(read[name].classes, m.classes)
        present = [c for c in np.unique(m.classes) if c >= 0]
        np.testing.assert_array_equal(decode_masks(masks[name]), [m.classes == c for c in present])
    report = validate_inputs(inputs(scene, tmp_path / "pan", tmp_path / "pan"))
    assert report.ok, report.problems
    assert report.summary["agnostic_masks"]["format"] == "coco-panoptic (panoptic.json)"
    assert report.summary["semantic_masks"]["format"] == "coco-panoptic (panoptic.json)"


def test_agnostic_masks_as_one_coco_instance_json(
    scene: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Every SAM record of every frame as a COCO annotation (RLE), all frames in one file."""
    sam = read_agnostic_masks(scene / "masks" / "agnostic")
    images: list[dict[str, Any]] = []
    annotations: list[dict[str, Any]] = []
    for i, (name, masks) in enumerate(sorted(sam.items())):
        images.append(
            {"id": i, "file_name": f"{name}.jpg", "height": masks.height, "width": masks.width}
        )
        for rle in masks.rles:
            segmentation = {"size": rle["size"], "counts": rle["counts"].decode()}
            annotations.append(
                {
                    "id": len(annotations),
                    "image_id": i,
                    "category_id": 1,
                    "segmentation": segmentation,
                }
            )
    write_json(tmp_path / "coco" / "instances.json", {"images": images, "annotations": annotations})
    read = read_agnostic_masks(tmp_path / "coco")
    assert sorted(read) == sorted(sam) and sum(len(m) for m in read.values()) == len(annotations)
    for name, masks in sam.items():
        np.testing.assert_array_equal(decode_masks(read[name]), decode_masks(masks))
    report = validate_inputs(
        inputs(scene, tmp_path / "coco" / "instances.json", scene / "masks" / "semantic")
    )
    assert report.ok, report.problems
    assert report.summary["agnostic_masks"]["format"] == "coco-instances (instances.json)"
    args = ["validate", str(scene), "--agnostic-masks", str(tmp_path / "coco" / "instances.json")]
    assert main(args) == 0
    assert "  format: coco-instances (instances.json)\n" in capsys.readouterr().out


def test_class_maps_as_coco_instances(scene: Path, tmp_path: Path) -> None:
    """One annotation per class region (RLE), categories named: the class maps read back."""
    maps = originals(scene)
    vocabulary = read_vocabulary(scene / "vocabulary.txt")
    images: list[dict[str, Any]] = []
    annotations: list[dict[str, Any]] = []
    for i, (name, m) in enumerate(sorted(maps.items())):
        height, width = m.classes.shape
        images.append({"id": i, "file_name": f"{name}.png", "height": height, "width": width})
        for c in np.unique(m.classes[m.classes >= 0]):
            rle = mask_util.encode(np.asfortranarray((m.classes == c).astype(np.uint8)))
            segmentation = {"size": rle["size"], "counts": rle["counts"].decode()}
            annotation = {"id": len(annotations), "image_id": i, "segmentation": segmentation}
            annotations.append({**annotation, "category_id": 100 + int(c)})
    categories = [{"id": 100 + i, "name": n} for i, n in enumerate(vocabulary.names)]
    data = {"images": images, "annotations": annotations, "categories": categories}
    write_json(tmp_path / "coco.json", data)
    read = read_semantic_maps(tmp_path / "coco.json", vocabulary)
    for name, m in maps.items():
        np.testing.assert_array_equal(read[name].classes, m.classes)
    report = validate_inputs(inputs(scene, tmp_path / "coco.json", tmp_path / "coco.json"))
    assert report.ok, report.problems
    assert report.summary["semantic_masks"]["format"] == "coco-instances (coco.json)"


def test_agnostic_masks_as_npz_stacks(scene: Path, tmp_path: Path) -> None:
    sam = read_agnostic_masks(scene / "masks" / "agnostic")
    for name, masks in sam.items():
        dense = decode_masks(masks)
        np.savez_compressed(tmp_path / f"{name}.npz", masks=dense, scores=np.ones(len(dense)))
    read = read_agnostic_masks(tmp_path)
    for name, masks in sam.items():
        np.testing.assert_array_equal(decode_masks(read[name]), decode_masks(masks))
    report = validate_inputs(inputs(scene, tmp_path, scene / "masks" / "semantic"))
    assert report.ok, report.problems
    assert report.summary["agnostic_masks"]["format"] == "per-frame: NPZ mask stack x6"
    frames = 6 * 64 * 48
    budget = 3 * frames + 1  # colour, depth and class maps fit; the stacks' headers do not
    over = validate_inputs(inputs(scene, tmp_path, scene / "masks" / "semantic"), max_pixels=budget)
    (problem,) = over.problems
    assert problem.path.endswith(".npz") and "nothing was decoded" in problem.reason


def test_bundle_masks_panoptic_is_one_source_for_both(scene: Path, tmp_path: Path) -> None:
    root = tmp_path / "bundle"
    shutil.copytree(scene, root)
    write_coco_panoptic(scene, root / "masks" / "panoptic")
    shutil.rmtree(root / "masks" / "agnostic")
    shutil.rmtree(root / "masks" / "semantic")
    bundle = RunInputs.from_bundle(root)
    assert bundle.agnostic_masks == bundle.semantic_masks == root / "masks" / "panoptic"
    report = validate_inputs(bundle)
    assert report.ok, report.problems
    assert report.summary["semantic_masks"]["frames"] == 6


def test_validate_names_a_broken_panoptic_folder(scene: Path, tmp_path: Path) -> None:
    name = sorted(originals(scene))[0]
    shutil.rmtree(tmp_path / "pan", ignore_errors=True)
    write_panoptic_png(tmp_path / "pan" / f"{name}.png", np.full((48, 64), 7))
    write_json(tmp_path / "pan" / f"{name}.json", [{"id": 8, "category_id": 0}])
    assert detect_masks(tmp_path / "pan").kind == "panoptic-pairs"
    report = validate_inputs(inputs(scene, tmp_path / "pan", tmp_path / "pan"))
    reasons = {str(p) for p in report.problems}
    assert (
        f"pan/{name}.png: panoptic id 7 (RGB 7,0,0) not in the segments_info of pan/{name}.json"
        in reasons
    )
