"""A run's rendered label maps against per-frame ground-truth class images: per-class IoU, and
how much of the unlabelled background the maps give an object's class.

For real captures whose ground truth is 2D (a class id per pixel per frame, 0 = background:
the Amazon Picking Challenge shelf sample, YCB-Video), where no 3D points exist to score. Both
images are read with OpenCV, not with dcseg's readers: the run's ``labels/<frame>.png`` hold
the vocabulary index + 1 (0 = none, ``docs/exports.md``); the ground truth holds the class id
that the run's vocabulary gave the same index (the masks the run was given, or others). A
ground-truth file belongs to a frame when its stem is the frame's name or adds one part name
(``frame-000000.segm.png``). Held-out frames (``--held-out``) are also reported apart.

    python -m benchmarks.label_maps_iou RUN GT_FOLDER --held-out frame-000000 frame-000008 \\
        --out benchmarks/results/background_share.json --name apc_shelf_after
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from benchmarks.entries import write_entry
from dcseg.io.folders import frame_of


def counts(
    predicted: NDArray[Any], truth: NDArray[Any], classes: Sequence[int]
) -> NDArray[np.int64]:
    """``[len(classes) + 1, 2]``: per class, pixels of both and of either; last row, background
    pixels (truth 0) and those ``predicted`` gives one of ``classes``. ``predicted`` holds
    class ids (-1 = none), ``truth`` class ids (0 = background)."""
    out = np.zeros((len(classes) + 1, 2), dtype=np.int64)
    for row, c in enumerate(classes):
        out[row] = (
            ((predicted == c) & (truth == c)).sum(),
            ((predicted == c) | (truth == c)).sum(),
        )
    background = truth == 0
    out[-1] = (background.sum(), (background & np.isin(predicted, classes)).sum())
    return out


def summary(table: NDArray[np.int64], classes: Sequence[int]) -> dict[str, Any]:
    """IoU (%) per class and their mean, and the share (%) of background labelled an object."""
    iou = 100.0 * table[:-1, 0] / np.maximum(table[:-1, 1], 1)
    return {
        "iou": {str(c): round(float(v), 1) for c, v in zip(classes, iou, strict=True)},
        "mean_iou": round(float(iou.mean()), 1) if len(iou) else None,
        "background_labelled": round(100.0 * float(table[-1, 1]) / max(int(table[-1, 0]), 1), 1),
    }


def read_png(path: Path) -> NDArray[np.int64]:
    """A single-channel PNG's values (OpenCV, unchanged depth)."""
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None or image.ndim != 2:
        raise ValueError(f"{path}: not a single-channel image")
    return image.astype(np.int64)


def _pairs(run: Path, truth: Path) -> dict[str, tuple[Path, Path]]:
    """Frame name -> (label map, ground-truth image), for frames with both."""
    maps = {p.stem: p for p in sorted((run / "labels").glob("*.png"))}
    found = {}
    for path in sorted(truth.glob("*.png")):
        frame = frame_of(path.stem, maps)
        if frame is not None:
            found[frame] = (maps[frame], path)
    return found


def score(pairs: Iterable[tuple[Path, Path]], classes: Sequence[int]) -> NDArray[np.int64]:
    """Summed :func:`counts` over (label map, ground truth) pairs, maps resized to the truth."""
    total = np.zeros((len(classes) + 1, 2), dtype=np.int64)
    for labels, truth_path in pairs:
        truth, predicted = read_png(truth_path), read_png(labels)
        if predicted.shape != truth.shape:
            size = (truth.shape[1], truth.shape[0])
            resized = cv2.resize(predicted.astype(np.uint16), size, interpolation=cv2.INTER_NEAREST)
            predicted = resized.astype(np.int64)
        total += counts(predicted - 1, truth, classes)
    return total


def main() -> None:
    p = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    p.add_argument("run", type=Path)
    p.add_argument("truth", type=Path, help="folder of per-frame ground-truth class PNGs")
    p.add_argument("--held-out", nargs="*", default=[], metavar="FRAME")
    p.add_argument("--out", type=Path)
    p.add_argument("--name", default="run")
    args = p.parse_args()
    pairs = _pairs(args.run, args.truth)
    if not pairs:
        raise SystemExit(f"{args.truth}: no ground-truth image of a frame of {args.run}/labels")
    classes = sorted({int(v) for _, t in pairs.values() for v in np.unique(read_png(t))} - {0})
    groups = {
        "all": list(pairs),
        "held_out": [f for f in pairs if f in args.held_out],
        "training": [f for f in pairs if f not in args.held_out],
    }
    result = {
        group: {
            "frames": len(frames),
            **summary(score([pairs[f] for f in frames], classes), classes),
        }
        for group, frames in groups.items()
        if frames
    }
    print(json.dumps(result, indent=1))
    if args.out is not None:
        write_entry(args.out, args.name, {"run": str(args.run), "truth": str(args.truth), **result})


if __name__ == "__main__":
    main()
