"""Turn a real Replica-layout capture into a bundle with stand-in masks, for timing runs.

Real captures rarely come with 2D masks for every frame (the Replica sample has SAM masks for
frame 0 only). For cost measurements any masks of realistic count and size do: each frame's
colours are quantised, connected regions of one colour become class-agnostic masks at two
granularities (fine: 6 levels per channel; coarse: 3 levels, which merges neighbours) and
the coarse regions' colour bin names their class in a small vocabulary. The masks mean nothing
semantically; they cost what real ones cost. SciPy only (no model, nothing downloaded).

    python benchmarks/superpixel_bundle.py ../shared/data/replica_room0_small /tmp/replica \\
        --intrinsics 600,600,599.5,339.5

The bundle links the capture's files (``results/``, ``traj.txt``) instead of copying them,
writes ``cam_params.json`` with the given intrinsics, ``masks/agnostic/<stem>.json`` (COCO
RLE records, both granularities), ``masks/semantic/<stem>.png`` and ``vocabulary.txt``.
Masks are written at half the frames' resolution (rescaled by dcseg with nearest neighbour).
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray
from pycocotools import mask as mask_utils
from scipy import ndimage

from dcseg.io.images import read_image

COLOUR = re.compile(r"frame\d+\.(jpg|png)")
"""Colour frames of the Replica layout."""
CLASSES = 12
"""Size of the stand-in vocabulary."""
MIN_SHARE = 0.002
"""Regions below this share of the image are not masks."""


def regions(rgb: NDArray[np.uint8], levels: int) -> NDArray[np.int64]:
    """``[H, W]`` connected regions of equal quantised colour, 0 = too small."""
    bins = (rgb.astype(np.int64) * levels) // 256
    key = (bins[..., 0] * levels + bins[..., 1]) * levels + bins[..., 2]
    out = np.zeros(key.shape, dtype=np.int64)
    count = 0
    for value in np.unique(key):
        labelled, n = ndimage.label(key == value)
        if n == 0:
            continue
        sizes = np.bincount(labelled.ravel())[1:]
        keep = np.flatnonzero(sizes >= MIN_SHARE * key.size) + 1
        lookup = np.zeros(n + 1, dtype=np.int64)
        lookup[keep] = count + 1 + np.arange(len(keep))
        out = np.where(labelled > 0, np.maximum(out, lookup[labelled]), out)
        count += len(keep)
    return out


def rle_records(label_map: NDArray[np.int64]) -> list[dict[str, object]]:
    """One SAM-style record per region of ``label_map``."""
    records = []
    for value in np.unique(label_map[label_map > 0]):
        rle = mask_utils.encode(np.asfortranarray(label_map == value))
        rle["counts"] = rle["counts"].decode("ascii")
        records.append({"segmentation": rle, "area": int((label_map == value).sum())})
    return records


def classes_of(rgb: NDArray[np.uint8], coarse: NDArray[np.int64]) -> NDArray[np.uint8]:
    """Class per pixel: each coarse region's mean colour hashed into the vocabulary."""
    out = np.full(coarse.shape, 255, dtype=np.uint8)
    for value in np.unique(coarse[coarse > 0]):
        inside = coarse == value
        mean = rgb[inside].mean(axis=0).astype(np.int64) // 64
        out[inside] = int((mean[0] * 16 + mean[1] * 4 + mean[2]) % CLASSES)
    return out


def write_frame(rgb_path: Path, bundle: Path) -> None:
    image: NDArray[np.uint8] = read_image(rgb_path)
    height, width = image.shape[:2]
    small = np.asarray(
        cv2.resize(image, (width // 2, height // 2), interpolation=cv2.INTER_AREA), np.uint8
    )
    fine, coarse = regions(small, 6), regions(small, 3)
    records = rle_records(fine) + rle_records(coarse)
    stem = rgb_path.stem
    (bundle / "masks" / "agnostic" / f"{stem}.json").write_text(json.dumps(records))
    cv2.imwrite(str(bundle / "masks" / "semantic" / f"{stem}.png"), classes_of(small, coarse))


def make_bundle(capture: Path, bundle: Path, intrinsics: tuple[float, ...]) -> int:
    """Write the bundle; returns the number of frames."""
    (bundle / "masks" / "agnostic").mkdir(parents=True, exist_ok=True)
    (bundle / "masks" / "semantic").mkdir(parents=True, exist_ok=True)
    for name in ("results", "traj.txt"):
        link = bundle / name
        if not link.exists():
            link.symlink_to((capture / name).resolve())
    frames = sorted(p for p in (capture / "results").iterdir() if COLOUR.fullmatch(p.name))
    height, width = read_image(frames[0]).shape[:2]
    fx, fy, cx, cy = intrinsics
    camera = {"w": width, "h": height, "fx": fx, "fy": fy, "cx": cx, "cy": cy, "scale": 6553.5}
    (bundle / "cam_params.json").write_text(json.dumps({"camera": camera}))
    (bundle / "vocabulary.txt").write_text("".join(f"class{i}\n" for i in range(CLASSES)))
    for rgb_path in frames:
        write_frame(rgb_path, bundle)
    return len(frames)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("capture", type=Path)
    parser.add_argument("bundle", type=Path)
    parser.add_argument("--intrinsics", default="600,600,599.5,339.5", help="fx,fy,cx,cy")
    args = parser.parse_args()
    intrinsics = tuple(float(v) for v in args.intrinsics.split(","))
    count = make_bundle(args.capture, args.bundle, intrinsics)
    print(f"{args.bundle}: {count} frames with stand-in masks")
    return 0


if __name__ == "__main__":
    sys.exit(main())
