"""The browser viewer of a run's labelled Gaussians: the page and its static files.

The JavaScript is built from ``viewer/`` (npm, esbuild) into ``static/viewer.js`` by
``scripts/setup.sh`` and the Docker build; the page and stylesheet are plain files here. Both
``dcseg view`` (:mod:`dcseg.viewer.server`) and the API (``/viewer/{job_id}``) serve the same
page with a small JSON configuration naming the data files; the page fetches them itself, with
the API key in an ``Authorization`` header when the server asks for one.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

STATIC = Path(__file__).parent / "static"
"""The viewer's static files: ``index.html`` (template), ``viewer.css``, ``viewer.js`` (built)."""

STATIC_FILES = {"viewer.js": "text/javascript", "viewer.css": "text/css"}
"""Every file a page loads from :data:`STATIC`, with its media type."""

CONTENT_SECURITY_POLICY = (
    "default-src 'none'; script-src 'self' 'wasm-unsafe-eval'; worker-src blob: data:; "
    "style-src 'self'; connect-src 'self' blob: data:; img-src 'self' blob: data:; "
    "base-uri 'none'; form-action 'none'; frame-ancestors 'none'"
)
"""Sent with the page: only this origin's scripts and data; Spark's splat sorter runs in a
blob: worker and compiles WebAssembly."""

BUILD_HINT = "build it with `npm ci && npm run build` in viewer/ (scripts/setup.sh does)"


class ViewerNotBuilt(RuntimeError):
    """``static/viewer.js`` is missing: the npm build did not run."""


@dataclass(frozen=True)
class ViewerFiles:
    """Where the page fetches the run's files from (URLs relative to the page's origin)."""

    scene: str
    instances: str
    labels: str


@dataclass(frozen=True)
class ViewerConfig:
    """What the page needs to know: a title, the data URLs, where its static files are, the
    URL of the run's ``frame.json`` (its up axis sets the camera's; None = none served) and the
    up axis used when no frame states one (``+z``: dcseg's synthetic scenes and ScanNet)."""

    title: str
    files: ViewerFiles
    static: str
    up: str = "+z"
    frame: str | None = None


def bundle() -> Path:
    """The built ``viewer.js``; raises :class:`ViewerNotBuilt` with how to build it."""
    path = STATIC / "viewer.js"
    if not path.is_file():
        raise ViewerNotBuilt(f"the viewer bundle {path} is missing: {BUILD_HINT}")
    return path


def static_file(name: str) -> Path | None:
    """The static file ``name`` when it is one of :data:`STATIC_FILES`, else None."""
    if name not in STATIC_FILES:
        return None
    return bundle() if name == "viewer.js" else STATIC / name


def render_page(config: ViewerConfig) -> str:
    """The viewer page with ``config`` embedded as JSON (``<`` escaped, so no value can close
    the script element)."""
    body = asdict(config)
    static = body.pop("static")
    text = json.dumps(body).replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026")
    template = (STATIC / "index.html").read_text(encoding="utf-8")
    return template.replace("{{config}}", text).replace("{{static}}", _attribute(static))


def _attribute(value: str) -> str:
    """``value`` safe inside a double-quoted HTML attribute."""
    return value.replace("&", "&amp;").replace('"', "&quot;").replace("<", "&lt;")
