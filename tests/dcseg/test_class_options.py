"""The job options ``segment.stuff_classes``, ``segment.unlabelled_id`` and
``segment.background_share``: declared once, set from the API and the command line, refused
naming the field, and read where they act (the class maps of the segment stage, the stuff
classes of object building)."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from dcseg.assign.config import AssignConfig
from dcseg.assign.objects import build_objects, stuff_ids
from dcseg.assign.stage import Assignment
from dcseg.cluster.features import Clustering
from dcseg.errors import InputError
from dcseg.inputs import RunInputs
from dcseg.io.images import write_image
from dcseg.io.run_output import SavedRun
from dcseg.io.semantic import read_semantic_maps, write_vocabulary
from dcseg.options import build_config, parse_options
from dcseg.pipeline import segment_scene
from dcseg.stages.base import StageRun
from dcseg.stages.segment import _with_semantic
from dcseg.types import Vocabulary
from tests.dcseg.assign.surfaces import RADIUS, patch
from tests.dcseg.io.layouts import make_scene, write_scannet
from tests.dcseg.test_segment_scene import N, scene

SCANNET = Vocabulary(("unannotated", "wall", "floor", "chair"))
"""ScanNet-style: class maps hold ids, 0 = unannotated (a placeholder at index 0)."""
LABEL_FILT = np.array([[0] * 6 + [3] * 6], dtype=np.uint16)
"""A ``label-filt`` PNG of the 1 x 12 test view: pixels 0-5 unannotated, 6-11 chair."""


def scannet_bundle(tmp_path: Path) -> tuple[Path, Path]:
    masks = tmp_path / "label-filt"
    for name in ("v0", "v1"):
        write_image(masks / f"{name}.png", LABEL_FILT)
    vocabulary = tmp_path / "vocabulary.txt"
    write_vocabulary(vocabulary, SCANNET)
    return masks, vocabulary


def test_the_options_reach_the_config_from_the_api() -> None:
    options = {"segment": {"stuff_classes": ["wall", "rug"], "unlabelled_id": 0}}
    assign = build_config("fast", parse_options(options)).pipeline.assign
    assert assign.stuff_classes == ("wall", "rug") and assign.unlabelled_id == 0
    default = build_config("fast", parse_options({})).pipeline.assign
    assert default.stuff_classes == ("wall", "floor", "ceiling") and default.unlabelled_id is None
    nothing = build_config("fast", parse_options({"segment": {"stuff_classes": []}}))
    assert nothing.pipeline.assign.stuff_classes == ()


@pytest.mark.parametrize(
    ("given", "where"),
    [
        ({"unlabelled_id": -1}, "options.segment.unlabelled_id"),
        ({"unlabelled_id": 65536}, "options.segment.unlabelled_id"),
        ({"unlabelled_id": 1.5}, "options.segment.unlabelled_id"),
        ({"unlabelled_id": "zero"}, "options.segment.unlabelled_id"),
        ({"background_share": 1.5}, "options.segment.background_share"),
        ({"background_share": -0.1}, "options.segment.background_share"),
        ({"stuff_classes": ["wall", ""]}, "options.segment.stuff_classes.1"),
        ({"stuff_classes": [" rug"]}, "options.segment.stuff_classes.0"),
        ({"stuff_classes": [3]}, "options.segment.stuff_classes.0"),
        ({"stuff_classes": "wall"}, "options.segment.stuff_classes"),
        ({"stuff_classes": ["x"] * 257}, "options.segment.stuff_classes"),
    ],
)
def test_bad_values_are_refused_naming_the_field(given: dict[str, Any], where: str) -> None:
    with pytest.raises(InputError) as caught:
        parse_options({"segment": given})
    assert [p.path for p in caught.value.problems] == [where]


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("unlabelled_id", -1),
        ("unlabelled_id", True),
        ("background_share", 1.5),
        ("stuff_classes", ("wall", " ")),
        ("stuff_classes", "wall"),
    ],
)
def test_the_python_api_checks_them_too(field: str, value: Any) -> None:
    with pytest.raises(ValueError, match=field):
        AssignConfig(**{field: value})


def test_the_flags_give_the_same_options() -> None:
    from dcseg.cli import build_parser
    from dcseg.cli._options import build, given

    base = ["run", "c", "--agnostic-masks", "a", "--semantic-masks", "s", "--vocabulary", "v"]
    flags = ["--out", "o", "--stuff-classes", "wall, rug", "--unlabelled-id", "0"]
    args = build_parser().parse_args([*base, *flags, "--background-share", "1"])
    options = given(args, "segment")
    assert options == {"stuff_classes": ("wall", "rug"), "unlabelled_id": 0, "background_share": 1}
    assign = build("fast", {"segment": options}).pipeline.assign
    assert assign.stuff_classes == ("wall", "rug") and assign.unlabelled_id == 0
    assert assign.background_share == 1.0
    with pytest.raises(SystemExit, match=r"--unlabelled-id \(options.segment.unlabelled_id\)"):
        build("fast", {"segment": {"unlabelled_id": 70000}})
    with pytest.raises(SystemExit):
        build_parser().parse_args([*base, "--out", "o", "--stuff-classes", "wall,,rug"])


def test_the_reader_makes_the_unlabelled_id_unlabelled(tmp_path: Path) -> None:
    masks, _ = scannet_bundle(tmp_path)
    plain = read_semantic_maps(masks, SCANNET)["v0"].classes
    assert plain.tolist() == [[0] * 6 + [3] * 6]
    read = read_semantic_maps(masks, SCANNET, unlabelled=0)["v0"].classes
    assert read.tolist() == [[-1] * 6 + [3] * 6]
    # a value outside the vocabulary may be the unlabelled one: it is not a class index
    write_image(masks / "v0.png", np.where(LABEL_FILT == 0, 40, LABEL_FILT).astype(np.uint16))
    with pytest.raises(InputError, match="40"):
        read_semantic_maps(masks, SCANNET)
    assert read_semantic_maps(masks, SCANNET, unlabelled=40)["v0"].classes.tolist() == read.tolist()


@pytest.fixture
def fixed_clusters(monkeypatch: pytest.MonkeyPatch) -> None:
    """Gaussians 0-7 one cluster, 8-11 another (as in ``test_segment_scene``)."""
    clusters = np.array([0] * 8 + [1] * 4)
    fixed = Clustering(clusters, np.eye(2, dtype=np.float32), np.ones(N, dtype=np.float32))
    features = np.tile(np.array([1.0, 0.0], np.float32), (N, 1))
    monkeypatch.setattr("dcseg.pipeline.gated_features", lambda affinity, scale: features)
    monkeypatch.setattr("dcseg.pipeline.cluster_features", lambda *a, **k: fixed)


def segment_stage(tmp_path: Path, options: dict[str, Any]) -> Any:
    """The segment stage's class maps (read with the job's options) through the vote."""
    masks, vocabulary = scannet_bundle(tmp_path)
    config = build_config("fast", parse_options({"segment": options}))
    inputs = RunInputs(tmp_path, semantic_masks=masks, vocabulary=vocabulary)
    run = StageRun(inputs, config, tmp_path / "out")
    saved = SavedRun(scene(), {}, Vocabulary(()), [], {})
    saved = _with_semantic(run, saved)
    cfg = config.pipeline
    cfg = dataclasses.replace(cfg, assign=dataclasses.replace(cfg.assign, objects=False))
    return segment_scene(saved.trained, saved.semantic, len(SCANNET), cfg)


@pytest.mark.usefixtures("fixed_clusters")
def test_scannet_unannotated_pixels_give_no_class_0_votes(tmp_path: Path) -> None:
    """With ``unlabelled_id`` 0, ScanNet's unannotated pixels vote for nothing; without it
    they are votes for the vocabulary's class 0 and win cluster 0."""
    plain = segment_stage(tmp_path / "plain", {})
    assert plain.assignment.labels.tolist()[0] == 0
    assert (plain.semantic_ids == 0).any()
    seg = segment_stage(tmp_path / "option", {"unlabelled_id": 0})
    assert 0 not in seg.assignment.labels.tolist()
    assert not seg.assignment.votes[:, 0].any()
    assert not (seg.semantic_ids == 0).any()
    assert (seg.semantic_ids == 3).sum() >= 4


def test_stored_maps_of_a_run_follow_the_option(tmp_path: Path) -> None:
    """Re-segmenting a run with its own class maps (no new masks) applies the option too."""
    masks, _ = scannet_bundle(tmp_path)
    own = read_semantic_maps(masks, SCANNET)
    config = build_config("fast", parse_options({"segment": {"unlabelled_id": 0}}))
    run = StageRun(RunInputs(tmp_path), config, tmp_path / "out")
    saved = _with_semantic(run, SavedRun(scene(), own, SCANNET, [], {}))
    assert saved.semantic["v1"].classes.tolist() == [[-1] * 6 + [3] * 6]


def test_custom_stuff_classes_change_which_classes_are_stuff() -> None:
    names = ["wall", "rug", "chair", "floor"]
    default = build_config("fast", parse_options({})).pipeline.assign
    custom = build_config("fast", parse_options({"segment": {"stuff_classes": ["rug"]}}))
    assert stuff_ids(names, default.stuff_classes) == [0, 3]
    assert stuff_ids(names, custom.pipeline.assign.stuff_classes) == [1]


def rug_regions(stuff_classes: list[str]) -> int:
    """Objects of a rug cut into three touching clusters with unlike features, with the job's
    stuff classes (``build_objects`` end to end)."""
    assign = build_config("fast", parse_options({"segment": {"stuff_classes": stuff_classes}}))
    cfg = dataclasses.replace(assign.pipeline.assign, complete=False, follow_evidence_ratio=0.0)
    names = ["chair", "rug"]
    pieces = [patch(x, x + 0.3, 0, 0.3) for x in (0.0, 0.3, 0.6)]
    means = np.concatenate(pieces)
    labels = np.repeat([0, 1, 2], [len(p) for p in pieces]).astype(np.int64)
    centers = np.eye(3, dtype=np.float32)  # unlike features: objects never merge
    clustering = Clustering(labels, centers, np.ones(len(means), np.float32))
    votes = np.zeros((3, 2))
    votes[:, 1] = 1.0
    assignment = Assignment(np.ones(3, np.int64), np.ones(3), votes, np.ones(3, np.int64))
    semantic = np.ones(len(means), dtype=np.int64)
    evidence = np.zeros((len(means), 2))
    stuff = stuff_ids(names, cfg.stuff_classes)
    instances, _ = build_objects(
        means, RADIUS, evidence, clustering, assignment, semantic, cfg, stuff
    )
    return int(instances.n_instances)


def test_stuff_classes_decide_whether_a_surface_is_one_region() -> None:
    """A rug cut into three touching clusters: one region when the job names rug a stuff
    class, three object instances with the default stuff classes."""
    assert rug_regions(["rug"]) == 1
    assert rug_regions(["wall", "floor", "ceiling"]) == 3


def scannet_capture(tmp_path: Path) -> tuple[Path, Path, Path]:
    """A ScanNet export of 16 x 12 frames with ``label-filt`` maps: the left half
    unannotated (0), the right half chair (3)."""
    capture = write_scannet(make_scene(n=2), tmp_path / "scan")
    masks = tmp_path / "label-filt"
    for i in range(2):
        write_image(
            masks / f"{i}.png", np.repeat(np.array([[0, 3]], np.uint16), 8, axis=1)[[0] * 12]
        )
    vocabulary = tmp_path / "vocabulary.txt"
    write_vocabulary(vocabulary, SCANNET)
    return capture, masks, vocabulary


def test_validate_counts_the_unlabelled_id_as_no_class(tmp_path: Path) -> None:
    from dcseg.io.validate import validate_inputs

    capture, masks, vocabulary = scannet_capture(tmp_path)
    inputs = RunInputs(capture, semantic_masks=masks, vocabulary=vocabulary)
    plain = validate_inputs(inputs).summary["semantic_masks"]
    assert plain["classes_present"] == ["unannotated", "chair"]
    assert plain["labelled_fraction"] == 1.0
    report = validate_inputs(inputs, unlabelled=0)
    assert report.ok
    summary = report.summary["semantic_masks"]
    assert summary["classes_present"] == ["chair"] and summary["labelled_fraction"] == 0.5


def test_dcseg_validate_takes_the_unlabelled_id(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from dcseg.cli import main

    capture, masks, vocabulary = scannet_capture(tmp_path)
    given = [str(capture), "--semantic-masks", str(masks), "--vocabulary", str(vocabulary)]
    assert main(["validate", *given, "--unlabelled-id", "0", "--json"]) == 0
    assert '"labelled_fraction": 0.5' in capsys.readouterr().out
    with pytest.raises(SystemExit, match=r"--unlabelled-id \(options.segment.unlabelled_id\)"):
        main(["validate", *given, "--unlabelled-id", "70000"])
