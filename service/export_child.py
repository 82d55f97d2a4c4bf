"""The entry point of an export's child process (kept light: it imports the exporter and
little else, so a spawned child starts quickly)."""

from __future__ import annotations

import importlib
import json
import logging
import uuid
from pathlib import Path
from typing import Any

RUN = "segment"
"""What clients call the run folder the exporter reads (the job's segment stage)."""


def run_exporter(target: str, run: str, out: str, fmt: str, instances: list[int] | None) -> None:
    """Child process: run the exporter, write ``result.json`` beside ``out``."""
    from dcseg.errors import InputError

    result: dict[str, Any]
    module, _, name = target.partition(":")
    try:
        export_run = getattr(importlib.import_module(module), name)
        paths = export_run(Path(run), Path(out), fmt, instances=instances)
        result = {"files": [str(Path(p)) for p in paths]}
    except InputError as error:
        problems = [{"path": p.path, "reason": p.reason} for p in error.problems]
        result = {"type": "export-failed", "errors": _scrubbed(problems, run, out)}
    except Exception:
        error_id = uuid.uuid4().hex[:12]
        logging.getLogger(__name__).exception("export %s failed (error id %s)", fmt, error_id)
        result = {"type": "export-error", "error_id": error_id}
    Path(out).with_name("result.json").write_text(json.dumps(result), encoding="utf-8")


def _scrubbed(problems: list[dict[str, str]], run: str, out: str) -> list[dict[str, str]]:
    """Problems with storage paths replaced by names clients know (``segment/``, ``export/``)."""

    def clean(text: str) -> str:
        return text.replace(run, RUN).replace(out, "export")

    return [{k: clean(v) for k, v in p.items()} for p in problems]
