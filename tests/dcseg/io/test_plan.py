"""The frame budget (:mod:`dcseg.io.captures.plan`): working resolution, keyframes by camera
motion, the frame cap, their overrides, and reading only the planned frames and their masks."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
from numpy.typing import NDArray

from dcseg.config import BUDGET_PRESETS, NATIVE_BUDGET, CaptureOptions, FrameBudget
from dcseg.errors import InputError
from dcseg.io.captures import read_capture, read_planned
from dcseg.io.captures.manifest import write_capture
from dcseg.io.captures.plan import CaptureMeta, downscale_factor, keyframes, plan_capture
from dcseg.io.folders import FrameSelection
from dcseg.io.images import write_image
from dcseg.io.masks import masks_from_label_map, read_agnostic_masks, write_agnostic_json
from dcseg.io.semantic import read_semantic_maps
from dcseg.options import build_config, parse_options
from dcseg.types import Capture, Frame, Intrinsics, Vocabulary

FAST = BUDGET_PRESETS["fast"]


def poses(steps: list[tuple[float, float]]) -> NDArray[np.float64]:
    """``[F, 4, 4]`` poses: each step moves ``metres`` along x and turns ``degrees`` about y."""
    out, x, angle = [], 0.0, 0.0
    for metres, degrees in [(0.0, 0.0), *steps]:
        x, angle = x + metres, angle + degrees
        pose = np.eye(4)
        pose[:3, :3] = cv2.Rodrigues(np.array([0.0, math.radians(angle), 0.0]))[0]
        pose[0, 3] = x
        out.append(pose)
    return np.stack(out)


def meta(c2w: NDArray[np.float64], size: tuple[int, int] = (1200, 680)) -> CaptureMeta:
    return CaptureMeta(tuple(f"f{i}" for i in range(len(c2w))), c2w, size)


@pytest.mark.parametrize(
    ("size", "max_side", "factor", "working"),
    [
        ((1200, 680), 640, 2, (600, 340)),  # Replica
        ((1296, 968), 640, 3, (432, 323)),  # ScanNet colour
        ((640, 480), 640, 1, (640, 480)),
        ((641, 480), 640, 2, (320, 240)),  # one pixel over: the next integer factor
        ((1200, 680), 1600, 1, (1200, 680)),  # paper preset keeps Replica native
        ((4032, 3024), None, 1, (4032, 3024)),  # native
    ],
)
def test_the_smallest_integer_factor_fits_the_longer_side(size, max_side, factor, working):
    assert downscale_factor(size, max_side) == factor
    plan = plan_capture(meta(poses([(0.1, 0.0)]), size), replace(FAST, max_side=max_side))
    assert (plan.factor, plan.size, plan.output_size) == (factor, working, size)
    assert max_side is None or max(plan.size) <= max_side


def test_keyframes_follow_translation_and_rotation():
    budget = FrameBudget(max_keyframes=None, min_translation=0.01, min_rotation_deg=1.0)
    # 4 mm per frame: a keyframe every third frame (12 mm); 0.6 deg: every second (1.2 deg)
    walking, moved = keyframes(poses([(0.004, 0.0)] * 9), budget)
    assert walking == [0, 3, 6, 9] and moved == 4
    turning, _ = keyframes(poses([(0.0, 0.6)] * 6), budget)
    assert turning == [0, 2, 4, 6]
    still, _ = keyframes(poses([(0.0, 0.0)] * 5), budget)
    assert still == [0]
    every, _ = keyframes(poses([(0.0, 0.0)] * 5), NATIVE_BUDGET)
    assert every == [0, 1, 2, 3, 4, 5]


def test_a_frame_whose_pose_is_not_finite_is_kept_so_reading_reports_it():
    c2w = poses([(0.0, 0.0)] * 3)
    c2w[2, 0, 3] = np.nan
    assert keyframes(c2w, FAST)[0] == [0, 2, 3]


def test_the_cap_keeps_evenly_spaced_keyframes_first_and_last_included():
    c2w = poses([(0.05, 0.0)] * 99)
    plan = plan_capture(meta(c2w), replace(FAST, max_keyframes=10))
    assert plan.moved == 100 and len(plan.frames) == 10
    assert plan.frames[0] == 0 and plan.frames[-1] == 99
    gaps = np.diff(plan.frames)
    assert gaps.min() >= 10 and gaps.max() <= 12
    assert plan.names == tuple(f"f{i}" for i in plan.frames)


def test_native_and_all_lift_both_caps():
    options = parse_options({"budget": {"max_side": "native", "max_keyframes": "all"}})
    budget = build_config("fast", options).pipeline.budget
    plan = plan_capture(meta(poses([(0.05, 0.0)] * 299)), budget)
    assert (plan.factor, len(plan.frames)) == (1, 300)
    capped = plan_capture(meta(poses([(0.05, 0.0)] * 299)), FAST)
    assert (capped.factor, len(capped.frames)) == (2, 200)


def test_describe_and_summary_state_the_choice():
    plan = plan_capture(meta(poses([(0.05, 0.0)] * 59)), FAST)
    text = plan.describe()
    assert "training at 600x340 (1200x680 / 2" in text and "60 of 60 frames" in text
    assert "outputs at 1200x680" in text
    summary = plan.summary()
    assert summary["size"] == [600, 340] and summary["output_size"] == [1200, 680]
    assert summary["kept"] == 60 and summary["budget"]["max_keyframes"] == 200
    assert summary["frames"] == list(plan.names)


# --------------------------------------------------------------------------- reading


def write_moving_capture(root: Path, steps: list[tuple[float, float]]) -> Capture:
    """A 160x120 capture in dcseg's layout whose camera moves by ``steps``."""
    rng = np.random.default_rng(0)
    k = Intrinsics(100.0, 100.0, 79.5, 59.5, 160, 120)
    frames = tuple(
        Frame(
            f"{i:03d}",
            rng.integers(0, 256, (120, 160, 3), dtype=np.uint8),
            np.full((120, 160), 2.0, np.float32),
            k,
            pose,
        )
        for i, pose in enumerate(poses(steps))
    )
    capture = Capture(frames, "dcseg")
    write_capture(capture, root)
    return capture


def test_only_the_planned_frames_are_read_at_the_working_size(tmp_path: Path, monkeypatch):
    # frames 0-3 move 2 cm each, 4-5 stand still: keyframes 0, 1, 2, 3
    root = tmp_path / "cap"
    write_moving_capture(root, [(0.02, 0.0)] * 3 + [(0.0, 0.0)] * 2)
    decoded: list[str] = []
    import dcseg.io.captures.common as common

    original = common.read_colour

    def counting(path: Path, where: Path):
        decoded.append(path.name)
        return original(path, where)

    monkeypatch.setattr(common, "read_colour", counting)
    capture, plan = read_planned(
        root, CaptureOptions(), replace(FAST, max_side=80, max_keyframes=3)
    )
    assert plan.names == ("000", "002", "003") and plan.moved == 4
    assert capture.names == plan.names and len(decoded) == 3
    frame = capture.frames[0]
    assert (frame.width, frame.height) == (80, 60) and frame.intrinsics.fx == pytest.approx(50.0)
    assert plan.output_size == (160, 120)


def test_an_explicit_size_is_the_output_size_and_the_budget_divides_it(tmp_path: Path):
    root = tmp_path / "cap"
    write_moving_capture(root, [(0.02, 0.0)] * 2)
    capture, plan = read_planned(root, CaptureOptions(size=(120, 90)), replace(FAST, max_side=60))
    assert plan.output_size == (120, 90) and plan.size == (60, 45)
    assert (capture.frames[0].width, capture.frames[0].height) == (60, 45)
    with pytest.raises(InputError, match="larger than the image's 160x120"):
        read_planned(root, CaptureOptions(size=(320, 240)), FAST)


def test_the_native_budget_reads_what_read_capture_reads(tmp_path: Path):
    root = tmp_path / "cap"
    write_moving_capture(root, [(0.0, 0.0)] * 3)
    capture, plan = read_planned(root, CaptureOptions(stride=2))
    assert capture.names == read_capture(root, CaptureOptions(stride=2)).names == ("000", "002")
    assert plan.listed == ("000", "002") and plan.factor == 1


def _label_png(path: Path) -> None:
    labels = np.zeros((120, 160), np.uint16)
    labels[:60] = 1
    write_image(path, labels)


def test_masks_are_read_for_the_selected_frames_only(tmp_path: Path):
    folder = tmp_path / "agnostic"
    folder.mkdir()
    _label_png(folder / "000.png")
    (folder / "001.png").write_bytes(b"not a png")  # listed, not selected: never decoded
    selection = FrameSelection(frozenset({"000"}), frozenset({"000", "001"}))
    masks = read_agnostic_masks(folder, size=(80, 60), frames=selection)
    assert list(masks) == ["000"] and (masks["000"].width, masks["000"].height) == (80, 60)
    with pytest.raises(InputError, match="001.png"):  # selected: its problem is reported
        read_agnostic_masks(folder, frames=replace(selection, read=frozenset({"000", "001"})))


def test_masks_of_frames_the_capture_lacks_are_refused(tmp_path: Path):
    folder = tmp_path / "agnostic"
    folder.mkdir()
    masks = masks_from_label_map("ghost", np.ones((12, 16), np.int64))
    write_agnostic_json(folder / "ghost.json", masks)
    selection = FrameSelection(frozenset({"000"}), frozenset({"000", "001"}))
    with pytest.raises(InputError, match="masks for frames the capture lacks: ghost"):
        read_agnostic_masks(folder, frames=selection)


def test_class_maps_are_read_for_the_selected_frames_only(tmp_path: Path):
    folder = tmp_path / "semantic"
    folder.mkdir()
    write_image(folder / "000.png", np.zeros((120, 160), np.uint8))
    (folder / "001.png").write_bytes(b"broken")
    selection = FrameSelection(frozenset({"000"}), frozenset({"000", "001"}))
    maps = read_semantic_maps(folder, Vocabulary(("wall",)), size=(80, 60), frames=selection)
    assert list(maps) == ["000"] and maps["000"].classes.shape == (60, 80)
    write_image(folder / "zzz.png", np.zeros((120, 160), np.uint8))
    with pytest.raises(InputError, match="class maps for frames the capture lacks: zzz"):
        read_semantic_maps(folder, Vocabulary(("wall",)), frames=selection)


def test_mask_files_that_add_a_part_name_to_the_frame_are_that_frame_s(tmp_path: Path):
    """``frame-000000.segm.png`` beside 7-Scenes' ``frame-000000.color.png`` (the Amazon
    Picking Challenge data), ``000001-label.png`` (YCB-Video): read for those frames."""
    agnostic, semantic = tmp_path / "agnostic", tmp_path / "semantic"
    agnostic.mkdir()
    semantic.mkdir()
    _label_png(agnostic / "frame-000000.segm.png")
    _label_png(agnostic / "frame-000001_mask.png")
    write_image(semantic / "frame-000000-label.png", np.zeros((120, 160), np.uint8))
    frames = frozenset({"frame-000000", "frame-000001"})
    masks = read_agnostic_masks(agnostic, frames=FrameSelection(frames, frames))
    assert sorted(masks) == ["frame-000000", "frame-000001"]
    assert len(masks["frame-000000"]) > 0 and masks["frame-000000"].name == "frame-000000"
    maps = read_semantic_maps(
        semantic, Vocabulary(("wall",)), frames=FrameSelection(frames, frames)
    )
    assert list(maps) == ["frame-000000"] and maps["frame-000000"].name == "frame-000000"


def test_two_files_of_one_frame_are_refused(tmp_path: Path):
    folder = tmp_path / "agnostic"
    folder.mkdir()
    _label_png(folder / "000.png")
    _label_png(folder / "000.segm.png")
    selection = FrameSelection(frozenset({"000"}), frozenset({"000", "001"}))
    with pytest.raises(InputError, match=r"frame '000' has several masks: 000, 000\.segm"):
        read_agnostic_masks(folder, frames=selection)


def test_a_numbered_stem_is_no_part_name(tmp_path: Path):
    """``000-001`` is not frame ``000``'s: only an alphabetic last part is taken off."""
    folder = tmp_path / "agnostic"
    folder.mkdir()
    _label_png(folder / "000-001.png")
    selection = FrameSelection(frozenset({"000"}), frozenset({"000"}))
    with pytest.raises(InputError, match="masks for frames the capture lacks: 000-001"):
        read_agnostic_masks(folder, frames=selection)
