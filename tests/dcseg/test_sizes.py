"""Size rules (:mod:`dcseg.sizes`): the presets' values at the reference size, the documented
growth at ten times the sizes, explicit values kept."""

from __future__ import annotations

import dataclasses

import pytest

from dcseg.config import PipelineConfig, preset
from dcseg.options import build_config, parse_options
from dcseg.sizes import (
    REFERENCE,
    SCALED,
    SceneSize,
    SizeRules,
    describe,
    reconstruct_record,
    resolve,
    summary,
    train_views,
)

TEN_TIMES = SceneSize(views=400, pixels=10 * 320 * 240, gaussians=1_200_000)
GROWING = SizeRules(reconstruct_max_iterations=7500, affinity_max_iterations=5000)
"""Rules with room to grow (the fast preset's own caps are time-bounded)."""


def _growing(fixed: tuple[str, ...] = ()) -> PipelineConfig:
    """The fast preset's stage values under :data:`GROWING` rules."""
    return dataclasses.replace(preset("fast"), rules=dataclasses.replace(GROWING, fixed=fixed))


def _stages(cfg: PipelineConfig) -> PipelineConfig:
    """``cfg`` without its rules (whose ``fixed`` lists what was resolved)."""
    return dataclasses.replace(cfg, rules=SizeRules())


def test_the_reference_is_the_benchmark_scene() -> None:
    assert REFERENCE == SceneSize(views=40, pixels=320 * 240, gaussians=120_000)
    assert train_views(40, preset("fast").reconstruct.holdout) == 35


@pytest.mark.parametrize("name", ["fast", "paper"])
def test_at_the_reference_size_every_rule_gives_the_preset_value(name: str) -> None:
    given = preset(name)
    resolved = resolve(given, REFERENCE)
    assert _stages(resolved) == _stages(given)
    assert sorted(resolved.rules.fixed) == sorted(SCALED)  # every rule ran
    values = describe(given, resolved, REFERENCE)["values"]
    assert all(v["preset"] == v["value"] for v in values.values()) and set(values) == set(SCALED)


def test_growing_rules_at_ten_times_the_sizes() -> None:
    cfg = resolve(_growing(), TEN_TIMES)
    r = cfg.reconstruct
    assert r.iterations == 7500  # 1500 * 350 / 35 training views, capped at 7500
    assert (r.densify_from, r.densify_until, r.full_res_from) == (1500, 6000, 4500)  # x5
    assert r.opacity_reset_every == 0 and r.sh_degree_interval == 5000
    assert (r.max_init_points, r.max_gaussians) == (240_000, 480_000)  # x4 cap
    assert cfg.affinity.iterations == 5000  # 1000 * 400 / 40, capped at 5000
    assert cfg.cluster.min_cluster_size == 14  # the sample doubles: 20 000 points
    assert cfg.assign.min_area == 10_000  # 1.3 % of the image


def test_growth_in_proportion_below_the_caps() -> None:
    cfg = resolve(_growing(), SceneSize(views=80, pixels=320 * 240, gaussians=600_000))
    assert cfg.reconstruct.iterations == 3000  # 70 training views: twice the reference's
    assert cfg.reconstruct.densify_until == 2400 and cfg.reconstruct.max_gaussians == 240_000
    assert cfg.affinity.iterations == 2000
    assert cfg.cluster.min_cluster_size == 8  # sample 12 000: 7 * 1.2


def test_fast_preset_is_bounded_in_time() -> None:
    cfg = resolve(preset("fast"), TEN_TIMES)
    assert cfg.reconstruct.iterations == 1500 and cfg.reconstruct.densify_until == 1200
    assert (cfg.reconstruct.max_init_points, cfg.reconstruct.max_gaussians) == (90_000, 180_000)
    assert cfg.affinity.iterations == 2000


def test_smaller_scenes_keep_the_preset_steps_and_caps() -> None:
    given = preset("fast")
    cfg = resolve(given, SceneSize(views=5, pixels=80 * 60, gaussians=5000))
    assert cfg.reconstruct == given.reconstruct and cfg.affinity == given.affinity
    assert cfg.cluster == given.cluster
    assert cfg.assign.min_area == round(1000 * 80 * 60 / (320 * 240))


def test_paper_keeps_the_3dgs_schedule_and_grows_affinity_to_its_cap() -> None:
    cfg = resolve(preset("paper"), TEN_TIMES)
    assert cfg.reconstruct.iterations == 30_000 and cfg.reconstruct.densify_until == 15_000
    assert cfg.reconstruct.max_gaussians == 4_000_000
    assert cfg.affinity.iterations == 30_000


def test_explicit_values_win() -> None:
    options = {"reconstruct": {"iterations": 1500, "max_gaussians": 100_000}}
    options["affinity"] = {"iterations": 800}
    built = build_config("fast", parse_options(options)).pipeline
    assert set(built.rules.fixed) == {
        "reconstruct.iterations", "reconstruct.max_gaussians", "affinity.iterations"
    }  # fmt: skip
    cfg = resolve(built, TEN_TIMES)
    assert cfg.reconstruct.iterations == 1500 and cfg.reconstruct.densify_until == 1200
    assert cfg.reconstruct.max_gaussians == 100_000 and cfg.affinity.iterations == 800
    assert cfg.reconstruct.max_init_points == 90_000  # not given: follows its rule (x1.5 cap)
    record = describe(built, cfg, TEN_TIMES)
    assert "affinity.iterations" in record["explicit"]
    assert "affinity.iterations" not in record["values"]


def test_a_given_schedule_field_is_not_stretched() -> None:
    built = build_config("fast", parse_options({"reconstruct": {"densify_until": 1000}})).pipeline
    cfg = resolve(dataclasses.replace(built, rules=_growing(built.rules.fixed).rules), TEN_TIMES)
    assert cfg.reconstruct.iterations == 7500 and cfg.reconstruct.densify_until == 1000


def test_resolving_twice_changes_nothing_and_disabled_rules_change_nothing() -> None:
    once = resolve(preset("fast"), TEN_TIMES)
    assert resolve(once, SceneSize(views=4, pixels=100, gaussians=10)) == once
    off = dataclasses.replace(preset("fast"), rules=SizeRules(enabled=False))
    assert resolve(off, TEN_TIMES) == off


def test_gaussian_rules_wait_for_the_gaussians() -> None:
    cfg = resolve(preset("fast"), dataclasses.replace(TEN_TIMES, gaussians=None))
    assert "cluster.min_cluster_size" not in cfg.rules.fixed
    assert resolve(cfg, TEN_TIMES).cluster.min_cluster_size == 14


def test_resolved_config_round_trips_through_run_json_form() -> None:
    cfg = resolve(preset("fast"), TEN_TIMES)
    assert PipelineConfig.from_dict(cfg.to_dict()) == cfg


def test_reconstruct_record_and_summary_line() -> None:
    given = _growing()
    cfg, record = reconstruct_record(given.reconstruct, given.rules, TEN_TIMES)
    assert cfg.iterations == 7500
    assert record["values"]["reconstruct.iterations"] == {"preset": 1500, "value": 7500}
    assert set(record["values"]) == {n for n in SCALED if n.startswith("reconstruct.")}
    line = summary(record)
    assert "400 views" in line and "reconstruct.iterations 1500 -> 7500" in line
    assert "opacity_reset_every" not in line  # unchanged values are not listed
    unchanged = summary(describe(given, resolve(given, REFERENCE), REFERENCE))
    assert unchanged.endswith("the presets' values")


def test_unknown_fixed_names_are_refused() -> None:
    with pytest.raises(ValueError, match="no rule sets"):
        SizeRules(fixed=("affinity.rays",))
