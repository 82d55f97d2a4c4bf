"""The OpenAPI document, shaped for SDK generators; ``python -m service.openapi [PATH]`` writes
``openapi/openapi.json``.

FastAPI's document is kept, with three changes generated clients need: the one ``Problem``
component every error response refers to (``service.problems``), the event payloads of the
event stream as components (``JobEvent`` and the ``*EventData`` of each type), and FastAPI's
default 422 body (``HTTPValidationError``, a body this API never sends: its 422s are problems)
replaced by the ``Problem`` reference.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

from fastapi import FastAPI
from fastapi.openapi.utils import get_openapi
from pydantic import BaseModel
from pydantic.json_schema import models_json_schema

from service.problems import PROBLEM_CONTENT, Problem
from service.schemas import JobEvent

DEFAULT_PATH = Path(__file__).resolve().parent.parent / "openapi" / "openapi.json"

COMPONENT_MODELS: tuple[type[BaseModel], ...] = (Problem, JobEvent)
"""Models described under ``components/schemas`` though no route names them as a model."""

FASTAPI_DEFAULTS = ("HTTPValidationError", "ValidationError")
"""FastAPI's components for its default 422 body, which this API never sends."""


def component_schemas() -> dict[str, Any]:
    """The schemas of :data:`COMPONENT_MODELS` and the models they use, by name."""
    _, top = models_json_schema(
        [(model, "serialization") for model in COMPONENT_MODELS],
        ref_template="#/components/schemas/{model}",
    )
    schemas: dict[str, Any] = top["$defs"]
    return schemas


def _replace_default_422(spec: dict[str, Any]) -> None:
    """Every 422 response refers to ``Problem`` (FastAPI adds its own body to routes with
    parameters that do not declare 422)."""
    for operations in spec["paths"].values():
        for operation in operations.values():
            response = operation.get("responses", {}).get("422")
            if response is not None and "HTTPValidationError" in json.dumps(response):
                operation["responses"]["422"] = {"description": response["description"]}
                operation["responses"]["422"].update(PROBLEM_CONTENT)
    schemas = spec["components"]["schemas"]
    for name in FASTAPI_DEFAULTS:
        schemas.pop(name, None)


def document(app: FastAPI) -> dict[str, Any]:
    """``app``'s OpenAPI document (made once, then cached as FastAPI does); the app's
    ``openapi()``, so ``/openapi.json`` serves the same document as the committed file."""
    if app.openapi_schema is None:
        spec = get_openapi(
            title=app.title,
            version=app.version,
            openapi_version=app.openapi_version,
            description=app.description,
            routes=app.routes,
        )
        schemas = spec.setdefault("components", {}).setdefault("schemas", {})
        schemas.update(component_schemas())
        _replace_default_422(spec)
        app.openapi_schema = spec
    return app.openapi_schema


def render(spec: dict[str, Any]) -> str:
    return json.dumps(spec, indent=2, sort_keys=True) + "\n"


def main(argv: list[str] | None = None) -> int:
    from service.main import app

    args = sys.argv[1:] if argv is None else argv
    path = Path(args[0]) if args else DEFAULT_PATH
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(render(app.openapi()), encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
