"""Declaring a method option once: its bounds, allowed values and help live with the field.

A stage config's field is declared with :func:`option`; the job options the API accepts
(:mod:`dcseg.options`) and the command-line flags (:mod:`dcseg.cli._options`) are generated
from these declarations, so adding an option is a one-line change in its config dataclass
(``docs/architecture.md``, "Adding an option"). Standard library only: the API imports it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

BOUNDS = "dcseg.bounds"
CHOICES = "dcseg.choices"
HELP = "dcseg.help"
FLAG = "dcseg.flag"
FIXED = "dcseg.fixed"
ABOVE = "dcseg.above"
GROUP = "dcseg.group"
NONE_WORD = "dcseg.none_word"


def option(
    default: Any = dataclasses.MISSING,
    *,
    bounds: tuple[float, float] | None = None,
    choices: tuple[str, ...] | None = None,
    help: str | None = None,
    flag: str | None = None,
    fixed: bool = False,
    above: bool = False,
    none_word: str | None = None,
    group: str | None = None,
) -> Any:
    """A dataclass field that jobs may set.

    Args:
        default: the value when no preset or job sets it.
        bounds: the closed ``[low, high]`` range a job may ask for (numeric fields). Bounds are
            policy, not physics: they keep one job from asking for days of work.
        choices: the allowed values of a string field.
        help: one line for the API schema and the flag's ``--help``.
        flag: the command-line flag that sets it (None = no flag of its own).
        fixed: not settable per stage (e.g. ``seed``, set for every stage at once).
        above: the low bound is exclusive (``(low, high]``).
        none_word: the word a job gives for None (``"native"``: no cap).
        group: the job option group that sets this field although its dataclass is not a
            group of its own (``"segment"``: the segmentation values a job sets directly).
    """
    metadata: dict[str, Any] = {BOUNDS: bounds, CHOICES: choices, HELP: help, FLAG: flag}
    metadata.update({FIXED: fixed, ABOVE: above, NONE_WORD: none_word, GROUP: group})
    return dataclasses.field(default=default, metadata=metadata)


def meta(field: dataclasses.Field[Any]) -> Mapping[str, Any]:
    """The option metadata of ``field`` (empty for plain fields)."""
    return field.metadata
