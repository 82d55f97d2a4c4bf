"""Every capture layout and mask format, with one file damaged many ways: the readers name the
problem (InputError) or read frames that are still sound; nothing else escapes.

The damage is seeded (``mutations.mutate``). Mutating fixtures this way found a COCO polygon
that crashed the process inside pycocotools, a 75 GiB allocation from an ``.npy`` header, null
JSON fields failing with assertions, and non-finite numbers failing with Python errors.
"""

from __future__ import annotations

import random
import shutil
from collections.abc import Callable, Iterator
from pathlib import Path

import cv2
import numpy as np
import pytest

from dcseg.config import CaptureOptions
from dcseg.errors import InputError
from dcseg.io.captures import read_capture
from dcseg.io.captures.manifest import write_capture
from dcseg.io.masks import decode_masks, read_agnostic_masks
from dcseg.io.semantic import read_semantic_maps
from dcseg.types import Capture, Vocabulary
from tests.dcseg.io.layouts import (
    RgbdScene,
    make_scene,
    scene_capture,
    write_7scenes,
    write_nerfstudio,
    write_replica,
    write_scannet,
)
from tests.dcseg.io.mask_files import write_json, write_palette_png
from tests.dcseg.io.mutations import mutate
from tests.dcseg.io.test_captures_arkitscenes import write_arkitscenes
from tests.dcseg.io.test_captures_colmap import write_colmap
from tests.dcseg.io.test_captures_polycam import write_polycam
from tests.dcseg.io.test_captures_record3d import write_r3d_folder
from tests.dcseg.io.test_captures_redwood import write_redwood
from tests.dcseg.io.test_captures_scannetpp import write_scannetpp
from tests.dcseg.io.test_captures_sens import write_sens
from tests.dcseg.io.test_captures_stray import write_stray
from tests.dcseg.io.test_captures_tum import write_tum
from tests.dcseg.io.test_mask_coco import SQUARE, TRIANGLE, coco
from tests.dcseg.io.test_mask_palette import davis_map
from tests.dcseg.io.test_mask_panoptic import write_coco_panoptic
from tests.dcseg.io.test_mask_stacks import sam_records, stack

MUTATIONS = 30
IMAGES = {".png", ".jpg", ".jpeg", ".exr", ".mp4", ".depth", ".conf"}
Write = Callable[[RgbdScene, Path], Path]

CAPTURES: dict[str, Write] = {
    "scannet": lambda s, r: write_scannet(s, r),
    "replica": lambda s, r: write_replica(s, r),
    "nerfstudio": lambda s, r: write_nerfstudio(s, r),
    "7scenes": lambda s, r: write_7scenes(s, r),
    "arkitscenes": lambda s, r: write_arkitscenes(s, r),
    "colmap binary": lambda s, r: write_colmap(s, r, binary=True),
    "colmap text": lambda s, r: write_colmap(s, r, binary=False),
    "redwood": lambda s, r: write_redwood(s, r),
    "scannet++": lambda s, r: write_scannetpp(s, r),
    "sens": lambda s, r: write_sens(s, r / "scene.sens"),
    "stray": lambda s, r: write_stray(s, r),
    "tum": lambda s, r: write_tum(s, r),
    "polycam": lambda s, r: write_polycam(r),
    "record3d": lambda s, r: write_r3d_folder(r),
    "manifest": lambda s, r: write_capture(scene_capture(s), r),
}


def damaged_copies(
    base: Path, files: list[Path], seed: str, tmp_path: Path
) -> Iterator[tuple[Path, str]]:
    """``MUTATIONS`` copies of ``base``, each with one of ``files`` damaged (seeded by
    ``seed``), as ``(copy, what was damaged)``; each copy is removed once used."""
    rng = random.Random(seed)
    for i in range(MUTATIONS):
        work = tmp_path / f"m{i}"
        shutil.copytree(base, work)
        file = work / rng.choice(files).relative_to(base)
        done, data = mutate(file.read_bytes(), rng)
        file.write_bytes(data)
        yield work, f"{file.relative_to(work)}: {done}"
        shutil.rmtree(work)


def metadata_files(root: Path) -> list[Path]:
    """What a layout holds besides images (those have their own decoding tests)."""
    return sorted(p for p in root.rglob("*") if p.is_file() and p.suffix.lower() not in IMAGES)


def unsound(capture: Capture) -> str:
    """Why a capture read from damaged files must not have been accepted, or ""."""
    for frame in capture.frames:
        k = frame.intrinsics
        rotation = frame.c2w[:3, :3]
        if not np.isfinite(frame.c2w).all():
            return f"{frame.name}: pose not finite"
        if np.abs(rotation.T @ rotation - np.eye(3)).max() > 1e-3:
            return f"{frame.name}: pose not rigid"
        if not (np.isfinite([k.fx, k.fy, k.cx, k.cy]).all() and k.fx > 0 and k.fy > 0):
            return f"{frame.name}: intrinsics {k}"
        if not np.isfinite(frame.depth).all() or (frame.depth < 0).any():
            return f"{frame.name}: depth not finite or negative"
    return "" if capture.frames else "no frames"


@pytest.mark.parametrize("layout", sorted(CAPTURES))
def test_damaged_capture_is_named_or_read_soundly(layout: str, tmp_path: Path) -> None:
    scene = make_scene()
    k = scene.k
    given = (k.fx, k.fy, k.cx, k.cy) if layout in ("7scenes", "tum") else None
    options = CaptureOptions(intrinsics=given)
    base = tmp_path / "base"
    CAPTURES[layout](scene, base)
    target = base / "scene.sens" if layout == "sens" else base
    assert not unsound(read_capture(target, options))
    for work, where in damaged_copies(base, metadata_files(base), layout, tmp_path):
        try:
            capture = read_capture(work / target.relative_to(base), options)
        except InputError:
            pass
        except Exception as error:  # noqa: BLE001 - the point: name the mutation that escaped
            pytest.fail(f"{where}: {type(error).__name__}: {error}")
        else:
            assert not unsound(capture), where


def _coco(folder: Path) -> None:
    annotations = [
        {"id": 10, "image_id": 1, "category_id": 1, "segmentation": [SQUARE]},
        {"id": 14, "image_id": 2, "category_id": 1, "segmentation": TRIANGLE, "score": 0.4},
    ]
    write_json(folder / "instances.json", coco(annotations))


def _label_png(folder: Path) -> None:
    labels = np.zeros((6, 8), dtype=np.uint16)
    labels[1:3, 1:4], labels[3:, :2] = 1, 2
    cv2.imwrite(str(folder / "f.png"), labels)


MASKS: dict[str, Callable[[Path], object]] = {
    "coco": _coco,
    "coco panoptic": write_coco_panoptic,
    "npz stack": lambda d: np.savez(d / "f.npz", masks=stack(), scores=np.linspace(0.2, 0.9, 4)),
    "npy stack": lambda d: np.save(d / "a.npy", stack()),
    "sam json": lambda d: write_json(d / "f.json", sam_records(stack(), [0.9] * 4, [0.9] * 4)),
    "palette png": lambda d: write_palette_png(d / "00000.png", davis_map()),
    "label png": _label_png,
}


def _read_both(folder: Path, where: str) -> None:
    """Both readers, the agnostic masks decoded too; InputError is the only way out."""
    for read in (
        lambda: [decode_masks(m) for m in read_agnostic_masks(folder).values()],
        lambda: read_semantic_maps(folder, Vocabulary(("wall", "floor", "chair", "table"))),
    ):
        try:
            read()
        except InputError:
            pass
        except Exception as error:  # noqa: BLE001 - the point: name the mutation that escaped
            pytest.fail(f"{where}: {type(error).__name__}: {error}")


@pytest.mark.parametrize("kind", sorted(MASKS))
def test_damaged_mask_files_are_named(kind: str, tmp_path: Path) -> None:
    base = tmp_path / "base"
    base.mkdir()
    MASKS[kind](base)
    _read_both(base, "unchanged")
    files = sorted(p for p in base.rglob("*") if p.is_file())
    for work, where in damaged_copies(base, files, kind, tmp_path):
        _read_both(work, where)
