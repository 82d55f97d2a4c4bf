"""The viewer page and ``dcseg view``'s server: configuration, served paths, bad runs."""

from __future__ import annotations

import json
import re
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import httpx
import pytest

from dcseg.cli import main
from dcseg.errors import InputError
from dcseg.viewer import CONTENT_SECURITY_POLICY, ViewerConfig, ViewerFiles, render_page
from dcseg.viewer.server import check_run, serving
from tests.scenes.labelled import LabelledRun

pytestmark = pytest.mark.usefixtures("built")


@pytest.fixture(scope="module")
def built() -> None:
    from dcseg.viewer import ViewerNotBuilt, bundle

    try:
        bundle()
    except ViewerNotBuilt as error:
        pytest.fail(str(error))


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


def test_dcseg_view_exits_1_naming_a_missing_folder(tmp_path: Path, capsys):
    assert main(["view", str(tmp_path / "nope"), "--port", "0"]) == 1
    err = capsys.readouterr().err
    assert (
        err
        == f"dcseg view: {tmp_path / 'nope'}: not a folder (expected a run folder of `dcseg run`)\n"
    )


def test_dcseg_view_rejects_a_bad_port(labelled_run: LabelledRun, capsys):
    with pytest.raises(SystemExit) as raised:
        main(["view", str(labelled_run.folder), "--port", "70000"])
    assert raised.value.code == 2
    assert "port must be in 0..65535, got 70000" in capsys.readouterr().err


def test_dcseg_view_serves_until_interrupted(labelled_run: LabelledRun):
    command = [sys.executable, "-m", "dcseg", "view", str(labelled_run.folder), "--port", "0"]
    # Ctrl-C must reach the server however the tests were started: a shell without job control
    # starts background jobs with SIGINT ignored, and an ignored signal stays ignored in children
    with subprocess.Popen(
        command, stdout=subprocess.PIPE, text=True, preexec_fn=_default_sigint
    ) as process:
        try:
            assert process.stdout is not None
            line = process.stdout.readline()
            pattern = r"serving (.+) at (http://127\.0\.0\.1:\d+/) \(Ctrl-C to stop\)\n"
            found = re.fullmatch(pattern, line)
            assert found is not None, line
            assert found.group(1) == str(labelled_run.folder)
            labels = httpx.get(found.group(2) + "run/labels.json", timeout=10).json()
            assert [entry["name"] for entry in labels["labels"]] == ["wall", "floor", "box", "ball"]
            process.send_signal(signal.SIGINT)
            assert process.wait(10) == 0
        finally:
            if process.poll() is None:
                process.kill()


def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)
