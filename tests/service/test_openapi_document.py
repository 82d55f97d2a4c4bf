"""The OpenAPI document as SDK generators read it: explicit operationIds, one ``Problem``
component, enums for states, and event payloads that real streams match."""

from __future__ import annotations

import json
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import jsonschema_rs
import pytest
from fastapi.routing import APIRoute

from jobstore.contract import ACTIVE, TERMINAL
from service.main import app
from service.openapi import DEFAULT_PATH
from tests.service.conftest import AUTH_A, assert_problem, state_of
from tests.worker.fakes import FakeStage
from worker.execute import execute_job
from worker.stage import StageContext, StageOutcome

OPERATION_IDS = {
    "getHealth",
    "getReadiness",
    "createUpload",
    "getUpload",
    "deleteUpload",
    "createDirectUpload",
    "completeDirectUpload",
    "createJob",
    "listJobs",
    "getJob",
    "cancelJob",
    "deleteJob",
    "listWebhookDeliveries",
    "streamJobEvents",
    "listArtifacts",
    "downloadArtifact",
    "headArtifact",
    "listInstances",
    "getInstance",
    "getSceneExport",
    "downloadSceneExportFile",
    "headSceneExportFile",
    "getInstanceExport",
    "downloadInstanceExportFile",
    "headInstanceExportFile",
}
"""The documented operationIds (CHANGELOG lists what each replaced); SDK method names."""

CAMEL_CASE = re.compile(r"^[a-z]+(?:[A-Z][a-z0-9]*)*$")
PROBLEM_REF = {"$ref": "#/components/schemas/Problem"}


@pytest.fixture(scope="module")
def spec() -> dict[str, Any]:
    document: dict[str, Any] = json.loads(Path(DEFAULT_PATH).read_text(encoding="utf-8"))
    return document


def operations(spec: dict[str, Any]) -> Iterator[tuple[str, str, dict[str, Any]]]:
    for path, methods in spec["paths"].items():
        for method, operation in methods.items():
            yield method, path, operation


def validator(spec: dict[str, Any], name: str) -> Any:
    """A JSON Schema validator of the component ``name`` (its references resolved)."""
    ref = f"#/components/schemas/{name}"
    return jsonschema_rs.validator_for({"$ref": ref, "components": spec["components"]})


PROBLEM_MEMBERS = {"type", "title", "status", "detail", "instance"}


def _objects(node: Any) -> Iterator[dict[str, Any]]:
    """Every ``properties`` object anywhere in ``node``."""
    if isinstance(node, dict):
        properties = node.get("properties")
        if isinstance(properties, dict):
            yield properties
        for value in node.values():
            yield from _objects(value)
    elif isinstance(node, list):
        for value in node:
            yield from _objects(value)


def _routes(routes: list[Any]) -> Iterator[APIRoute]:
    for route in routes:
        if isinstance(route, APIRoute):
            yield route
        elif hasattr(route, "original_router"):  # an included router (FastAPI >= 0.160)
            yield from _routes(route.original_router.routes)


def test_every_operation_has_its_documented_camel_case_id(spec):
    ids = [operation.get("operationId", "") for _, _, operation in operations(spec)]
    assert all(CAMEL_CASE.match(i) for i in ids), ids
    assert len(ids) == len(set(ids))
    assert set(ids) == OPERATION_IDS
    implicit = [r.name for r in _routes(app.routes) if r.include_in_schema and not r.operation_id]
    assert implicit == [], "give these routes operation_id="


def test_error_responses_refer_to_the_one_problem_component(spec):
    problem = spec["components"]["schemas"]["Problem"]
    assert {"type", "title", "status", "detail", "instance"} <= set(problem["required"])
    error_items = spec["components"]["schemas"]["ProblemError"]
    assert set(error_items["required"]) == {"path", "reason"}
    errors = 0
    for method, path, operation in operations(spec):
        for code, response in operation["responses"].items():
            if int(code) < 400:
                continue
            errors += 1
            assert response["content"] == {"application/problem+json": {"schema": PROBLEM_REF}}, (
                f"{method} {path} {code}"
            )
    assert errors > 90
    problems = [found for found in _objects(spec) if PROBLEM_MEMBERS <= set(found)]
    assert problems == [problem["properties"]], "a problem schema is inlined somewhere"
    assert "HTTPValidationError" not in json.dumps(spec)


def test_real_problems_match_the_component(spec, client):
    check = validator(spec, "Problem")
    missing = assert_problem(client.get("/v1/jobs/nope", headers=AUTH_A), 404)
    invalid = assert_problem(
        client.post("/v1/jobs", json={"upload_id": 3, "preset": "x"}, headers=AUTH_A), 422
    )
    assert invalid["errors"] and all(set(e) == {"path", "reason"} for e in invalid["errors"])
    for body in (missing, invalid):
        check.validate(body)
    assert not check.is_valid({**missing, "errors": [{"path": "x"}]})


def test_states_are_enums(spec):
    schemas = spec["components"]["schemas"]
    assert set(schemas["JobPublic"]["properties"]["status"]["enum"]) == ACTIVE | TERMINAL
    assert set(schemas["StatusEventData"]["properties"]["status"]["enum"]) == ACTIVE | TERMINAL
    assert set(schemas["CompletedEventData"]["properties"]["status"]["enum"]) == TERMINAL
    assert schemas["ExportPublic"]["properties"]["status"]["enum"] == ["succeeded", "running"]
    assert schemas["Health"]["properties"]["status"]["const"] == "ok"
    parameters = spec["paths"]["/v1/jobs"]["get"]["parameters"]
    status = next(p for p in parameters if p["name"] == "status")
    assert set(status["schema"]["anyOf"][0]["enum"]) == ACTIVE | TERMINAL


def test_event_stream_refers_to_its_event_schemas(spec):
    response = spec["paths"]["/v1/jobs/{job_id}/events"]["get"]["responses"]["200"]
    stream = response["content"]["text/event-stream"]
    assert stream["schema"]["type"] == "string"
    assert stream["x-itemSchema"] == {"$ref": "#/components/schemas/JobEvent"}
    event = spec["components"]["schemas"]["JobEvent"]
    assert set(event["discriminator"]["mapping"]) == {"status", "progress", "log", "completed"}


class LoggingStage(FakeStage):
    """A fake stage that also writes a log line (a ``log`` event)."""

    def run(self, ctx: StageContext, out: Path) -> StageOutcome:
        ctx.log(f"{self.name}: a log line")
        return super().run(ctx, out)


def sse_events(text: str) -> list[dict[str, Any]]:
    """The events of a server-sent event stream: ``{"event", "id", "data"}`` each."""
    events = []
    for block in text.split("\n\n"):
        fields = dict(
            line.split(": ", 1) for line in block.splitlines() if line and ":" in line[1:]
        )
        if "event" in fields:
            data = json.loads(fields["data"])
            events.append({"event": fields["event"], "id": int(fields["id"]), "data": data})
    return events


@pytest.mark.parametrize("fail", [False, True])
def test_real_event_streams_match_the_event_schemas(spec, client, upload_id, fail):
    state = state_of(client)
    job = client.post("/v1/jobs", json={"upload_id": upload_id}, headers=AUTH_A).json()
    failure = RuntimeError("boom") if fail else None
    stages = [LoggingStage("one", steps=2), FakeStage("two", fail=failure)]
    final = execute_job(job["id"], state.store, state.settings, stages=stages)
    assert final == ("failed" if fail else "succeeded")
    stream = client.get(f"/v1/jobs/{job['id']}/events", headers=AUTH_A)
    assert stream.status_code == 200
    events = sse_events(stream.text)
    assert {"status", "progress", "log", "completed"} <= {e["event"] for e in events}
    check = validator(spec, "JobEvent")
    for event in events:
        check.validate(event)
        data_schema = f"{event['event'].capitalize()}EventData"
        validator(spec, data_schema).validate(event["data"])
    completed = events[-1]
    assert completed["event"] == "completed" and completed["data"]["status"] == final
    assert (completed["data"]["error"] is not None) == fail
    assert not check.is_valid({**completed, "data": {**completed["data"], "status": "running"}})


def test_the_app_serves_the_committed_document(spec, client):
    assert client.get("/openapi.json").json() == spec
