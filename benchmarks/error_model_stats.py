"""How consistent a synthetic scene's class-map errors are across views (no training).

Per ground-truth object (``kind`` object or furniture) of a ``dcseg synth`` scene: in every
view that shows at least ``--min-pixels`` of it, the class its pixels mostly get in the input
class map (``masks/semantic``; -1 = unlabelled). An object whose own class is not the most
frequent one over its views cannot be recovered by any vote over the class maps, however the
views are weighted; geometry alone does not name a class.

    python -m benchmarks.error_model_stats SCENE [SCENE ...] --out FILE
"""

from __future__ import annotations

import argparse
import json
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray


def _read(path: Path) -> NDArray[Any]:
    import cv2

    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise SystemExit(f"{path}: not a readable image")
    return np.asarray(image)


def object_views(scene: Path, min_pixels: int, structure: bool = False) -> dict[int, Counter[int]]:
    """Per object id (and wall / floor id with ``structure``), how many views mostly give it
    each class (-1 = unlabelled)."""
    made = json.loads((scene / "scene.json").read_text(encoding="utf-8"))
    objects = {i["id"] for i in made["instances"] if structure or i["kind"] != "structure"}
    out: dict[int, Counter[int]] = {i: Counter() for i in objects}
    for path in sorted((scene / "gt" / "instance").glob("*.png")):
        ids = _read(path).astype(np.int64)
        classes = _read(scene / "masks" / "semantic" / path.name).astype(np.int64)
        classes[classes == 255] = -1
        for inst_id in objects:
            pixels = classes[ids == inst_id]
            if len(pixels) >= min_pixels:
                values, counts = np.unique(pixels, return_counts=True)
                out[inst_id][int(values[counts.argmax()])] += 1
    return out


def scene_stats(scene: Path, min_pixels: int) -> dict[str, Any]:
    """Shares of objects by how often their views name them right."""
    made = json.loads((scene / "scene.json").read_text(encoding="utf-8"))
    names = made["vocabulary"]
    truth = {i["id"]: names.index(i["class"]) for i in made["instances"]}
    rows = []
    for inst_id, votes in sorted(object_views(scene, min_pixels).items()):
        seen = sum(votes.values())
        if not seen:
            continue
        right = votes[truth[inst_id]] / seen
        top = votes.most_common(1)[0][0]
        rows.append(
            {
                "id": inst_id,
                "views": seen,
                "right_share": round(right, 3),
                "top": top,
                "labelled_top": labelled_top(votes),
            }
        )
    n = max(len(rows), 1)
    return {
        "scene": str(scene),
        "error_model": made.get("error_model"),
        "objects": len(rows),
        "wrong_in_every_view": round(sum(r["right_share"] == 0 for r in rows) / n, 3),
        "majority_wrong": round(sum(r["top"] != truth[r["id"]] for r in rows) / n, 3),
        "right_in_every_view": round(sum(r["right_share"] == 1 for r in rows) / n, 3),
        "labelled_majority_wrong": round(
            sum(r["labelled_top"] != truth[r["id"]] for r in rows) / n, 3
        ),
        **vote_bounds(scene, min_pixels),
        "per_object": rows,
    }


def labelled_top(votes: Counter[int]) -> int:
    """The class most views give an object, unlabelled views left out (-1 = none labels it)."""
    named = [(n, c) for c, n in votes.items() if c >= 0]
    return max(named)[1] if named else -1


def vote_bounds(scene: Path, min_pixels: int) -> dict[str, float]:
    """mIoU of the scene's ground-truth points (3D protocol's classes) under two per-object
    oracles with perfect geometry (every surface and object, walls and floor included, is one
    labelled unit): ``majority`` = each takes the class most of its labelled views give it
    (what any view-counting vote reaches at best), ``ceiling`` = each takes its true class
    when at least one view mostly gives it that class, else the majority (what any vote over
    the class maps reaches at best: an object no view names is lost whatever the weights)."""
    from dcseg.evaluate import EvaluateConfig, evaluate_scenes
    from dcseg.io.ground_truth import read_ground_truth

    made = json.loads((scene / "scene.json").read_text(encoding="utf-8"))
    names = made["vocabulary"]
    truth = {i["id"]: names.index(i["class"]) for i in made["instances"]}
    gt = read_ground_truth(scene / "gt" / "points.ply", len(names))
    assert gt.instances is not None
    majority = np.full(len(gt.labels), -1, dtype=np.int64)
    ceiling = majority.copy()
    for inst_id, votes in object_views(scene, min_pixels, structure=True).items():
        points = gt.instances == inst_id
        top = labelled_top(votes)
        majority[points] = top
        ceiling[points] = truth[inst_id] if votes[truth[inst_id]] else top
    cfg = EvaluateConfig()
    return {
        name: round(100 * evaluate_scenes([gt.labels], [pred], names, cfg)["miou"], 2)
        for name, pred in (("majority_miou", majority), ("ceiling_miou", ceiling))
    }


def main() -> None:
    p = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    p.add_argument("scenes", nargs="+", type=Path)
    p.add_argument("--min-pixels", type=int, default=20)
    p.add_argument("--out", type=Path)
    args = p.parse_args()
    found = [scene_stats(s, args.min_pixels) for s in args.scenes]
    for s in found:
        keys = (
            *("error_model", "objects", "wrong_in_every_view", "majority_wrong"),
            *("labelled_majority_wrong", "right_in_every_view", "majority_miou", "ceiling_miou"),
        )
        print(s["scene"], {k: s[k] for k in keys})
    if args.out:
        args.out.write_text(json.dumps(found, indent=1) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
