"""Fuzz the API with schemathesis against its own OpenAPI document: every operation, with
generated inputs, answers without a server error, with a documented status, content type and
body schema.

Needs the ``schemathesis`` dev dependency (skipped without it). Its pytest plugin does not
support this pytest version, so each operation's strategy is driven through Hypothesis here.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest

from service.main import create_app
from tests.service.conftest import AUTH_A, TestClient, make_settings
from tests.service.test_uploads import _nothing_stored

schemathesis = pytest.importorskip("schemathesis")
hypothesis = pytest.importorskip("hypothesis")
strategies = pytest.importorskip("hypothesis.strategies")

MAX_EXAMPLES = 25
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


def _fuzz(operation: Any) -> None:
    """Run Hypothesis over one operation's generated cases."""
    excluded = []
    if operation.label in OPAQUE_INPUTS:
        excluded.append(schemathesis.checks.positive_data_acceptance)

    @hypothesis.settings(  # type: ignore[untyped-decorator]
        max_examples=MAX_EXAMPLES,
        deadline=None,
        derandomize=True,
        database=None,
        suppress_health_check=list(hypothesis.HealthCheck),
    )
    @hypothesis.given(case=operation.as_strategy())  # type: ignore[untyped-decorator]
    def check(case: Any) -> None:
        case.call_and_validate(headers=AUTH_A, excluded_checks=excluded)

    check()


def test_every_operation_conforms_to_the_schema(fuzz_client: Any) -> None:
    api = schemathesis.openapi.from_asgi("/openapi.json", fuzz_client.app)
    operations = [result.ok() for result in api.get_all_operations()]
    assert len(operations) >= 12
    for operation in operations:
        _fuzz(operation)
    _nothing_stored(fuzz_client)
