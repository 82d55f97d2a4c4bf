"""One finished run per test module, written in code (see :mod:`tests.scenes.runs`)."""

from __future__ import annotations

from tests.scenes.runs import run as run
