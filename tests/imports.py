"""Which heavy packages a statement imports, checked in a fresh interpreter."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterable


def loaded_after(statement: str, packages: Iterable[str]) -> list[str]:
    """The ``packages`` in ``sys.modules`` after running ``statement`` in a new process."""
    code = f"import sys; {statement}; print(' '.join(sorted({set(packages)!r} & set(sys.modules))))"
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True)
    return out.stdout.split()
