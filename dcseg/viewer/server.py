"""``dcseg view``: serve the viewer page and one run's files on a loopback port.

Only a fixed set of paths answers: ``/`` (the page), ``/static/<file>`` (:data:`STATIC_FILES`),
``/run/<file>`` (:data:`RUN_FILES`) and ``/run/frame.json`` (the run's axes,
:func:`dcseg.viewer.frame.frame_json`); nothing else of the disk is reachable.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

from dcseg.errors import InputError, Problem
from dcseg.viewer import (
    CONTENT_SECURITY_POLICY,
    STATIC_FILES,
    ViewerConfig,
    ViewerFiles,
    bundle,
    render_page,
    static_file,
)
from dcseg.viewer.frame import FRAME_FILE, frame_json

log = logging.getLogger(__name__)

RUN_FILES = {
    "scene_labelled.ply": "application/octet-stream",
    "instances.json": "application/json",
    "labels.json": "application/json",
}
"""The files of a run folder the viewer reads, with their media types."""


def check_run(run: Path) -> None:
    """Raise :class:`InputError` naming every viewer file ``run`` lacks (and a missing bundle
    as :class:`~dcseg.viewer.ViewerNotBuilt`)."""
    if not run.is_dir():
        raise InputError.single(str(run), "not a folder (expected a run folder of `dcseg run`)")
    missing = [Problem(str(run / n), "missing") for n in RUN_FILES if not (run / n).is_file()]
    if missing:
        raise InputError(missing)
    bundle()


def page_config(run: Path) -> ViewerConfig:
    files = ViewerFiles(*(f"run/{name}" for name in RUN_FILES))
    return ViewerConfig(
        title=run.resolve().name, files=files, static="static", frame=f"run/{FRAME_FILE}"
    )


class _Handler(BaseHTTPRequestHandler):
    run: Path  # set on the subclass made by make_server
    page: bytes
    frame: bytes

    def do_GET(self) -> None:  # noqa: N802 (http.server's naming)
        self._answer(body=True)

    def do_HEAD(self) -> None:  # noqa: N802
        self._answer(body=False)

    def _answer(self, body: bool) -> None:
        path = self.path.split("?", 1)[0]
        if path in ("/", "/index.html"):
            self._send(self.page, "text/html; charset=utf-8", body, page=True)
            return
        if path == f"/run/{FRAME_FILE}":  # derived once, when the server was made
            self._send(self.frame, "application/json", body)
            return
        found = self._file(path)
        if found is None:
            self.send_error(HTTPStatus.NOT_FOUND, f"no such file: {path}")
            return
        file, media_type = found
        self._send(file.read_bytes(), media_type, body)

    def _file(self, path: str) -> tuple[Path, str] | None:
        folder, _, name = path.lstrip("/").partition("/")
        if folder == "static" and (file := static_file(name)) is not None:
            return file, STATIC_FILES[name]
        if folder == "run" and name in RUN_FILES:
            return self.run / name, RUN_FILES[name]
        return None

    def _send(self, data: bytes, media_type: str, body: bool, page: bool = False) -> None:
        self.send_response(HTTPStatus.OK)
        self.send_header("Content-Type", media_type)
        self.send_header("Content-Length", str(len(data)))
        self.send_header("Cache-Control", "no-store")
        self.send_header("X-Content-Type-Options", "nosniff")
        if page:
            self.send_header("Content-Security-Policy", CONTENT_SECURITY_POLICY)
        self.end_headers()
        if body:
            self.wfile.write(data)

    def log_message(self, format: str, *args: object) -> None:  # noqa: A002
        log.debug("%s %s", self.address_string(), format % args)


def make_server(run: Path, port: int = 0, host: str = "127.0.0.1") -> ThreadingHTTPServer:
    """A server (not yet serving) of ``run`` on ``host:port`` (0 = a free port)."""
    check_run(run)
    page = render_page(page_config(run)).encode("utf-8")
    attributes = {"run": run, "page": page, "frame": frame_json(run)}
    handler = type("RunHandler", (_Handler,), attributes)
    return ThreadingHTTPServer((host, port), handler)


def url_of(server: ThreadingHTTPServer) -> str:
    host, port = server.server_address[:2]
    return f"http://{host!s}:{port}/"


@contextmanager
def serving(run: Path, port: int = 0) -> Iterator[str]:
    """Serve ``run`` in a background thread for the ``with`` block; yields the page URL."""
    server = make_server(run, port)
    thread = threading.Thread(target=server.serve_forever, name="dcseg-view", daemon=True)
    thread.start()
    try:
        yield url_of(server)
    finally:
        server.shutdown()
        server.server_close()
        thread.join()
