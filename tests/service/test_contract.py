"""Contracts: the committed OpenAPI document, torch-free imports, problem+json everywhere."""

from __future__ import annotations

import json
import re
import subprocess
import sys
import tomllib
from collections.abc import Iterable, Iterator
from pathlib import Path

import pytest

from service.main import app
from service.openapi import DEFAULT_PATH, render
from tests.service.conftest import AUTH_A, assert_problem, state_of

REPO = Path(__file__).resolve().parents[2]


def test_openapi_document_is_up_to_date():
    committed = DEFAULT_PATH.read_text(encoding="utf-8")
    assert committed == render(app.openapi()), "run: python -m service.openapi"
    spec = json.loads(committed)
    assert "/v1/jobs/{job_id}:cancel" in spec["paths"]
    assert "application/x-tar" in spec["paths"]["/v1/uploads"]["post"]["requestBody"]["content"]


def test_api_and_jobstore_import_neither_torch_nor_worker():
    code = (
        "import sys, service.main, jobstore.store, jobstore.contract, dcseg.client; "
        "bad = [m for m in sys.modules if m == 'torch' or m.split('.')[0] == 'worker']; "
        "print(bad); sys.exit(1 if bad else 0)"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60
    )
    assert result.returncode == 0, result.stdout + result.stderr


def test_upload_validation_does_not_load_torch():
    code = (
        "import sys, service.uploads, dcseg.io.validate, dcseg.io.archive; "
        "sys.exit(1 if 'torch' in sys.modules else 0)"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60
    )
    assert result.returncode == 0, result.stdout + result.stderr


def test_unknown_route_and_method_are_problems(client):
    assert_problem(client.get("/v2/nothing", headers=AUTH_A), 404)
    response = client.put("/v1/jobs", headers=AUTH_A)
    assert_problem(response, 405)


def test_health(client):
    assert client.get("/healthz").json() == {"status": "ok", "checks": {}}
    ready = client.get("/readyz")
    assert ready.status_code == 200
    assert ready.json()["checks"] == {"database": "ok", "storage": "ok"}


def test_not_ready_is_a_problem(client, monkeypatch):
    state = state_of(client)
    state.store.engine.dispose()

    def broken() -> None:
        raise ConnectionError("down")

    monkeypatch.setattr(state.store, "ping", broken)
    body = assert_problem(client.get("/readyz"), 503)
    assert body["checks"]["database"].startswith("error")


@pytest.mark.parametrize(
    ("image", "packages"),
    [("api", {"dcseg", "jobstore", "service"}), ("worker", {"dcseg", "jobstore", "worker"})],
)
def test_images_ship_their_layer_and_what_it_imports(image: str, packages: set[str]):
    """The API image has no ``worker/`` and the worker image no ``service/`` (they never import
    each other; lint-imports checks it): each copies and lets in exactly its packages."""
    dockerfile = (REPO / f"docker/{image}.Dockerfile").read_text(encoding="utf-8")
    ignore = (REPO / f"docker/{image}.Dockerfile.dockerignore").read_text(encoding="utf-8")
    assert set(re.findall(r"^COPY (\w+) \./\1$", dockerfile, re.M)) == packages
    assert set(re.findall(r"^!(\w+)/\*\*$", ignore, re.M)) == packages


def test_api_image_requirements_cover_the_api_imports():
    """docker/api-requirements.txt must hold every project dependency the API process loads."""

    def names(lines: Iterable[str]) -> Iterator[str]:
        for line in lines:
            line = line.strip().strip('",')
            if line and not line.startswith("#"):
                yield re.split(r"[<>=\[ ]", line, maxsplit=1)[0].lower().replace("-", "_")

    import_name = {"opencv_python_headless": "cv2", "scikit_learn": "sklearn", "pymcubes": "mcubes"}
    requirements = (REPO / "docker/api-requirements.txt").read_text().splitlines()
    image = {import_name.get(n, n) for n in names(requirements)}
    pyproject = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["dependencies"]
    project = {import_name.get(n, n) for n in names(pyproject)}
    code = (
        "import sys, service.main, service.uploads, dcseg.io.validate, dcseg.io.archive\n"
        # the export child runs in the API image too (every format's writer)
        "import service.export_child, dcseg.export.gaussians, dcseg.export.meshes\n"
        "assert 'torch' not in sys.modules, 'an API-image import loaded torch'\n"
        "print(' '.join(sorted({m.split('.')[0] for m in sys.modules})))"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True
    )
    loaded = set(result.stdout.split()) & project
    assert loaded, "no project dependency seen: the check is broken"
    assert loaded <= image, f"the API image lacks {sorted(loaded - image)}"
