"""Contracts: the committed OpenAPI document, torch-free imports, problem+json everywhere."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

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


def test_an_unreachable_database_is_a_503_to_retry(client, monkeypatch):
    """A refused or dropped database connection (PostgreSQL restarting) answers 503 with
    Retry-After, which clients retry, not a 500."""
    from sqlalchemy.exc import OperationalError

    state = state_of(client)

    def refused(*args: object, **kwargs: object) -> None:
        raise OperationalError("SELECT 1", {}, ConnectionRefusedError("connection refused"))

    monkeypatch.setattr(state.store, "get_job", refused)
    response = client.get("/v1/jobs/00000000-0000-0000-0000-000000000000", headers=AUTH_A)
    body = assert_problem(response, 503)
    assert body["type"].endswith("database-unavailable")
    assert response.headers["Retry-After"] == str(state.settings.retry_after_s)
