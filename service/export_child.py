"""The export child process: ``python -m service.export_child '<job JSON>'`` (kept light: it
imports the exporter and little else, so it starts quickly).

The job is ``{target, run, out, fmt, instances, options}``; the outcome is written to
``result.json`` beside ``out``: ``{"files": [paths relative to out]}`` or
``{"type": ..., ...}``.
"""

from __future__ import annotations

import importlib
import json
import logging
import sys
import uuid
from pathlib import Path
from typing import Any

RUN = "segment"
"""What clients call the run folder the exporter reads (the job's segment stage)."""


def run_exporter(
    target: str,
    run: str,
    out: str,
    fmt: str,
    instances: list[int] | None,
    options: dict[str, Any],
) -> None:
    """Child process: run the exporter, write ``result.json`` beside ``out``.

    ``options`` are ``dcseg.export.ExportOptions`` fields (none = the exporter's defaults)."""
    from dcseg.errors import InputError

    result: dict[str, Any]
    module, _, name = target.partition(":")
    try:
        export_run = getattr(importlib.import_module(module), name)
        paths = export_run(
            Path(run), Path(out), fmt, instances=instances, options=_options(options)
        )
        _scrub_sidecars(paths, run)
        result = {"files": [_inside(Path(p), Path(out)) for p in paths]}
    except InputError as error:
        problems = [{"path": p.path, "reason": p.reason} for p in error.problems]
        result = {"type": "export-failed", "errors": _scrubbed(problems, run, out)}
    except Exception:
        error_id = uuid.uuid4().hex[:12]
        logging.getLogger(__name__).exception("export %s failed (error id %s)", fmt, error_id)
        result = {"type": "export-error", "error_id": error_id}
    Path(out).with_name("result.json").write_text(json.dumps(result), encoding="utf-8")


def _inside(path: Path, out: Path) -> str:
    """``path`` relative to ``out`` (the exporter may return it relative to the working
    directory, as ``out`` was given, or absolute); ValueError when it is not inside."""
    return path.resolve().relative_to(out.resolve()).as_posix()


def _scrub_sidecars(paths: list[Path], run: str) -> None:
    """JSON sidecars name the run folder: give clients ``segment``, never a storage path."""
    for path in map(Path, paths):
        if path.suffix == ".json":
            text = path.read_text(encoding="utf-8")
            if run in text:
                path.write_text(text.replace(json.dumps(run)[1:-1], RUN), encoding="utf-8")


def _scrubbed(problems: list[dict[str, str]], run: str, out: str) -> list[dict[str, str]]:
    """Problems with storage paths replaced by names clients know (``segment/``, ``export/``)."""

    def clean(text: str) -> str:
        return text.replace(run, RUN).replace(out, "export")

    return [{k: clean(v) for k, v in p.items()} for p in problems]


def _options(values: dict[str, Any]) -> Any:
    if not values:
        return None
    return importlib.import_module("dcseg.export").ExportOptions(**values)


def main(argv: list[str]) -> int:
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    job = json.loads(argv[0])
    run_exporter(
        job["target"], job["run"], job["out"], job["fmt"], job["instances"], job["options"]
    )
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
