"""The runs the CLI verbs work on: a finished run and the viewer's labelled run."""

from __future__ import annotations

from tests.scenes.labelled import labelled_run as labelled_run
from tests.scenes.runs import run as run
