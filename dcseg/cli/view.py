"""``dcseg view``: open a run's labelled Gaussians in the browser viewer."""

from __future__ import annotations

import argparse
import sys
import webbrowser
from pathlib import Path
from typing import Any


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "view",
        help="serve a run in the browser viewer",
        description="Serve the browser viewer of a run folder (scene_labelled.ply, "
        "instances.json, labels.json) on 127.0.0.1 until interrupted: objects coloured by "
        "instance or class, click to select, hide/show, download one object as PLY.",
    )
    parser.add_argument(
        "run_dir", metavar="RUN", type=Path, help="run folder (the --out of dcseg run or demo)"
    )
    parser.add_argument("--port", type=_port, default=8765, help="port (8765; 0 = any free)")
    parser.add_argument("--open", action="store_true", help="open the page in a web browser")
    parser.set_defaults(run=run)


def _port(text: str) -> int:
    try:
        port = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a port number: {text!r}") from None
    if not 0 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"port must be in 0..65535, got {port}")
    return port


def run(args: argparse.Namespace) -> int:
    from dcseg.errors import InputError
    from dcseg.viewer import ViewerNotBuilt
    from dcseg.viewer.server import make_server, url_of

    try:
        server = make_server(args.run_dir, args.port)
    except (InputError, ViewerNotBuilt) as error:
        sys.stderr.write(f"dcseg view: {error}\n")
        return 1
    except OSError as error:
        sys.stderr.write(f"dcseg view: cannot listen on port {args.port}: {error.strerror}\n")
        return 1
    url = url_of(server)
    sys.stdout.write(f"serving {args.run_dir} at {url} (Ctrl-C to stop)\n")
    sys.stdout.flush()
    if args.open:
        webbrowser.open(url)
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        server.server_close()
    return 0
