"""Segmentation on held-out synthetic layouts: both protocols, instances, two baselines.

Each noise level is run on several scene layouts (``dcseg synth --seed`` = layout). Defaults
are tuned on layouts 0-2 (``--tuning``) and layouts 3-4 are reported apart as held out
(``--heldout``). A layout is trained once (fast preset) into ``--work``; scoring re-segments
the saved state with the current code and defaults (nothing is retrained), at several
clustering seeds, so a change to clustering, masks or assignment is re-scored in minutes.

    python -m benchmarks.bench_segment --train --work WORK    # train what is missing
    python -m benchmarks.bench_segment --work WORK            # score the saved runs
    python -m benchmarks.bench_segment --work WORK --noise heavy --heldout 3 --tuning \
        --out one.json                                        # score one run
    python -m benchmarks.bench_segment --merge one.json two.json   # summarise runs scored apart
    python -m benchmarks.bench_segment --work WORK --set assign.complete=false   # an ablation

Scores go to ``--out`` (``benchmarks/results/segment_heldout.json``): every run's rows and a
summary per noise level and group (mean, sample standard deviation, range, count). Training
order puts the held-out layouts of every noise level before the tuning ones.

Per run and clustering seed: the 3D protocol (each ground-truth point takes the label of the
nearest Gaussian centre with opacity > 0.05 within 5 cm), the paper's projection protocol on
the rendered label maps, the share of ground-truth points without a prediction, and instance
metrics (one-to-one matches at IoU >= 0.5); baselines per run: naive 2D fusion (projection of
the input class maps) and the training-free 3D vote (:func:`dcseg.segment.vote_3d`), scored by
both protocols.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
import time
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402
import torch  # noqa: E402
from numpy.typing import NDArray  # noqa: E402
from plyfile import PlyData  # noqa: E402

from benchmarks.bench_handheld import ensure_scene  # noqa: E402
from dcseg.config import JobConfig, PipelineConfig, preset  # noqa: E402
from dcseg.evaluate import EvaluateConfig, evaluate_scenes, transfer_opaque, vote_projection  # noqa: E402
from dcseg.evaluate.instances import instance_metrics  # noqa: E402
from dcseg.io.ground_truth import read_ground_truth  # noqa: E402
from dcseg.io.run_output import SavedRun, load_labels, load_run, write_outputs  # noqa: E402
from dcseg.io.run_state import ViewState  # noqa: E402
from dcseg.jobs import RunInputs, run_job  # noqa: E402
from dcseg.pipeline import segment_scene  # noqa: E402
from dcseg.segment import class_evidence, vote_3d  # noqa: E402
from dcseg.segmentation import Labels, Segmentation  # noqa: E402
from dcseg.synth import SynthConfig  # noqa: E402
from dcseg.types import GroundTruth  # noqa: E402

TUNING = (0, 1, 2)
HELDOUT = (3, 4)
NOISES = ("clean", "default", "heavy", "realistic")
GENERATORS = ("detector", "lowres")
"""Segmenter-error generators (``dcseg synth --error-model``) scored like noise levels: masks
from the generator, depth noise of the ``default`` level. ``realistic`` (a noise level) is the
third generator (:mod:`dcseg.synth.errors`)."""
PROTOCOL = EvaluateConfig()
"""3D protocol (evaluation.md): the nearest Gaussian above ``min_opacity`` (0.05) within
``max_distance`` (5 cm)."""


def run_dir(work: Path, noise: str, layout: int) -> Path:
    return work / noise / f"layout{layout}"


def ensure_run(work: Path, noise: str, layout: int, args: argparse.Namespace) -> Path:
    """The trained run of one layout at one noise level, synthesised and trained if missing."""
    root = run_dir(work, noise, layout)
    scene = root / "scene"
    width, height = args.size
    generator = noise if noise in GENERATORS else ""
    synth = SynthConfig(
        seed=layout,
        frames=args.frames,
        width=width,
        height=height,
        noise="default" if generator else noise,
        error_model=generator,
        **synth_fields(args.synth),
    )
    start = time.perf_counter()
    ensure_scene(scene, synth)
    print(f"{noise} layout{layout}: scene in {time.perf_counter() - start:.0f} s", flush=True)
    run = root / "run"
    if not (run / "run.json").is_file():
        start = time.perf_counter()
        run_job(RunInputs.from_bundle(scene), JobConfig(train_config(args)), run)
        print(f"{noise} layout{layout}: trained in {time.perf_counter() - start:.0f} s", flush=True)
    return run


def key_value(item: str) -> tuple[str, Any]:
    """``KEY=JSON`` as ``(KEY, value)``; a value that is not JSON is a string."""
    key, _, text = item.partition("=")
    try:
        return key, json.loads(text)
    except json.JSONDecodeError:
        return key, text


def synth_fields(items: Sequence[str]) -> dict[str, Any]:
    """``--synth`` ``KEY=JSON`` items as :class:`SynthConfig` fields (handheld faults:
    ``pose_error_deg``, ``pose_error_m``, ``motion_blur_px``, ``depth_sigma``)."""
    fields = dict(key_value(item) for item in items)
    for key in fields.keys() & {"seed", "frames", "width", "height", "noise", "error_model"}:
        raise SystemExit(f"--synth {key}: set by the layout, --frames, --size or --noise")
    return fields


def train_config(args: argparse.Namespace) -> PipelineConfig:
    """The fast preset with ``--pipeline-seed`` and the ``--set`` overrides (training reads
    its ``reconstruct``, ``cache`` and ``affinity`` sections); iteration overrides only for
    smoke runs."""
    cfg = overridden(preset("fast").seeded(args.pipeline_seed), args.set)
    if args.reconstruct_iterations is not None:
        cfg = replace(
            cfg, reconstruct=replace(cfg.reconstruct, iterations=args.reconstruct_iterations)
        )
    if args.affinity_iterations is not None:
        cfg = replace(cfg, affinity=replace(cfg.affinity, iterations=args.affinity_iterations))
    return cfg


def train(args: argparse.Namespace) -> None:
    """Train the missing runs: held-out layouts of every noise level first, then tuning ones."""
    for group in (args.heldout, args.tuning):
        for noise in args.noise:
            for layout in group:
                ensure_run(args.work, noise, layout, args)


class Scorer:
    """The ground truth of one run and the protocols that label its points."""

    def __init__(self, saved: SavedRun, gt: GroundTruth, depth_tol: float) -> None:
        g = saved.trained.gaussians
        self.opacities = g.opacities().detach().cpu().numpy()
        self.means = g.means.detach().cpu().numpy()
        self.views = saved.trained.views
        self.gt, self.names = gt, saved.vocabulary.names
        self.depth_tol = depth_tol

    def nearest(self, per_gaussian: NDArray[Any]) -> NDArray[np.int64]:
        """3D protocol: each point takes the value of the nearest opaque Gaussian within 5 cm."""
        values = np.asarray(per_gaussian)
        return transfer_opaque(self.means, self.opacities, values, self.gt.points, PROTOCOL)

    def projection(
        self, images: Sequence[NDArray[Any]], views: Sequence[ViewState]
    ) -> NDArray[np.int64]:
        """The paper's protocol: majority vote of the label images that see each point."""
        return vote_projection(
            self.gt.points, images, [v.depth for v in views], [v.K for v in views],
            [v.c2w for v in views], len(self.names), self.depth_tol,
        )  # fmt: skip

    def semantic(self, pred: NDArray[np.int64]) -> dict[str, float]:
        m = evaluate_scenes([self.gt.labels], [pred], self.names, EvaluateConfig())
        return {
            "miou": round(100 * m["miou"], 2),
            "macc": round(100 * m["macc"], 2),
            "no_prediction": round(100 * m["no_prediction"] / max(m["n_points"], 1), 2),
        }

    def instances(self, instance_ids: NDArray[np.int64], n_written: int) -> dict[str, Any]:
        if self.gt.instances is None:
            return {}
        m = instance_metrics(self.gt.instances, self.nearest(instance_ids), n_written)
        out = {k: round(100 * m[k], 2) for k in ("precision", "recall", "f1", "mcov")}
        return {
            **out,
            "n_written": m["n_written"],
            "n_gt": m["n_gt"],
            "count_ratio": round(m["count_ratio"], 2),
        }


def class_maps(saved: SavedRun) -> tuple[list[ViewState], list[NDArray[Any]]]:
    """The views that have a class map, and their class maps."""
    seen = [v for v in saved.trained.views if v.name in saved.semantic]
    return seen, [saved.semantic[v.name].classes for v in seen]


def vote3d(
    saved: SavedRun, seen: Sequence[ViewState], maps: Sequence[NDArray[Any]]
) -> NDArray[Any]:
    """The training-free 3D vote's class per Gaussian (:func:`dcseg.segment.vote_3d`)."""
    n, c = len(saved.trained.gaussians.means), len(saved.vocabulary)
    return vote_3d(class_evidence([v.blend for v in seen], maps, n, c))


def exported_labels(saved: SavedRun, seg: Segmentation, out: Path) -> Labels:
    """Write ``seg``'s outputs into ``out`` and read their labels back (what users download);
    the trained run's record goes beside them (``load_labels`` reads its lens record)."""
    write_outputs(out, saved.trained, seg, saved.vocabulary, [])
    (out / "run.json").write_text(json.dumps(saved.record), encoding="utf-8")
    return load_labels(out, [v.name for v in saved.trained.views])


def baselines(saved: SavedRun, scorer: Scorer, cfg: PipelineConfig) -> dict[str, Any]:
    """Naive 2D fusion and the training-free 3D vote on one run, by both protocols."""
    seen, maps = class_maps(saved)
    vote = vote3d(saved, seen, maps)
    groups = torch.from_numpy(vote)
    rendered = [v.blend.dominant_group(groups, cfg.masks.min_weight).numpy() for v in seen]
    return {
        "naive_fusion": scorer.semantic(scorer.projection(maps, seen)),
        "vote3d_nearest": scorer.semantic(scorer.nearest(vote)),
        "vote3d_projection": scorer.semantic(scorer.projection(rendered, seen)),
    }


def overridden(cfg: PipelineConfig, overrides: Sequence[str]) -> PipelineConfig:
    """``cfg`` with ``section.field=JSON`` overrides (``assign.complete=false``, ``scale=0.5``);
    a value that is not JSON is a string (``assign.label_maps=clusters``)."""
    for item in overrides:
        key, value = key_value(item)
        section, _, name = key.rpartition(".")
        if section:
            cfg = replace(cfg, **{section: replace(getattr(cfg, section), **{name: value})})
        else:
            cfg = replace(cfg, **{name: value})
    return cfg


def current_config(
    saved: SavedRun, cluster_seed: int, overrides: Sequence[str] = ()
) -> PipelineConfig:
    """The current fast preset's segmentation with the run's trained config (seeds, cache)."""
    trained = PipelineConfig.from_dict(saved.record["config"])
    now = overridden(preset("fast"), overrides)
    return replace(
        now,
        seed=trained.seed,
        reconstruct=trained.reconstruct,
        affinity=trained.affinity,
        cache=trained.cache,
        cluster=replace(now.cluster, seed=cluster_seed),
    )


def score_segmentation(
    saved: SavedRun, scorer: Scorer, cluster_seed: int, tmp: Path, overrides: Sequence[str]
) -> dict[str, Any]:
    """Segment the saved state with the current code and defaults, export, score the exports."""
    cfg = current_config(saved, cluster_seed, overrides)
    start, cpu = time.perf_counter(), time.process_time()
    names = saved.vocabulary.names
    seg = segment_scene(saved.trained, saved.semantic, len(names), cfg, class_names=names)
    seconds, cpu = time.perf_counter() - start, time.process_time() - cpu
    out = Path(tempfile.mkdtemp(dir=tmp))
    labels = exported_labels(saved, seg, out)
    views = saved.trained.views
    vertex = PlyData.read(str(out / "scene_labelled.ply"))["vertex"]
    instance_ids = np.asarray(vertex["instance_id"], dtype=np.int64)
    n_written = len(json.loads((out / "instances.json").read_text())["instances"])
    return {
        "cluster_seed": cluster_seed,
        "segment_seconds": round(seconds, 2),
        "segment_cpu_seconds": round(cpu, 2),
        "mask_agreement": round(seg.mask_agreement, 4),
        "evidence_trusted": seg.evidence_trusted,
        "nearest": scorer.semantic(scorer.nearest(labels.semantic_ids)),
        "projection": scorer.semantic(
            scorer.projection([labels.label_maps[v.name] for v in views], views)
        ),
        "instances": scorer.instances(instance_ids, n_written),
    }


def capture_faults(scene_json: Path) -> dict[str, Any]:
    """The handheld faults a synthetic scene was made with (``--synth``; older scenes: none)."""
    made = json.loads(scene_json.read_text(encoding="utf-8"))
    return {
        "depth_sigma": made["noise_level"]["depth_sigma"],
        "pose_error": made.get("pose_error", {"deg": 0.0, "m": 0.0}),
        "motion_blur_px": made.get("motion_blur_px", 0.0),
    }


def applied_pose_lr(record: dict[str, Any]) -> float:
    """The pose learning rate the reconstruction trained with (0 where ``auto`` did not
    refine; runs before ``config_changes`` report the requested one)."""
    requested = float(record["config"]["reconstruct"].get("pose_lr", 0.0))
    changes = record.get("reconstruction", {}).get("config_changes", {})
    return float(changes.get("pose_lr", {}).get("applied", requested))


def score_run(work: Path, noise: str, layout: int, args: argparse.Namespace) -> dict[str, Any]:
    root = run_dir(work, noise, layout)
    saved = load_run(root / "run")
    gt = read_ground_truth(root / "scene" / "gt" / "points.ply", len(saved.vocabulary))
    cfg = current_config(saved, args.cluster_seeds[0])
    scorer = Scorer(saved, gt, cfg.evaluate.depth_tol)
    row: dict[str, Any] = {
        "noise": noise,
        "layout": layout,
        "group": "heldout" if layout in args.heldout else "tuning",
        "run_seconds": saved.record.get("seconds", {}),
        "capture_faults": capture_faults(root / "scene" / "scene.json"),
        "pose_lr": applied_pose_lr(saved.record),
        "pose_refinement": saved.record["config"]["reconstruct"].get("pose_refinement"),
        "baselines": baselines(saved, scorer, cfg),
    }
    with tempfile.TemporaryDirectory() as tmp:
        row["dcseg"] = [
            score_segmentation(saved, scorer, seed, Path(tmp), args.set)
            for seed in args.cluster_seeds
        ]
    return row


METRICS: dict[str, tuple[str, ...]] = {
    "naive_fusion": ("baselines", "naive_fusion", "miou"),
    "vote3d_nearest": ("baselines", "vote3d_nearest", "miou"),
    "vote3d_projection": ("baselines", "vote3d_projection", "miou"),
    "dcseg_nearest": ("nearest", "miou"),
    "dcseg_projection": ("projection", "miou"),
    "no_prediction_nearest": ("nearest", "no_prediction"),
    "no_prediction_vote3d": ("baselines", "vote3d_nearest", "no_prediction"),
    "instance_f1": ("instances", "f1"),
    "instance_precision": ("instances", "precision"),
    "instance_recall": ("instances", "recall"),
    "instance_mcov": ("instances", "mcov"),
    "count_ratio": ("instances", "count_ratio"),
    "segment_seconds": ("segment_seconds",),
    "segment_cpu_seconds": ("segment_cpu_seconds",),
}
"""Summary name -> path into a row's baselines or one of its segmentations."""


def _get(node: Any, path: Sequence[str]) -> float | None:
    for key in path:
        if not isinstance(node, dict) or key not in node:
            return None
        node = node[key]
    return None if node is None else float(node)


def _values(rows: Sequence[dict[str, Any]], path: tuple[str, ...]) -> list[float]:
    """One value per run for baselines, one per run and clustering seed for dcseg."""
    if path[0] == "baselines":
        found = [_get(r, path) for r in rows]
    else:
        found = [_get(seg, path) for r in rows for seg in r["dcseg"]]
    return [v for v in found if v is not None and v == v]


def _stats(values: list[float]) -> dict[str, float]:
    if not values:
        return {"n": 0}
    spread = statistics.stdev(values) if len(values) > 1 else 0.0
    return {
        "mean": round(statistics.mean(values), 2),
        "std": round(spread, 2),
        "min": round(min(values), 2),
        "max": round(max(values), 2),
        "n": len(values),
    }


def _margins(rows: Sequence[dict[str, Any]]) -> dict[str, dict[str, float]]:
    """Per run, dcseg's mean over clustering seeds minus each baseline, same protocol."""
    pairs = {
        "nearest_minus_naive": (("nearest", "miou"), ("baselines", "naive_fusion", "miou")),
        "projection_minus_naive": (("projection", "miou"), ("baselines", "naive_fusion", "miou")),
        "nearest_minus_vote3d": (("nearest", "miou"), ("baselines", "vote3d_nearest", "miou")),
        "projection_minus_vote3d": (
            ("projection", "miou"), ("baselines", "vote3d_projection", "miou"),
        ),
    }  # fmt: skip
    out = {}
    for name, (ours, theirs) in pairs.items():
        diffs = []
        for r in rows:
            mine = _values([r], ours)
            base = _get(r, theirs)
            if mine and base is not None:
                diffs.append(statistics.mean(mine) - base)
        out[name] = _stats(diffs)
    return out


def summarise(rows: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Per noise level and group (tuning / held out): mean, spread, range of every metric."""
    out: dict[str, Any] = {}
    for noise in (*NOISES, *GENERATORS):
        for group in ("tuning", "heldout"):
            chosen = [r for r in rows if r["noise"] == noise and r["group"] == group]
            if not chosen:
                continue
            entry: dict[str, Any] = {
                name: _stats(_values(chosen, path)) for name, path in METRICS.items()
            }
            entry["margins"] = _margins(chosen)
            entry["layouts"] = sorted(r["layout"] for r in chosen)
            out.setdefault(noise, {})[group] = entry
    return out


def _cell(stats: dict[str, float], digits: int = 1) -> str:
    if not stats.get("n"):
        return "-"
    return f"{stats['mean']:.{digits}f} ± {stats['std']:.{digits}f}"


def markdown(summary: dict[str, Any]) -> str:
    """The README table: one row per noise level and group."""
    lines = [
        "| noise | layouts | naive 2D fusion | 3D vote: 3D / proj. | dcseg 3D labels "
        "| dcseg rendered maps | no prediction % (dcseg / vote) | instance F1 (P / R) "
        "| mCov | instances / objects |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for noise, groups in summary.items():
        for group, e in groups.items():
            layouts = ",".join(str(i) for i in e["layouts"])
            p, r = e["instance_precision"], e["instance_recall"]
            cells = [
                f"{noise}",
                f"{group} {layouts}",
                _cell(e["naive_fusion"]),
                f"{_cell(e['vote3d_nearest'])} / {_cell(e['vote3d_projection'])}",
                _cell(e["dcseg_nearest"]),
                _cell(e["dcseg_projection"]),
                f"{_cell(e['no_prediction_nearest'])} / {_cell(e['no_prediction_vote3d'])}",
                f"{_cell(e['instance_f1'])} ({_cell(p, 0)} / {_cell(r, 0)})",
                _cell(e["instance_mcov"]),
                _cell(e["count_ratio"], 2),
            ]
            lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def score(args: argparse.Namespace) -> None:
    """Score every trained run in ``--work`` (or merge the rows of ``--merge``), write ``--out``."""
    rows, missing = [], []
    for path in args.merge:
        rows.extend(json.loads(path.read_text())["runs"])
    for noise in args.noise if not args.merge else []:
        for layout in [*args.tuning, *args.heldout]:
            if not (run_dir(args.work, noise, layout) / "run" / "run.json").is_file():
                missing.append(f"{noise}/layout{layout}")
                continue
            row = score_run(args.work, noise, layout, args)
            print(json.dumps({k: row[k] for k in ("noise", "layout", "baselines")}), flush=True)
            print(json.dumps(row["dcseg"]), flush=True)
            rows.append(row)
    summary = summarise(rows)
    meta = {
        "frames": args.frames,
        "size": list(args.size),
        "preset": "fast",
        "pipeline_seed": args.pipeline_seed,
        "cluster_seeds": args.cluster_seeds,
        "overrides": args.set,
        "tuning_layouts": args.tuning,
        "heldout_layouts": args.heldout,
        "not_trained": missing,
        "scored": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "protocols": {
            "nearest": (
                f"nearest Gaussian with opacity > {PROTOCOL.min_opacity} "
                f"within {PROTOCOL.max_distance} m"
            ),
            "projection": "majority vote of label maps, depth test (EvaluateConfig.depth_tol)",
        },
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    body = {"meta": meta, "summary": summary, "runs": rows}
    args.out.write_text(json.dumps(body, indent=1) + "\n")
    print(markdown(summary))


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    p.add_argument("--work", type=Path, default=Path("/tmp/dcseg-bench-segment"))
    p.add_argument("--out", type=Path, default=Path("benchmarks/results/segment_heldout.json"))
    p.add_argument("--train", action="store_true", help="train the missing runs, then stop")
    p.add_argument(
        "--merge",
        nargs="*",
        type=Path,
        default=[],
        help="summarise the runs of earlier --out files (scored in parallel) instead of scoring",
    )
    p.add_argument(
        "--noise",
        nargs="+",
        default=list(NOISES),
        choices=(*NOISES, *GENERATORS),
        help="noise levels, or error generators (detector, lowres: default-level depth)",
    )
    p.add_argument("--tuning", nargs="*", type=int, default=list(TUNING))
    p.add_argument("--heldout", nargs="*", type=int, default=list(HELDOUT))
    p.add_argument("--cluster-seeds", nargs="+", type=int, default=[0, 10])
    p.add_argument("--pipeline-seed", type=int, default=0)
    p.add_argument(
        "--set",
        nargs="*",
        default=[],
        metavar="KEY=JSON",
        help="overrides for ablations (with --train also of training: reconstruct, cache, "
        "affinity), e.g. assign.complete=false scale=0.5 "
        "assign.label_maps=clusters",
    )
    p.add_argument(
        "--synth",
        nargs="*",
        default=[],
        metavar="KEY=JSON",
        help="SynthConfig fields of the scenes --train makes, e.g. pose_error_deg=0.5 "
        "pose_error_m=0.01 motion_blur_px=3 depth_sigma=0.00285 (use a --work of its own)",
    )
    p.add_argument("--frames", type=int, default=40)
    p.add_argument("--reconstruct-iterations", type=int, help="override (smoke runs only)")
    p.add_argument("--affinity-iterations", type=int, help="override (smoke runs only)")
    p.add_argument("--size", type=lambda s: tuple(int(v) for v in s.split("x")), default=(320, 240))
    return p


def main() -> None:
    args = parser().parse_args()
    if args.train:
        train(args)
        return
    score(args)


if __name__ == "__main__":
    main()
