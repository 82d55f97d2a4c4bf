"""Why an export was refused; each is an :class:`~dcseg.errors.InputError` naming the field."""

from __future__ import annotations

from dcseg.errors import InputError


class ExportError(InputError):
    """An export request that cannot be served (a bad request, not a server fault)."""


class UnknownFormatError(ExportError):
    """The format is not one of :data:`dcseg.export.FORMATS`."""


class UnknownInstanceError(ExportError):
    """An instance id the run's ``instances.json`` does not hold (HTTP: 404)."""


class RunNotFinishedError(ExportError):
    """The folder is not a finished, segmented run (HTTP: 409 while a job still runs)."""
