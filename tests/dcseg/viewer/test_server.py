"""The viewer page and its server: configuration, served paths, bad runs."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import httpx
import pytest

from dcseg.errors import InputError
from dcseg.export.depth import poses
from dcseg.export.frame import describe_frame
from dcseg.viewer import CONTENT_SECURITY_POLICY, ViewerConfig, ViewerFiles, render_page
from dcseg.viewer.server import check_run, serving
from tests.dcseg.viewer.browser import built as built
from tests.dcseg.viewer.posed import Z_TO_Y, run_with_poses
from tests.scenes.labelled import LabelledRun

pytestmark = pytest.mark.usefixtures("built")


def config_of(page: str) -> dict[str, object]:
    match = re.search(r'<script id="dcseg-config" type="application/json">(.*?)</script>', page)
    assert match is not None
    parsed: dict[str, object] = json.loads(match.group(1))
    return parsed


def test_page_embeds_its_configuration_as_inert_json():
    title = 'x</script><script>alert(1)</script>&"'
    files = ViewerFiles(scene="a.ply", instances="b.json", labels="c.json")
    page = render_page(ViewerConfig(title=title, files=files, static='s"t'))
    assert page.count("</script>") == 2  # the config element's and the module's only
    assert config_of(page) == {
        "title": title,
        "files": {"scene": "a.ply", "instances": "b.json", "labels": "c.json"},
        "up": "+z",
        "frame": None,
    }
    assert 'href="s&quot;t/viewer.css"' in page


def test_server_answers_only_the_viewer_paths(labelled_run: LabelledRun):
    with serving(labelled_run.folder) as url, httpx.Client(base_url=url) as client:
        page = client.get("/")
        assert page.status_code == 200
        assert page.headers["content-security-policy"] == CONTENT_SECURITY_POLICY
        assert config_of(page.text)["files"] == {
            "scene": "run/scene_labelled.ply",
            "instances": "run/instances.json",
            "labels": "run/labels.json",
        }
        assert config_of(page.text)["frame"] == "run/frame.json"
        script = client.get("/static/viewer.js")
        assert script.status_code == 200 and script.headers["content-type"] == "text/javascript"
        body = client.get("/run/instances.json").content
        assert body == (labelled_run.folder / "instances.json").read_bytes()
        assert client.head("/run/scene_labelled.ply").headers["content-length"] == str(
            (labelled_run.folder / "scene_labelled.ply").stat().st_size
        )
        for path in ("/run/run.json", "/run/../instances.json", "/static/index.html", "/x"):
            assert client.get(path).status_code == 404, path


def test_a_run_without_the_viewer_files_is_refused_naming_them(
    labelled_run: LabelledRun, tmp_path: Path
):
    run = tmp_path / "run"
    run.mkdir()
    shutil.copy(labelled_run.folder / "instances.json", run)
    with pytest.raises(InputError) as raised:
        check_run(run)
    assert str(raised.value) == (
        f"{run / 'scene_labelled.ply'}: missing; {run / 'labels.json'}: missing"
    )


def served_frame(run: Path) -> object:
    with serving(run) as url:
        response = httpx.get(url + "run/frame.json")
    assert response.headers["content-type"] == "application/json"
    return response.json()


def test_frame_json_is_derived_from_the_runs_poses_as_exports_derive_it(
    labelled_run: LabelledRun, tmp_path: Path
):
    no_poses = served_frame(labelled_run.folder)
    assert no_poses == describe_frame(None, [])
    run = run_with_poses(labelled_run, tmp_path / "run", Z_TO_Y)
    frame = served_frame(run)
    assert frame == describe_frame(poses(run), [])
    assert isinstance(frame, dict) and frame["world"]["up_axis"] == "+y"


def test_a_runs_own_frame_json_is_served_and_broken_poses_give_no_up(
    labelled_run: LabelledRun, tmp_path: Path
):
    run = Path(shutil.copytree(labelled_run.folder, tmp_path / "run"))
    (run / "state").mkdir()
    (run / "state" / "views.json").write_text("{not json", encoding="utf-8")
    assert served_frame(run) == describe_frame(None, [])
    (run / "frame.json").write_text('{"world": {"up_axis": "-x"}}', encoding="utf-8")
    assert served_frame(run) == {"world": {"up_axis": "-x"}}
