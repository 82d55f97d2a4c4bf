"""The one config builder (:mod:`dcseg.options`): bounds on every field, presets inside them,
the same configs for the CLI, the API and the worker, precise errors."""

from __future__ import annotations

import dataclasses
import typing
from typing import Any

import pytest

from dcseg.affinity.config import PRESETS as AFFINITY_PRESETS
from dcseg.affinity.config import AffinityConfig
from dcseg.config import (
    BUDGET_PRESETS,
    MAX_KEYFRAMES,
    MAX_SIDE,
    CaptureOptions,
    FrameBudget,
    PipelineConfig,
    preset,
)
from dcseg.errors import InputError
from dcseg.fields import BOUNDS, CHOICES, FIXED
from dcseg.options import (
    JobOptions,
    build_config,
    from_stored,
    parse_options,
)
from dcseg.reconstruct.config import PRESETS as RECONSTRUCT_PRESETS
from dcseg.reconstruct.config import ReconstructConfig
from dcseg.sizes import SCALED, SceneSize, resolve


def declared(stage: type, key: str) -> dict[str, Any]:
    """Each field's ``key`` declaration (:func:`dcseg.fields.option`), where it has one."""
    return {f.name: f.metadata[key] for f in dataclasses.fields(stage) if f.metadata.get(key)}


RECONSTRUCT_BOUNDS = declared(ReconstructConfig, BOUNDS)
AFFINITY_BOUNDS = declared(AffinityConfig, BOUNDS)


@pytest.mark.parametrize("stage", [ReconstructConfig, AffinityConfig])
def test_every_overridable_field_is_bounded_or_a_choice(stage):
    hints = typing.get_type_hints(stage)
    switches = {name for name, hint in hints.items() if hint is bool}
    names = {f.name for f in dataclasses.fields(stage)} - set(declared(stage, FIXED))
    bounds, choices = declared(stage, BOUNDS), declared(stage, CHOICES)
    assert names == set(bounds) | set(choices) | switches
    assert set(declared(stage, FIXED)) == {"seed"}


def test_a_switch_takes_only_a_json_boolean():
    options = parse_options({"reconstruct": {"planar_depth": True}})
    built = build_config("fast", options).pipeline
    assert built.reconstruct.planar_depth is True
    with pytest.raises(InputError, match="planar_depth"):
        parse_options({"reconstruct": {"planar_depth": "yes"}})


@pytest.mark.parametrize("name", ["fast", "paper"])
def test_presets_lie_inside_the_bounds(name):
    for cfg, bounds in (
        (RECONSTRUCT_PRESETS[name], RECONSTRUCT_BOUNDS),
        (AFFINITY_PRESETS[name], AFFINITY_BOUNDS),
    ):
        for field, (low, high) in bounds.items():
            value = getattr(cfg, field)
            assert value is None or low <= value <= high, (name, field, value)
    overrides = {
        "reconstruct": {k: getattr(RECONSTRUCT_PRESETS[name], k) for k in RECONSTRUCT_BOUNDS},
        "affinity": {k: getattr(AFFINITY_PRESETS[name], k) for k in AFFINITY_BOUNDS},
    }
    built = build_config(name, parse_options(overrides)).pipeline
    assert dataclasses.replace(built, rules=preset(name).rules) == preset(name)
    assert set(built.rules.fixed) == {n for n in SCALED if n.split(".")[0] in overrides}


@pytest.mark.parametrize("name", ["fast", "paper"])
def test_size_rules_stay_inside_the_bounds(name):
    """What the rules make of a preset is a value the API would accept, at any size."""
    huge = SceneSize(views=MAX_KEYFRAMES, pixels=MAX_SIDE * MAX_SIDE, gaussians=10**8)
    resolved = resolve(preset(name), huge)
    for cfg, bounds in (
        (resolved.reconstruct, RECONSTRUCT_BOUNDS),
        (resolved.affinity, AFFINITY_BOUNDS),
    ):
        for field, (low, high) in bounds.items():
            value = getattr(cfg, field)
            assert value is None or low <= value <= high, (name, field, value)


def test_defaults_are_the_preset():
    built = build_config("fast", JobOptions())
    cfg, capture = built.pipeline, built.capture
    assert cfg == preset("fast") and capture == CaptureOptions()


def test_segment_options_seed_every_stage_and_set_scale_and_matcher():
    options = parse_options({"segment": {"seed": 7, "scale": 0.5, "matcher": "matching"}})
    cfg = build_config("paper", options).pipeline
    assert cfg == dataclasses.replace(
        preset("paper").seeded(7),
        scale=0.5,
        assign=dataclasses.replace(preset("paper").assign, matcher="matching"),
    )


def test_segment_options_choose_what_the_label_maps_show():
    cfg = build_config("fast", parse_options({"segment": {"label_maps": "clusters"}})).pipeline
    assert cfg.assign.label_maps == "clusters"
    assert build_config("fast", JobOptions()).pipeline.assign.label_maps == "gaussians"
    with pytest.raises(InputError, match="label_maps"):
        parse_options({"segment": {"label_maps": "pixels"}})


def test_stored_options_rebuild_the_same_configs():
    options = parse_options(
        {"capture": {"size": [64, 48], "stride": 2}, "reconstruct": {"iterations": 9}}
    )
    stored = options.stored()
    assert from_stored({"preset": "fast", "options": stored}) == build_config("fast", options)
    assert stored["reconstruct"] == {"iterations": 9}


def test_options_stored_under_an_earlier_name_rebuild_under_the_new_one():
    old = {"preset": "fast", "options": {"budget": {"max_frames": "all"}}}
    assert from_stored(old).pipeline.budget.max_keyframes is None
    with pytest.raises(InputError, match="options.budget.max_frames"):
        parse_options({"budget": {"max_frames": "all"}})  # submissions use the new name


def test_every_bad_field_is_named():
    with pytest.raises(InputError) as caught:
        parse_options(
            {
                "capture": {"size": [60000, 2], "depth_trunc": float("nan")},
                "affinity": {"iterations": 10**9},
                "nope": 1,
            }
        )
    paths = {p.path for p in caught.value.problems}
    assert paths == {
        "options.capture.size.0",
        "options.capture.depth_trunc",
        "options.affinity.iterations",
        "options.nope",
    }


def test_unknown_preset_is_named():
    with pytest.raises(InputError, match="unknown preset 'huge'"):
        build_config("huge", JobOptions())


def test_min_confidence_is_bounded_and_reaches_the_capture_options():
    assert build_config("fast", parse_options({})).capture.min_confidence == 0
    capture = build_config("fast", parse_options({"capture": {"min_confidence": 2}})).capture
    assert capture.min_confidence == 2
    for bad in (-1, 3, 1.5):
        with pytest.raises(InputError) as caught:
            parse_options({"capture": {"min_confidence": bad}})
        assert [p.path for p in caught.value.problems] == ["options.capture.min_confidence"]


@pytest.mark.parametrize("name", ["fast", "paper"])
def test_budget_defaults_are_the_preset_and_words_lift_the_caps(name):
    cfg = build_config(name, JobOptions()).pipeline
    assert cfg.budget == BUDGET_PRESETS[name]
    lifted = build_config(name, parse_options({"budget": {"max_side": "native"}})).pipeline
    assert lifted.budget.max_side is None
    assert lifted.budget.max_keyframes == BUDGET_PRESETS[name].max_keyframes
    options = parse_options({"budget": {"max_keyframes": "all", "min_rotation_deg": 0}})
    assert build_config(name, options).pipeline.budget.max_keyframes is None
    assert options.stored()["budget"] == {"max_keyframes": "all", "min_rotation_deg": 0}


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("max_side", 8),
        ("max_side", 10**6),
        ("max_side", "big"),
        ("max_side", True),
        ("max_side", 196.5),
        ("max_keyframes", 0),
        ("max_keyframes", "none"),
        ("min_translation", -1.0),
        ("min_rotation_deg", 181.0),
    ],
)
def test_budget_out_of_bounds_is_named(field, value):
    with pytest.raises(InputError) as caught:
        parse_options({"budget": {field: value}})
    assert [p.path for p in caught.value.problems] == [f"options.budget.{field}"]


def test_a_whole_float_is_an_integer_as_in_json_schema():
    """The schema says ``integer``; JSON Schema counts 196.0 as one (found by the fuzzer)."""
    options = parse_options({"budget": {"max_side": 196.0, "max_keyframes": 7.0}})
    budget = build_config("fast", options).pipeline.budget
    assert (budget.max_side, budget.max_keyframes) == (196, 7)
    assert isinstance(budget.max_side, int)


def test_budget_travels_in_the_pipeline_config():
    cfg = preset("paper")
    assert PipelineConfig.from_dict(cfg.to_dict()).budget == BUDGET_PRESETS["paper"]
    with pytest.raises(ValueError, match="max_side"):
        FrameBudget(max_side=0)


def test_every_declared_option_reaches_the_api_and_its_flag_the_cli():
    """One declaration per option: the API models and the flags are generated from it."""
    from dcseg.cli import build_parser
    from dcseg.cli._options import GROUPS, dest, flags
    from dcseg.fields import FLAG
    from dcseg.option_models import declared as field_of

    schema = JobOptions.model_json_schema()
    expected = {}
    for group, members in GROUPS.items():
        ref = schema["properties"][group]["$ref"].split("/")[-1]
        assert set(schema["$defs"][ref]["properties"]) == set(members), group
        for key, (cls, name) in members.items():
            flag = field_of(cls, name).metadata.get(FLAG)
            if flag:
                expected[f"{group}.{key}"] = flag
    assert flags() == expected and expected["budget.max_keyframes"] == "--max-keyframes"
    args = ["run", "c", "--agnostic-masks", "a", "--semantic-masks", "s", "--vocabulary", "v"]
    run = build_parser().parse_args([*args, "--out", "o", "--max-keyframes", "7"])
    assert getattr(run, dest("--max-keyframes")) == 7
