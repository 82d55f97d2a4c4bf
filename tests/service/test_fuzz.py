"""Fuzz the API with schemathesis against its own OpenAPI document: every operation, with
generated inputs, answers without a server error, with a documented status, content type and
body schema.

Every route the app serves is fuzzed: the set of fuzzed operations must equal the document's
operations plus the routes hidden from it (each hidden route is fuzzed with the operation it
aliases), so a new route cannot be left out. The run is bounded: ``FUZZ_MAX_EXAMPLES``
generated cases per operation (environment ``DCSEG_FUZZ_MAX_EXAMPLES``, default 25), a
Hypothesis ``deadline`` per case and a watchdog that ends the run with a traceback if it hangs.

Needs the ``schemathesis`` dev dependency: skipped without it locally, but never under CI (CI
installs the dev extras, so a missing package fails instead of silently skipping). Its pytest
plugin does not support this pytest version, so each operation's strategy is driven through
Hypothesis here.
"""

from __future__ import annotations

import copy
import faulthandler
import importlib
import os
import re
from collections.abc import Iterator
from datetime import timedelta
from typing import Any

import pytest
from fastapi import FastAPI
from fastapi.routing import APIRoute

from service.main import create_app
from tests.service.conftest import AUTH_A, TestClient, make_settings
from tests.service.test_uploads import _nothing_stored


def _require(name: str) -> Any:
    """Import ``name``; skip when it is missing, except under CI where that is a failure."""
    if os.environ.get("CI"):
        return importlib.import_module(name)
    return pytest.importorskip(name)


schemathesis: Any = _require("schemathesis")
hypothesis: Any = _require("hypothesis")
strategies: Any = _require("hypothesis.strategies")

FUZZ_MAX_EXAMPLES = int(os.environ.get("DCSEG_FUZZ_MAX_EXAMPLES", "25"))
"""Generated cases per operation (the bound on the run's length)."""
CASE_DEADLINE = timedelta(seconds=10)
"""Hypothesis deadline of one case: a hang-level bound (a case takes milliseconds), not a
performance check."""
WATCHDOG_S = 900.0
"""The whole fuzz run is ended with a traceback of every thread after this long (a hang)."""
HTTP_METHODS = {"get", "put", "post", "delete", "patch", "head", "options", "trace"}
_CONVERTER = re.compile(r"{(\w+):\w+}")
"""A path parameter's converter (``{name:path}``), absent from the document."""
_PARAMETER = r"{\1}"
HIDDEN_ALIASES = {"POST /v1/jobs/{job_id}/cancel": "POST /v1/jobs/{job_id}:cancel"}
"""Routes left out of the OpenAPI document -> the documented operation they answer like."""
BROWSER_PAGES = {
    "GET /viewer/{job_id}",
    "GET /viewer/{job_id}/frame.json",
    "GET /viewer/static/{name}",
}
"""The viewer's HTML page, its frame and its static files: served for browsers, left out of the API
document on purpose (tests/service/test_viewer_route.py tests them)."""
OPAQUE_INPUTS = {"POST /v1/uploads", "GET /v1/jobs"}
"""Operations whose schema cannot say which values are acceptable (archive bytes, page tokens):
schema-valid inputs may be refused there, so that one check is skipped for them."""

for _media_type in (
    "application/zip",
    "application/x-tar",
    "application/gzip",
    "application/x-gzip",
):
    schemathesis.openapi.media_type(_media_type, strategies.binary(max_size=1024))


@pytest.fixture(scope="module")
def fuzz_client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Any]:
    # the limits answer 429 on every route (undocumented there), so keep them out of reach
    settings = make_settings(
        tmp_path_factory.mktemp("fuzz"), rate_limit_per_minute=10**6, failed_auth_per_minute=10**6
    )
    with TestClient(create_app(settings)) as client:
        yield client


def document_operations(document: dict[str, Any]) -> set[str]:
    """``"METHOD /path"`` of every operation of an OpenAPI document."""
    return {
        f"{method.upper()} {path}"
        for path, item in document["paths"].items()
        for method in item
        if method in HTTP_METHODS
    }


def served_operations(app: FastAPI) -> set[str]:
    """``"METHOD /path"`` of every API route the app serves (path converters dropped)."""
    return {
        f"{method} {_CONVERTER.sub(_PARAMETER, route.path)}"
        for route in _api_routes(app.routes)
        for method in route.methods or ()
    }


def _api_routes(routes: list[Any]) -> Iterator[APIRoute]:
    for route in routes:
        if isinstance(route, APIRoute):
            yield route
        elif hasattr(route, "original_router"):  # an included router (FastAPI >= 0.160)
            yield from _api_routes(route.original_router.routes)


def with_hidden_aliases(document: dict[str, Any]) -> dict[str, Any]:
    """The document plus each hidden alias, described as the operation it aliases."""
    extended = copy.deepcopy(document)
    for alias, twin in HIDDEN_ALIASES.items():
        method, path = alias.split(" ", 1)
        twin_method, twin_path = twin.split(" ", 1)
        spec = copy.deepcopy(document["paths"][twin_path][twin_method.lower()])
        spec["operationId"] = f"{spec['operationId']}_alias"
        extended["paths"].setdefault(path, {})[method.lower()] = spec
    return extended


def _fuzz(operation: Any) -> None:
    """Run Hypothesis over one operation's generated cases."""
    excluded = []
    if operation.label in OPAQUE_INPUTS or HIDDEN_ALIASES.get(operation.label) in OPAQUE_INPUTS:
        excluded.append(schemathesis.checks.positive_data_acceptance)

    @hypothesis.settings(  # type: ignore[untyped-decorator]
        max_examples=FUZZ_MAX_EXAMPLES,
        deadline=CASE_DEADLINE,
        derandomize=True,
        database=None,
        suppress_health_check=list(hypothesis.HealthCheck),
    )
    @hypothesis.given(case=operation.as_strategy())  # type: ignore[untyped-decorator]
    def check(case: Any) -> None:
        case.call_and_validate(headers=AUTH_A, excluded_checks=excluded)

    check()


def test_every_served_route_is_documented_or_a_known_alias(fuzz_client: Any) -> None:
    """A fuzz run over every route: a route must be in the OpenAPI document (or a listed
    hidden alias) to be fuzzed, so none can be left out."""
    app = fuzz_client.app
    documented = document_operations(app.openapi())
    assert served_operations(app) == documented | set(HIDDEN_ALIASES) | BROWSER_PAGES
    assert set(HIDDEN_ALIASES.values()) <= documented
    assert not BROWSER_PAGES & documented


def test_every_operation_conforms_to_the_schema(fuzz_client: Any) -> None:
    """A fuzz run (schemathesis) over every route with bounded time in CI."""
    app = fuzz_client.app
    document = with_hidden_aliases(app.openapi())
    api = schemathesis.openapi.from_dict(document)
    api.app = app
    fuzzed: set[str] = set()
    faulthandler.dump_traceback_later(WATCHDOG_S, exit=True)
    try:
        for result in api.get_all_operations():
            operation = result.ok()
            _fuzz(operation)
            fuzzed.add(operation.label)
    finally:
        faulthandler.cancel_dump_traceback_later()
    assert fuzzed == document_operations(document)
    assert fuzzed == document_operations(app.openapi()) | set(HIDDEN_ALIASES)
    _nothing_stored(fuzz_client)
