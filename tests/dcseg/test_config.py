"""Stored pipeline configs: round trip, retired fields, unknown fields."""

from __future__ import annotations

import pytest

from dcseg.config import RENAMED_KEYS, RETIRED_KEYS, PipelineConfig, preset


def test_retired_fields_of_a_stored_config_are_dropped_and_named() -> None:
    stored = preset("fast").to_dict()
    stored["assign"] = {**stored["assign"], "min_class_share": 0.15, "stuff_min_fraction": 0.05}
    with pytest.raises(ValueError, match="min_class_share"):
        PipelineConfig.from_dict(stored)  # strict for fresh configs
    cfg, dropped = PipelineConfig.from_stored(stored)
    assert dropped == ["assign.min_class_share", "assign.stuff_min_fraction"]
    assert cfg == preset("fast")


def test_a_stored_config_with_an_unknown_field_is_refused() -> None:
    stored = preset("fast").to_dict()
    stored["cluster"] = {**stored["cluster"], "from_the_future": 1}
    with pytest.raises(ValueError, match="'cluster': from_the_future"):
        PipelineConfig.from_stored(stored)


def test_retired_fields_are_not_current_fields() -> None:
    current = preset("fast").to_dict()
    for stage, retired in RETIRED_KEYS.items():
        assert stage in current
        assert not set(retired) & set(current[stage]), stage


def test_renamed_fields_of_a_stored_config_are_read_under_their_new_name() -> None:
    stored = preset("paper").to_dict()
    budget = dict(stored["budget"])
    budget["max_frames"] = budget.pop("max_keyframes")  # as an earlier version wrote it
    stored["budget"] = budget
    with pytest.raises(ValueError, match="max_frames"):
        PipelineConfig.from_dict(stored)
    cfg, dropped = PipelineConfig.from_stored(stored)
    assert cfg == preset("paper") and dropped == []


def test_renamed_fields_are_current_fields_and_not_their_old_names() -> None:
    current = preset("fast").to_dict()
    for section, names in RENAMED_KEYS.items():
        for old, new in names.items():
            assert new in current[section] and old not in current[section]
