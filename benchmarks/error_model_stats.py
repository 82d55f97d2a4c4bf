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


def object_views(scene: Path, min_pixels: int) -> dict[int, Counter[int]]:
    """Per object id, how many views mostly give it each class (-1 = unlabelled)."""
    made = json.loads((scene / "scene.json").read_text(encoding="utf-8"))
    objects = {i["id"] for i in made["instances"] if i["kind"] != "structure"}
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
        rows.append({"id": inst_id, "views": seen, "right_share": round(right, 3), "top": top})
    n = max(len(rows), 1)
    return {
        "scene": str(scene),
        "error_model": made.get("error_model"),
        "objects": len(rows),
        "wrong_in_every_view": round(sum(r["right_share"] == 0 for r in rows) / n, 3),
        "majority_wrong": round(sum(r["top"] != truth[r["id"]] for r in rows) / n, 3),
        "right_in_every_view": round(sum(r["right_share"] == 1 for r in rows) / n, 3),
        "per_object": rows,
    }


def main() -> None:
    p = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    p.add_argument("scenes", nargs="+", type=Path)
    p.add_argument("--min-pixels", type=int, default=20)
    p.add_argument("--out", type=Path)
    args = p.parse_args()
    found = [scene_stats(s, args.min_pixels) for s in args.scenes]
    for s in found:
        keys = ("error_model", "objects", "wrong_in_every_view", "majority_wrong")
        print(s["scene"], {k: s[k] for k in (*keys, "right_in_every_view")})
    if args.out:
        args.out.write_text(json.dumps(found, indent=1) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
