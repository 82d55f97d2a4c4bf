import json
from pathlib import Path

import pytest

from dcseg.config import CaptureOptions
from dcseg.errors import InputError
from dcseg.export.depth import recorded_options


def _run(tmp_path: Path, record: object) -> Path:
    run = tmp_path / "run"
    run.mkdir()
    (run / "run.json").write_text(json.dumps(record))
    return run


def test_the_recorded_capture_options_are_read_back(tmp_path: Path) -> None:
    stored = {"size": [64, 48], "stride": 2, "intrinsics": [585.0, 585.0, 320.0, 240.0]}
    options = recorded_options(_run(tmp_path, {"capture_options": stored}))
    assert options == CaptureOptions(
        size=(64, 48), stride=2, intrinsics=(585.0, 585.0, 320.0, 240.0)
    )


def test_a_run_recorded_before_the_options_or_no_run_reads_with_the_defaults(
    tmp_path: Path,
) -> None:
    assert recorded_options(_run(tmp_path, {"inputs": {}})) == CaptureOptions()
    assert recorded_options(None) == CaptureOptions()


@pytest.mark.parametrize(
    ("stored", "message"),
    [({"stride": 2, "zoom": 3}, "zoom"), ([2], "must be an object")],
)
def test_a_malformed_record_names_run_json_and_the_field(
    tmp_path: Path, stored: object, message: str
) -> None:
    run = _run(tmp_path, {"capture_options": stored})
    with pytest.raises(InputError) as caught:
        recorded_options(run)
    text = str(caught.value)
    assert str(run / "run.json") in text and "capture_options" in text and message in text
