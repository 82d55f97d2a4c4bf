"""End to end on a tiny synthetic scene: run, re-cluster, re-classify, evaluate."""

from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from dcseg.cli import main
from dcseg.config import JobConfig, PipelineConfig, preset
from dcseg.errors import InputError
from dcseg.io.images import read_image
from dcseg.io.run_output import load_run
from dcseg.jobs import (
    RunInputs,
    evaluate_job,
    resegment_job,
    run_job,
    run_stages,
    stored_config,
)
from dcseg.options import build_config, parse_options
from dcseg.pipeline import segment_scene
from dcseg.segment import class_agreement, label_map
from dcseg.segmentation import Segmentation
from dcseg.stages import RECONSTRUCT, TRAIN, VALIDATE

pytest.importorskip("pybullet", reason="the synthetic scene generator needs pybullet")

OUTPUTS = (
    "scene.ply",
    "scene_labelled.ply",
    "instances.json",
    "labels.json",
    "preview.png",
    "run.json",
    "state/gaussians.ply",
    "state/affinity.npz",
    "state/views.json",
    "state/clusters.npz",
)


def tiny_config() -> PipelineConfig:
    """The fast preset shrunk to seconds on a 64x48 scene."""
    cfg = preset("fast")
    return replace(
        cfg,
        reconstruct=replace(cfg.reconstruct, iterations=150, holdout=0),
        affinity=replace(cfg.affinity, iterations=150, rays=256),
    )


def job(cfg: PipelineConfig | None = None) -> JobConfig:
    """``cfg`` (the tiny config) as a job's config."""
    return JobConfig(tiny_config() if cfg is None else cfg)


def resegment(run: Path, out: Path, inputs: RunInputs | None = None, **segment: object):
    """Re-segment ``run`` with the segment options ``segment`` (the CLI's way)."""
    config = build_config(stored_config(run), parse_options({"segment": segment}))
    return resegment_job(run, out, inputs, config)


@pytest.fixture(scope="module")
def scene(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("pipeline") / "scene"
    args = ["synth", str(out), "--frames", "6", "--size", "64x48", "--noise", "clean"]
    assert main(args) == 0
    return out


def inputs_of(scene: Path) -> RunInputs:
    inputs = RunInputs.from_bundle(scene)
    assert inputs.ground_truth == scene / "gt" / "points.ply"
    return inputs


@pytest.fixture(scope="module")
def run_dir(scene: Path) -> Path:
    out = scene.parent / "run"
    run_job(inputs_of(scene), job(), out)
    return out


def test_run_writes_every_output(run_dir: Path, scene: Path) -> None:
    for name in OUTPUTS:
        assert (run_dir / name).is_file(), name
    record = json.loads((run_dir / "run.json").read_text())
    assert set(record["seconds"]) >= {"read", "reconstruct", "train", "segment", "write"}
    assert record["counts"]["clusters"] >= 2
    agreement = record["segmentation"]["mask_agreement"]  # clean masks of the tiny scene
    assert 0.5 < agreement <= 1.0
    assert record["segmentation"]["evidence_trusted"] == (agreement >= 0.985)
    assert 0.0 <= record["segmentation"]["unanimous_clusters"] <= 1.0
    assert record["segmentation"]["confusions_undone"] >= 0
    assert record["segmentation"]["ring_gaussians_given_back"] >= 0
    assert record["segmentation"]["background_gaussians"] >= 0
    stems = [p.stem for p in (scene / "rgb").iterdir()]
    for stem in stems:
        ids = read_image(run_dir / "masks" / f"{stem}.png")
        assert ids.dtype == np.uint16 and ids.shape == (48, 64)
    instances = json.loads((run_dir / "instances.json").read_text())["instances"]
    assert instances and all(r["n_gaussians"] > 0 for r in instances)
    assert record["counts"]["instances"] == len(instances)


def test_ply_carries_objects_and_clusters(run_dir: Path) -> None:
    """``instance_id`` is the object level (what instances.json lists), ``cluster_id`` the
    cluster level (what state/clusters.npz holds); every object is one class."""
    from dcseg.io.ply import read_ply_extra

    ply = run_dir / "scene_labelled.ply"
    objects, clusters = read_ply_extra(ply, "instance_id"), read_ply_extra(ply, "cluster_id")
    semantic = read_ply_extra(ply, "semantic_id")
    assert objects is not None and clusters is not None and semantic is not None
    saved = np.load(run_dir / "state" / "clusters.npz")
    assert np.array_equal(np.where(saved["labels"] >= 0, saved["labels"] + 1, -1), clusters)
    records = json.loads((run_dir / "instances.json").read_text())["instances"]
    assert sorted(r["id"] for r in records) == sorted(set(objects[objects > 0].tolist()))
    for r in records:
        members = objects == r["id"]
        assert r["n_gaussians"] == int(members.sum())
        assert np.bincount(semantic[members] + 1).argmax() - 1 == r["label_id"]


def test_run_quality_floor(run_dir: Path) -> None:
    metrics = json.loads((run_dir / "metrics.json").read_text())
    summary = metrics["summary"]
    # Clean masks on a tiny scene: the 3D method must label a real share of the points.
    assert summary["dcseg_projection"]["miou"] >= 0.2, summary
    assert summary["naive_fusion"]["miou"] >= 0.5, summary
    assert metrics["dcseg_projection"]["n_points"] > 1000


def forbid_training(monkeypatch: pytest.MonkeyPatch) -> None:
    def fail(*args: object, **kwargs: object) -> None:
        raise AssertionError("trained again")

    monkeypatch.setattr("dcseg.pipeline.train_affinity", fail)
    monkeypatch.setattr("dcseg.reconstruct.fit_gaussians", fail)


def test_recluster_reuses_training(
    run_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    forbid_training(monkeypatch)
    out = tmp_path / "coarse"
    record = resegment(run_dir, out, scale=1.0)
    assert record["config"]["scale"] == 1.0 and record["parent"] == str(run_dir)
    for name in OUTPUTS:
        assert (out / name).is_file(), name
    # The derived run can itself be re-clustered.
    resegment(out, tmp_path / "fine", scale=0.2, matcher="matching", label_maps="clusters")
    fine = json.loads((tmp_path / "fine" / "run.json").read_text())
    assert fine["config"]["assign"]["matcher"] == "matching"
    assert fine["config"]["assign"]["label_maps"] == "clusters"
    assert record["config"]["assign"]["label_maps"] == "gaussians"


def test_reclassify_with_other_masks(
    run_dir: Path, scene: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    forbid_training(monkeypatch)
    out = tmp_path / "gt-classes"
    # Use the perfect per-frame ground truth as another segmenter's output.
    maps, vocabulary = scene / "gt" / "semantic", scene / "vocabulary.txt"
    resegment_job(run_dir, out, RunInputs(run_dir, semantic_masks=maps, vocabulary=vocabulary))
    labels = json.loads((out / "labels.json").read_text())["labels"]
    assert len(labels) == len((scene / "vocabulary.txt").read_text().split())
    metrics = evaluate_job(out, scene / "gt" / "points.ply")
    assert (out / "metrics.json").is_file()
    assert metrics["summary"]["dcseg_projection"]["miou"] > 0.0


def test_derived_run_must_not_replace_parent(run_dir: Path) -> None:
    with pytest.raises(InputError, match="must not replace"):
        resegment(run_dir, run_dir, scale=0.5)


def test_masks_for_missing_frames_rejected(scene: Path, tmp_path: Path) -> None:
    masks = tmp_path / "agnostic"
    masks.mkdir()
    source = next((scene / "masks" / "agnostic").iterdir())
    (masks / "ghost.json").write_bytes(source.read_bytes())
    bad = replace(inputs_of(scene), agnostic_masks=masks)
    with pytest.raises(InputError, match="ghost"):
        run_job(bad, job(), tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_cli_run_refuses_non_empty_out(
    scene: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "keep.txt").write_text("mine")
    args = [
        "run", str(scene), "--agnostic-masks", str(scene / "masks" / "agnostic"),
        "--semantic-masks", str(scene / "masks" / "semantic"),
        "--vocabulary", str(scene / "vocabulary.txt"), "--out", str(tmp_path),
    ]  # fmt: skip
    assert main(args) == 2
    assert "--overwrite" in capsys.readouterr().err
    assert (tmp_path / "keep.txt").read_text() == "mine"


def test_bundle_without_masks_is_named(tmp_path: Path) -> None:
    (tmp_path / "vocabulary.txt").write_text("wall\n")
    with pytest.raises(InputError, match="agnostic_masks .*masks/agnostic.*semantic_masks"):
        RunInputs.from_bundle(tmp_path)


def test_train_then_segment_separately(
    scene: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    trained = tmp_path / "trained"
    run_stages((VALIDATE, RECONSTRUCT, TRAIN), inputs_of(scene), job(), tmp_path / "work")
    (tmp_path / "work" / "train").rename(trained)
    record = json.loads((trained / "run.json").read_text())
    assert (trained / "state" / "affinity.npz").is_file()
    assert not (trained / "state" / "semantic").exists() and "counts" not in record
    unclassed = resegment_job(trained, tmp_path / "none")  # no class masks: class-agnostic
    assert unclassed["counts"]["labelled_clusters"] == 0 and unclassed["counts"]["instances"]
    forbid_training(monkeypatch)
    out = tmp_path / "segmented"
    given = RunInputs.from_bundle(scene)
    resegment_job(trained, out, given)
    for name in OUTPUTS:
        assert (out / name).is_file(), name
    assert json.loads((out / "metrics.json").read_text())["summary"]["naive_fusion"]["miou"] > 0.5


def test_cli_recluster_reclassify_evaluate(
    run_dir: Path, scene: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    coarse, other = tmp_path / "coarse", tmp_path / "other"
    assert main(["recluster", str(run_dir), "--scale", "0.9", "--out", str(coarse), "--quiet"]) == 0
    assert json.loads((coarse / "run.json").read_text())["config"]["scale"] == 0.9
    args = ["reclassify", str(run_dir), "--out", str(other), "--quiet"]
    args += ["--semantic-masks", str(scene / "gt" / "semantic")]
    args += ["--vocabulary", str(scene / "vocabulary.txt")]
    assert main(args) == 0
    assert main(["evaluate", str(other), "--gt", str(scene / "gt" / "points.ply")]) == 0
    assert "naive_fusion" in json.loads(capsys.readouterr().out)
    with pytest.raises(SystemExit, match="--scale"):
        main(["recluster", str(run_dir), "--scale", "2", "--out", str(tmp_path / "bad")])


def test_a_loaded_run_reads_views_from_their_files_unless_asked_to_hold_them(
    run_dir: Path,
) -> None:
    """Re-segmenting holds no view by default (the page cache serves the second read; holding
    them all doubled recluster's fresh memory); ``memory_mb`` holds them."""
    views = load_run(run_dir).trained.views
    for view in views:
        assert view.blend.nnz > 0
    assert all(v.memory is not None and v.memory.nbytes == 0 for v in views)
    held = load_run(run_dir, memory_mb=64).trained.views
    first = held[0].blend
    assert held[0].memory is not None and held[0].memory.nbytes == first.nbytes()
    assert held[0].blend is first


def test_inconsistent_gaussians_leave_their_clusters(run_dir: Path) -> None:
    saved = load_run(run_dir)
    base = PipelineConfig.from_dict(saved.record["config"])
    n_classes = len(saved.vocabulary)

    def segment(ratio: float, regroup: int = 0) -> Segmentation:
        # completion, objects, regrouping, the support rings and the support check of the
        # votes off: this test is about the consistency step alone (the support check runs
        # only where the class evidence is summed, i.e. with a ratio > 0, and may relabel a
        # whole cluster), and its label maps are the cluster maps through each cluster's class
        assign = replace(
            base.assign, min_share_ratio=ratio, complete=False, objects=False,
            label_maps="clusters", regroup_min_gaussians=regroup, min_cluster_support=0.0,
            ring_plane_tol=0.0,
        )  # fmt: skip
        return segment_scene(saved.trained, saved.semantic, n_classes, replace(base, assign=assign))

    plain, refined = segment(0.0), segment(0.9)
    # Regrouping makes clusters (numbered after the kept ones) of some of the Gaussians that
    # left, with a class; every other Gaussian keeps its cluster and class.
    grouped = segment(0.9, regroup=5)
    new = grouped.clustering.labels >= refined.n_clusters
    assert new.any() and (refined.clustering.labels[new] == -1).all()
    assert np.array_equal(grouped.clustering.labels[~new], refined.clustering.labels[~new])
    assert np.array_equal(grouped.semantic_ids != refined.semantic_ids, new)
    before, after = plain.semantic_ids, refined.semantic_ids
    dropped = (before >= 0) & (after < 0)
    assert dropped.any(), "a 0.9 ratio must drop some Gaussians on this scene"
    # Gaussians only ever leave a cluster: nobody changes class or gains one.
    assert np.array_equal(after[after >= 0], before[after >= 0])
    # Exactly the Gaussians far below their cluster's pooled share went (brute force).
    views = [v for v in saved.trained.views if v.name in saved.semantic]
    maps = [saved.semantic[v.name].classes for v in views]
    agree, total = class_agreement([v.blend for v in views], maps, before)
    clusters = plain.clustering.labels
    for k in range(plain.n_clusters):
        member = (clusters == k) & (before >= 0) & (total > 0)
        if not member.any():
            continue
        share = agree[clusters == k].sum() / total[clusters == k].sum()
        low = agree[member] < 0.9 * share * total[member]
        assert np.array_equal(dropped[member], low), k
    # Clusters are compact 0..K-1 and the assignment's arrays follow them.
    labels = refined.clustering.labels
    k = refined.n_clusters
    assert np.array_equal(np.unique(labels[labels >= 0]), np.arange(k))
    assert refined.assignment.labels.shape == (k,) and refined.assignment.votes.shape[0] == k
    # The cluster maps were rendered from the refined clusters.
    for name, ids in refined.cluster_maps.items():
        assert ids.max() < k
        assert np.array_equal(refined.label_maps[name], label_map(ids, refined.assignment.labels))


def test_a_real_run_exports_every_object(run_dir: Path, tmp_path: Path) -> None:
    """``dcseg export`` on a pipeline run: per-object PLYs partition the labelled Gaussians and
    the GLB has a node for objects with a surface, named by their class."""
    import trimesh

    from dcseg.export import export_run
    from dcseg.io.splat_table import read_splat_table

    export_run(run_dir, tmp_path / "ply", "ply")
    table = json.loads((tmp_path / "ply" / "instances.ply.json").read_text())
    total = len(read_splat_table(run_dir / "scene_labelled.ply"))
    counted = sum(len(read_splat_table(tmp_path / "ply" / r["file"])) for r in table["instances"])
    assert counted + table["unassigned_gaussians"][1] == total
    export_run(run_dir, tmp_path / "glb", "glb-mesh")
    scene = trimesh.load_scene(tmp_path / "glb" / "scene_mesh.glb")
    records = json.loads((tmp_path / "glb" / "instances.glb-mesh.json").read_text())["instances"]
    nodes = {r["node"]: r for r in records if r["node"] is not None}
    assert set(scene.graph.nodes_geometry) == set(nodes) and len(nodes) >= len(records) // 2
    assert all(name.startswith(f"{r['label'] or 'object'}_") for name, r in nodes.items())


def test_device_is_recorded_and_a_missing_gpu_is_named(run_dir: Path, scene: Path, tmp_path):
    """``device="auto"`` (the default) ran on the CPU here and says so in ``run.json``; asking
    for CUDA where torch sees none is an input error naming the device, before any work."""
    import torch

    record = json.loads((run_dir / "run.json").read_text())
    expected = "cuda" if torch.cuda.is_available() else "cpu"
    assert record["reconstruction"]["device"].startswith(expected)
    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA: a missing-GPU error cannot be provoked")
    with pytest.raises(InputError, match="device 'cuda' asked for, but torch sees no CUDA"):
        run_job(inputs_of(scene), job(), tmp_path / "gpu", device="cuda")
    with pytest.raises(InputError, match="unknown device 'tpu'"):
        run_job(inputs_of(scene), job(), tmp_path / "tpu", device="tpu")
    assert not (tmp_path / "gpu").exists() and not (tmp_path / "tpu").exists()


@pytest.mark.gpu
def test_whole_pipeline_on_cuda(scene: Path, tmp_path: Path) -> None:
    """Reconstruction, the cache's projection and affinity training on CUDA; segmentation,
    exports and re-clustering work from the GPU-trained state."""
    out = tmp_path / "cuda"
    record = run_job(inputs_of(scene), job(), out, device="cuda")
    assert record["reconstruction"]["device"].startswith("cuda")
    assert record["counts"]["clusters"] >= 2
    for name in OUTPUTS:
        assert (out / name).is_file(), name
    again = resegment(out, tmp_path / "again", scale=0.5)
    assert again["counts"]["clusters"] >= 1


class LiveBlends:
    """Bytes of blending weights alive at once (every BlendWeights ever built is tracked)."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch) -> None:
        import weakref

        from dcseg.blend import BlendWeights

        self.live = 0
        self.peak = 0
        original = BlendWeights.__post_init__

        def tracked(blend: BlendWeights) -> None:
            original(blend)
            size = blend.nbytes()
            self.live += size
            self.peak = max(self.peak, self.live)
            weakref.finalize(blend, self._release, size)

        monkeypatch.setattr(BlendWeights, "__post_init__", tracked)

    def _release(self, size: int) -> None:
        self.live -= size


def test_cache_memory_does_not_grow_with_frames(
    scene: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A run holds one or two views' blending weights at a time, whatever the frame count:
    the cache is written view by view into the staged ``state/`` and read back per use
    (affinity steps, cluster maps, the consistency filter). Measured in-process: 18 frames
    peak no higher than 6 frames (in memory, the same views would sum up)."""
    peaks = {}
    cfg = tiny_config()
    cfg = replace(cfg, cache=replace(cfg.cache, memory_mb=1))  # about one 64x48 view
    for frames in (6, 18):
        bundle = tmp_path / f"scene{frames}"
        args = ["synth", str(bundle), "--frames", str(frames), "--size", "64x48"]
        assert main([*args, "--noise", "clean"]) == 0
        tracker = LiveBlends(monkeypatch)
        record = run_job(inputs_of(bundle), job(cfg), tmp_path / f"run{frames}")
        peaks[frames] = tracker.peak
        cache = record["cache_mb"] * 2**20
        monkeypatch.undo()
        view_bytes = cache / frames
        bound = 2**20 + 3 * view_bytes * 1.3  # the budget plus the views in use
        assert tracker.peak <= bound, (frames, tracker.peak, view_bytes)
    assert peaks[18] <= 1.3 * peaks[6], peaks
    resegmented = resegment(tmp_path / "run18", tmp_path / "again", scale=0.5)
    assert resegmented["cache_mb"] == record["cache_mb"]  # state/ linked, not grown


def counted_reads(monkeypatch: pytest.MonkeyPatch) -> list[Path]:
    """The view files read from now on (one entry per read of a view's weights)."""
    import dcseg.io.run_state as run_state

    reads: list[Path] = []
    original = run_state._read_blend

    def counted(path: Path, width: int, height: int):
        reads.append(path)
        return original(path, width, height)

    monkeypatch.setattr(run_state, "_read_blend", counted)
    return reads


def test_a_cache_within_its_memory_budget_is_never_read_back(
    scene: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The default budget holds a small capture's whole cache: training and segmentation use
    the weights computed in memory and never read a view file back (no time lost)."""
    reads = counted_reads(monkeypatch)
    run_job(inputs_of(scene), job(), tmp_path / "run")
    assert reads == []
    assert len(list((tmp_path / "run" / "state" / "views").glob("*.npz"))) == 6


def test_segmentation_reads_each_view_twice(run_dir: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """With no view held in memory, segmentation reads each view's weights twice: once for
    the first cluster maps and the class evidence (one pass), once for the final cluster and
    label maps; a third pass for the evidence alone is gone."""
    import dcseg.io.run_state as run_state

    saved = load_run(run_dir)
    views = tuple(run_state.load_views(run_dir / "state"))  # no memory: every access reads
    trained = replace(saved.trained, views=views)
    reads = counted_reads(monkeypatch)
    cfg = replace(tiny_config(), scale=0.5)
    result = segment_scene(trained, saved.semantic, len(saved.vocabulary), cfg)
    assert result.label_maps and cfg.assign.label_maps == "gaussians"
    assert sorted(reads) == sorted(2 * [Path(str(v.source)) for v in views])


def test_older_run_with_retired_fields_still_reclusters(
    run_dir: Path, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    old = tmp_path / "old"
    shutil.copytree(run_dir, old)
    record = json.loads((old / "run.json").read_text())
    record["config"]["assign"]["min_class_share"] = 0.15
    (old / "run.json").write_text(json.dumps(record))
    with caplog.at_level("WARNING", logger="dcseg.jobs"):
        resegment(old, tmp_path / "again", scale=0.5)
    assert "assign.min_class_share" in caplog.text
    again = json.loads((tmp_path / "again" / "run.json").read_text())
    assert "min_class_share" not in again["config"]["assign"]
    record["config"]["assign"]["from_the_future"] = 1
    (old / "run.json").write_text(json.dumps(record))
    with pytest.raises(InputError, match=r"run\.json.*from_the_future"):
        resegment(old, tmp_path / "refused", scale=0.5)
    assert not (tmp_path / "refused").exists()


def test_without_class_masks_the_run_is_class_agnostic(scene: Path, tmp_path: Path) -> None:
    """Agnostic masks only: objects without classes, instance metrics only; re-clusters."""
    inputs = replace(inputs_of(scene), semantic_masks=None, vocabulary=None)
    out = tmp_path / "agnostic"
    record = run_job(inputs, job(), out)
    instances = json.loads((out / "instances.json").read_text())["instances"]
    assert instances and all(i["label"] is None and i["label_id"] == -1 for i in instances)
    assert record["counts"]["labelled_clusters"] == 0 and record["counts"]["instances"] > 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert set(metrics["summary"]) == {"instances"} and metrics["instances"]["n_gt"] > 0
    assert 0.0 <= metrics["instances"]["f1"] <= 1.0
    assert all(read_image(path).max() == 0 for path in (out / "labels").iterdir())
    again = resegment(out, tmp_path / "again", scale=0.5)
    assert again["counts"]["labelled_clusters"] == 0
    with pytest.raises(InputError, match="go together"):
        run_job(replace(inputs, vocabulary=scene / "vocabulary.txt"), job(), tmp_path / "bad")


def test_a_classed_run_reports_instance_metrics_too(run_dir: Path) -> None:
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert {"dcseg_projection", "dcseg_nearest", "naive_fusion", "instances"} <= set(metrics)
    assert metrics["summary"]["instances"]["f1"] == metrics["instances"]["f1"]
