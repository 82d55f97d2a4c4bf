"""The real stages on the synthetic capture, and the Celery adapter without a broker."""

from __future__ import annotations

import json
import shutil
from typing import Any

import pytest

from dcseg.errors import InputError
from dcseg.stages import VALIDATE
from jobstore.contract import TASK_RUN_JOB, JobPaths
from tests.worker.conftest import add_job
from worker import celery_app
from worker.execute import execute_job
from worker.stages import LibraryStage, default_stages, job_config


def _use_scene(settings: Any, scene: Any) -> None:
    data = settings.storage_dir / "uploads" / "u1" / "data"
    shutil.rmtree(data)
    shutil.copytree(scene, data)


def test_validate_and_reconstruct_on_a_tiny_capture(store, settings, scene):
    _use_scene(settings, scene)
    job_id = add_job(
        store,
        options={
            "reconstruct": {"iterations": 2, "holdout": 0},
            "affinity": {"iterations": 5, "rays": 64},
        },
    )
    settings = settings.model_copy(update={"device": "cpu"})
    assert execute_job(job_id, store, settings, stages=default_stages()) == "succeeded"
    output = JobPaths(settings.storage_dir, job_id).output
    report = json.loads((output / "validate" / "report.json").read_text())
    assert report["capture"]["frames"] == 4 and report["semantic_masks"]["frames"] == 4
    metrics = json.loads((output / "reconstruct" / "reconstruction.json").read_text())
    assert metrics["gaussians"] > 0 and metrics["config"]["iterations"] == 2
    assert (output / "reconstruct" / "scene.ply").read_bytes().startswith(b"ply")
    assert (output / "train" / "state" / "affinity.npz").is_file()
    assert json.loads((output / "segment" / "instances.json").read_text())["instances"]


def test_an_upload_without_class_masks_is_segmented_class_agnostically(store, settings, scene):
    _use_scene(settings, scene)
    data = settings.storage_dir / "uploads" / "u1" / "data"
    shutil.rmtree(data / "masks" / "semantic")
    (data / "vocabulary.txt").unlink()
    options = {"reconstruct": {"iterations": 2, "holdout": 0}, "affinity": {"iterations": 5}}
    job_id = add_job(store, options=options)
    settings = settings.model_copy(update={"device": "cpu"})
    assert execute_job(job_id, store, settings, stages=default_stages()) == "succeeded"
    output = JobPaths(settings.storage_dir, job_id).output
    instances = json.loads((output / "segment" / "instances.json").read_text())["instances"]
    assert instances and all(i["label"] is None for i in instances)
    assert set(json.loads((output / "segment" / "metrics.json").read_text())["summary"]) == {
        "instances"
    }


def test_validate_stage_reports_damaged_inputs(store, settings, scene):
    _use_scene(settings, scene)
    data = settings.storage_dir / "uploads" / "u1" / "data"
    next((data / "depth").iterdir()).unlink()
    job_id = add_job(store)
    assert execute_job(job_id, store, settings, stages=[LibraryStage(VALIDATE)]) == "failed"
    error = store.get_job(job_id).error
    assert error["type"] == "invalid-input" and error["errors"]


def test_job_config_checks_preset_and_fields():
    job = job_config(
        {"preset": "fast", "options": {"reconstruct": {"iterations": 7}, "capture": {"stride": 2}}}
    )
    cfg, capture = job.pipeline, job.capture
    assert cfg.reconstruct.iterations == 7 and capture.stride == 2
    assert cfg.reconstruct.train_downscale == 2  # the rest is the fast preset
    with pytest.raises(InputError, match="unknown preset"):
        job_config({"preset": "nope"})
    with pytest.raises(InputError, match="options.reconstruct.bogus"):
        job_config({"preset": "fast", "options": {"reconstruct": {"bogus": 1}}})
    with pytest.raises(InputError, match="options.reconstruct.iterations"):
        job_config({"preset": "fast", "options": {"reconstruct": {"iterations": -1}}})


def test_celery_settings_and_task_adapter(monkeypatch):
    conf = celery_app.app.conf
    assert conf.task_acks_late and conf.task_reject_on_worker_lost
    assert conf.worker_prefetch_multiplier == 1
    assert conf.task_routes[TASK_RUN_JOB] == {"queue": "gpu"}
    assert conf.broker_transport_options["visibility_timeout"] >= 3600
    assert conf.task_soft_time_limit < conf.task_time_limit
    calls = []

    def fake_execute(job_id: str, store: Any, settings: Any, **options: Any) -> str:
        calls.append(job_id)
        return "succeeded"

    monkeypatch.setattr(celery_app, "execute_job", fake_execute)
    monkeypatch.setattr(celery_app, "_store", lambda: None)
    assert celery_app.run_job.run("job-9") == "succeeded"
    assert calls == ["job-9"] and celery_app.run_job.name == TASK_RUN_JOB


def test_derived_job_with_new_scale_trains_nothing(store, settings, scene, monkeypatch):
    _use_scene(settings, scene)
    tiny = {
        "reconstruct": {"iterations": 2, "holdout": 0},
        "affinity": {"iterations": 5, "rays": 64},
    }
    settings = settings.model_copy(update={"device": "cpu"})
    parent = add_job(store, options=tiny)
    assert execute_job(parent, store, settings, stages=default_stages()) == "succeeded"

    def fail(*args: Any, **kwargs: Any) -> None:
        raise AssertionError("trained again")

    monkeypatch.setattr("dcseg.pipeline.train_affinity", fail)
    monkeypatch.setattr("dcseg.reconstruct.fit_gaussians", fail)
    child = add_job(store, parent=parent, options={**tiny, "segment": {"scale": 0.3}})
    assert execute_job(child, store, settings, stages=default_stages()) == "succeeded"
    output = JobPaths(settings.storage_dir, child).output
    manifest = json.loads((output / "manifest.json").read_text())
    reused = {s["name"]: bool(s["details"].get("reused")) for s in manifest["stages"]}
    assert reused == {"validate": True, "reconstruct": True, "train": True, "segment": False}
    record = json.loads((output / "segment" / "run.json").read_text())
    assert record["config"]["scale"] == 0.3
