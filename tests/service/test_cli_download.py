"""``dcseg download`` against a real server: the deliverables by default, ``--all``,
``--only`` globs, sizes on stderr, and files already there kept."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from dcseg.cli import main
from dcseg.client.selection import DELIVERABLES, human_size
from tests.service.conftest import KEY_A
from tests.service.live import LiveServer, finished_job, live, live_overrides, run_stages

__all__ = ["live", "live_overrides"]

BIG = os.urandom(1 << 20)
SEGMENT = {
    "scene_labelled.ply": b"ply labelled" + BIG[:4000],
    "scene.ply": b"ply" + BIG,
    "instances.json": b'{"instances": []}',
    "labels.json": b'{"labels": []}',
    "labels/000.png": b"png0",
    "labels/001.png": b"png1",
    "masks/000.png": b"mask0",
    "metrics.json": b"{}",
    "preview.png": b"preview",
    "run.json": b'{"run": 1}',
    "state/affinity.npz": BIG,
    "state/masks/000.npz": b"cached",
}
STAGES = {
    "validate": {"report.json": b"{}"},
    "reconstruct": {"scene.ply": b"ply" + BIG[:9000]},
    "train": {"state/affinity.npz": BIG, "run.json": b"{}"},
    "segment": SEGMENT,
}
WANTED = {
    f"segment/{name}" for name in SEGMENT if name != "scene.ply" and not name.startswith("state/")
}


@pytest.fixture
def job(live: LiveServer, scene_tar: bytes) -> str:
    return finished_job(live, scene_tar, run_stages(STAGES))


def _download(live: LiveServer, job: str, dest: Path, *extra: str) -> int:
    return main(["download", job, str(dest), "--url", live.url, "--api-key", KEY_A, *extra])


def _listed(out: str, dest: Path) -> set[str]:
    return {Path(line).relative_to(dest).as_posix() for line in out.split()}


def test_default_is_the_deliverables_with_sizes(live, job, tmp_path, capsys):
    dest = tmp_path / "out"
    assert _download(live, job, dest) == 0
    printed = capsys.readouterr()
    assert _listed(printed.out, dest) == WANTED
    on_disk = {p.relative_to(dest).as_posix() for p in dest.rglob("*") if p.is_file()}
    assert on_disk == WANTED  # no state/, no unlabelled copy, no earlier stage, no .part
    for name in WANTED:
        assert (dest / name).read_bytes() == SEGMENT[name.removeprefix("segment/")]
    total = sum(len(SEGMENT[n.removeprefix("segment/")]) for n in WANTED)
    assert f"{human_size(total)}  total, {len(WANTED)} files" in printed.err
    ply = len(SEGMENT["scene_labelled.ply"])
    assert f"{human_size(ply):>10}  segment/scene_labelled.ply" in printed.err


def test_all_and_only(live, job, tmp_path, capsys):
    assert _download(live, job, tmp_path / "all", "--all") == 0
    every = {f"{stage}/{name}" for stage, files in STAGES.items() for name in files}
    assert _listed(capsys.readouterr().out, tmp_path / "all") == every
    argv = ["--only", "segment/labels/*", "--only", "metrics.json,state"]
    assert _download(live, job, tmp_path / "some", *argv) == 0
    assert _listed(capsys.readouterr().out, tmp_path / "some") == {
        "segment/labels/000.png",
        "segment/labels/001.png",
        "segment/metrics.json",
        "train/state/affinity.npz",
        "segment/state/affinity.npz",
        "segment/state/masks/000.npz",
    }
    assert _download(live, job, tmp_path / "none", "--only", "*.obj") == 2
    assert "'*.obj'" in capsys.readouterr().err
    with pytest.raises(SystemExit) as refused:  # --all and --only exclude each other
        _download(live, job, tmp_path / "x", "--all", "--only", "run.json")
    assert refused.value.code == 2


def test_a_second_run_keeps_the_files_already_there(live, job, tmp_path, capsys):
    dest = tmp_path / "out"
    assert _download(live, job, dest) == 0
    (dest / "segment" / "metrics.json").write_bytes(b"damaged")
    live.app.seen.clear()
    assert _download(live, job, dest) == 0
    fetched = [path for _, path, _ in live.app.seen if "/artifacts/" in path]
    assert fetched == [f"/v1/jobs/{job}/artifacts/segment/metrics.json"]
    assert (dest / "segment" / "metrics.json").read_bytes() == b"{}"


def test_a_job_that_did_not_segment_gives_everything(live, scene_tar, tmp_path, capsys):
    stages = {"validate": STAGES["validate"], "reconstruct": STAGES["reconstruct"]}
    job = finished_job(live, scene_tar, run_stages(stages))
    assert _download(live, job, tmp_path / "out") == 0
    assert _listed(capsys.readouterr().out, tmp_path / "out") == {
        "validate/report.json",
        "reconstruct/scene.ply",
    }


def test_the_deliverables_are_segment_files():
    assert all(pattern.startswith("segment/") for pattern in DELIVERABLES)
    assert not any("state" in pattern for pattern in DELIVERABLES)


def test_unknown_job_exits_4(live, tmp_path, capsys):
    assert _download(live, "no-such-job", tmp_path / "out") == 4
    err = capsys.readouterr().err
    assert err.startswith("dcseg download: HTTP 404") and "Traceback" not in err
    assert err.count("\n") == 1


def test_an_unreachable_service_exits_3(tmp_path, monkeypatch, capsys):
    from dcseg.client import RetryPolicy
    from tests.service.conftest import free_port

    policy = RetryPolicy(attempts=2, backoff_s=0.01)
    monkeypatch.setattr("dcseg.client.sync.RetryPolicy", lambda: policy)
    url = f"http://127.0.0.1:{free_port()}"
    assert main(["download", "j", str(tmp_path / "out"), "--url", url]) == 3
    err = capsys.readouterr().err
    assert err.startswith(f"dcseg download: GET {url}/v1/jobs/j/artifacts failed")
    assert "after 2 tries" in err and err.count("\n") == 1
