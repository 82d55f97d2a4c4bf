"""The viewer page and its server: configuration, served paths, bad runs."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import httpx
import pytest

from dcseg.errors import InputError
from dcseg.viewer import CONTENT_SECURITY_POLICY, ViewerConfig, ViewerFiles, render_page
from dcseg.viewer.server import check_run, serving
from tests.dcseg.viewer.browser import built as built
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
