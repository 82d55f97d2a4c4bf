"""Print the project's dependencies (pyproject.toml) without the ones named, one per line.

The images install the dependencies in a layer of their own, before the code, so that a code
change does not reinstall them; the API image leaves torch out (it never imports it):

    python3 docker/requirements.py pyproject.toml torch > requirements.txt
"""

from __future__ import annotations

import re
import sys
import tomllib
from pathlib import Path


def requirements(pyproject: Path, without: set[str]) -> list[str]:
    """The ``[project] dependencies`` of ``pyproject`` whose names are not in ``without``."""
    deps: list[str] = tomllib.loads(pyproject.read_text(encoding="utf-8"))["project"][
        "dependencies"
    ]
    return [dep for dep in deps if _name(dep) not in {_name(w) for w in without}]


def _name(requirement: str) -> str:
    """The normalised distribution name of a requirement string (PEP 503)."""
    name = re.split(r"[<>=!~;\[ ]", requirement.strip(), maxsplit=1)[0]
    return re.sub(r"[-_.]+", "-", name).lower()


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit("usage: requirements.py PYPROJECT [NAME ...]")
    sys.stdout.write(
        "".join(f"{dep}\n" for dep in requirements(Path(sys.argv[1]), set(sys.argv[2:])))
    )
