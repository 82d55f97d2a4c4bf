"""The Amazon Picking Challenge shelf sample as a 7-Scenes-layout capture dcseg reads.

Source: ``andyzeng/apc-vision-toolbox`` (Simplified BSD), ``data/sample/scene-0000``: 15
Intel RealSense SR300 frames of one shelf bin from a robot arm, ``frame-NNNNNN.color.png``,
``frame-NNNNNN.depth.png`` (aligned to colour) and ``cam.info.txt`` (intrinsics and each
frame's camera-to-world pose), ground-truth masks in ``segm/frame-NNNNNN.segm.png`` (6 x the
object's id, 0 = the unlabelled shelf). Never committed: fetch the repository and give its
folder. The depth is uint16 in 1/10000 m, circularly shifted by 3 bits (the repository's
``rgbd-utils/matlab/readDepth.m``); it is written in millimetres. Then:

    python -m benchmarks.apc_capture SCENE_0000 APC7S
    dcseg run APC7S --intrinsics 615.195,615.195,298.443,247.519 \\
        --semantic-masks SCENE_0000/segm --agnostic-masks SCENE_0000/segm \\
        --vocabulary VOCABULARY --unlabelled-id 0 --out RUN

with a vocabulary of 145 lines whose lines 48, 114, 132 and 144 name the objects
(:func:`vocabulary`).
"""

from __future__ import annotations

import argparse
import re
import shutil
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

POSE = re.compile(r"Camera-to-world extrinsic matrix \(camera pose\) for (frame-\d+)")
"""The heading of each frame's pose block in ``cam.info.txt``."""


def depth_mm(raw: NDArray[Any]) -> NDArray[np.uint16]:
    """Millimetres from the sample's depth PNG values (3-bit circular shift, 1/10000 m).

    Example:
        >>> v = np.array([1234 * 10], np.uint32)  # 1.234 m
        >>> depth_mm((((v << 3) | (v >> 13)) & 0xFFFF).astype(np.uint16)).tolist()
        [1234]
    """
    v = raw.astype(np.uint32)
    tenths = ((v << 13) | (v >> 3)) & 0xFFFF
    return np.round(tenths / 10.0).astype(np.uint16)


def poses(info: str) -> dict[str, NDArray[np.float64]]:
    """Frame name -> 4x4 camera-to-world pose, from ``cam.info.txt``'s text."""
    lines = info.splitlines()
    found = {}
    for i, line in enumerate(lines):
        match = POSE.search(line)
        if match:
            found[match.group(1)] = np.array(
                [[float(x) for x in lines[i + 1 + r].split()] for r in range(4)]
            )
    return found


def vocabulary(names: dict[int, str], size: int = 145) -> list[str]:
    """``size`` class names, object ``k`` at line ``6 k`` (its ``segm`` value), placeholders
    elsewhere."""
    out = ["background"] + [f"unused_{i}" for i in range(1, size)]
    for k, name in names.items():
        out[6 * k] = name
    return out


def convert(scene: Path, out: Path) -> int:
    """Write ``scene`` as a 7-Scenes-layout folder ``out``; returns the number of frames."""
    out.mkdir(parents=True, exist_ok=True)
    found = poses((scene / "cam.info.txt").read_text())
    for name, pose in sorted(found.items()):
        raw = cv2.imread(str(scene / f"{name}.depth.png"), cv2.IMREAD_UNCHANGED)
        if raw is None or raw.dtype != np.uint16:
            raise ValueError(f"{scene / name}.depth.png: not a 16-bit depth image")
        cv2.imwrite(str(out / f"{name}.depth.png"), depth_mm(raw))
        shutil.copy(scene / f"{name}.color.png", out / f"{name}.color.png")
        np.savetxt(out / f"{name}.pose.txt", pose)
    return len(found)


def main() -> None:
    p = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    p.add_argument("scene", type=Path, help="the sample's data/sample/scene-0000 folder")
    p.add_argument("out", type=Path)
    p.add_argument("--vocabulary", type=Path, help="also write the 145-line vocabulary here")
    args = p.parse_args()
    print(f"{convert(args.scene, args.out)} frames written to {args.out}")
    if args.vocabulary is not None:
        names = {
            8: "creativity_chenille_stems",
            19: "i_am_a_bunny_book",
            22: "kleenex_tissue_box",
            24: "laugh_out_loud_joke_book",
        }
        args.vocabulary.write_text("\n".join(vocabulary(names)) + "\n")


if __name__ == "__main__":
    main()
