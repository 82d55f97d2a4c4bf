"""Command-line flags generated from the option declarations, and the one builder behind them.

Each flag is declared with its field (:func:`dcseg.fields.option`: ``flag``, ``help``,
bounds); :func:`add_flags` adds a group of them to a verb and :func:`given` reads back the
ones given, as the job options the API takes (``{"capture": {...}, "budget": {...}}``), which
:func:`build` turns into the job's config through :func:`dcseg.options.build_config`, naming
the flag of a refused value.
"""

from __future__ import annotations

import argparse
import dataclasses
import typing
from collections.abc import Callable, Mapping
from types import NoneType
from typing import Any

from dcseg.affinity.config import AffinityConfig
from dcseg.config import CaptureOptions, FrameBudget, JobConfig, PipelineConfig
from dcseg.errors import InputError
from dcseg.fields import BOUNDS, CHOICES, FLAG, HELP, NONE_WORD
from dcseg.option_models import Member, declared, settable
from dcseg.options import SEGMENT_OPTIONS, build_config, parse_options
from dcseg.reconstruct.config import ReconstructConfig

GROUPS: dict[str, dict[str, Member]] = {
    "capture": settable(CaptureOptions),
    "budget": settable(FrameBudget),
    "segment": SEGMENT_OPTIONS,
    "reconstruct": settable(ReconstructConfig),
    "affinity": settable(AffinityConfig),
}
"""The job option groups that have flags, with their settable fields."""


def parse_size(text: str) -> tuple[int, int]:
    """Parse ``WxH`` (e.g. ``320x240``) into ``(width, height)``."""
    try:
        width, height = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"size must look like 320x240, got {text!r}") from None
    if width < 1 or height < 1:
        raise argparse.ArgumentTypeError(f"size must be positive, got {text!r}")
    return width, height


def parse_intrinsics(text: str) -> tuple[float, float, float, float]:
    """Parse ``fx,fy,cx,cy`` into four floats."""
    try:
        fx, fy, cx, cy = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"intrinsics must look like 600,600,599.5,339.5 (fx,fy,cx,cy), got {text!r}"
        ) from None
    return fx, fy, cx, cy


def parse_numbers(text: str) -> tuple[float, ...]:
    """Parse comma-separated numbers (``-0.26,0.95,-0.005,0.003,1.16``)."""
    try:
        return tuple(float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected comma-separated numbers like -0.26,0.95,-0.005,0.003, got {text!r}"
        ) from None


def parse_names(text: str) -> tuple[str, ...]:
    """Parse comma-separated names (``wall,floor,ceiling``; ``""`` = none); each is stripped,
    and a blank one is refused."""
    if not text.strip():
        return ()
    names = tuple(name.strip() for name in text.split(","))
    if not all(names):
        raise argparse.ArgumentTypeError(
            f"names must look like wall,floor,ceiling (no blank name), got {text!r}"
        )
    return names


def parse_cap(text: str) -> int | str:
    """An integer (``640``) or a word (``native``, ``all``); the config builder checks which."""
    return int(text) if text.strip().lstrip("-").isdigit() else text.strip().lower()


def add_flags(parser: Any, group: str, only: tuple[str, ...] | None = None) -> None:
    """Add the flags of the job option group ``group`` (:data:`GROUPS`; ``only`` these of its
    options) to ``parser``; unset flags leave the preset's value."""
    for key, (cls, name) in GROUPS[group].items():
        if only is not None and key not in only:
            continue
        f = declared(cls, name)
        flag = f.metadata.get(FLAG)
        if flag is None:
            continue
        kind = _parser(f, typing.get_type_hints(cls)[name])
        choices = f.metadata.get(CHOICES)
        parser.add_argument(flag, dest=dest(flag), type=kind, choices=choices, help=_help(cls, f))


TITLES = {
    "capture": "capture options",
    "budget": "frame budget (default: the preset's)",
    "segment": "method",
    "reconstruct": "reconstruction (default: the preset's)",
    "affinity": "mask scores (docs/masks.md; default: keep every mask)",
}


def add_groups(parser: argparse.ArgumentParser, *groups: str) -> None:
    """Add the flags of each of ``groups`` as an argument group of its own."""
    for group in groups:
        add_flags(parser.add_argument_group(TITLES[group]), group)


def options_of(args: argparse.Namespace, *groups: str) -> dict[str, dict[str, Any]]:
    """The job options of the flags of ``groups`` that were given."""
    return {group: given(args, group) for group in groups}


def given(args: argparse.Namespace, group: str) -> dict[str, Any]:
    """The options of ``group`` whose flags were given, by their job option names."""
    values: dict[str, Any] = {}
    for key, (cls, name) in GROUPS[group].items():
        flag = declared(cls, name).metadata.get(FLAG)
        value = None if flag is None else getattr(args, dest(flag), None)
        if value is not None:
            values[key] = value
    return values


def dest(flag: str) -> str:
    """The ``argparse`` attribute of ``flag`` (``--max-side`` -> ``max_side``)."""
    return flag.lstrip("-").replace("-", "_")


def _parser(f: dataclasses.Field[Any], hint: Any) -> Callable[[str], Any] | None:
    if f.metadata.get(CHOICES):
        return None
    if f.metadata.get(NONE_WORD):
        return parse_cap
    args = typing.get_args(hint)
    base = next(a for a in args if a is not NoneType) if NoneType in args else hint
    if typing.get_origin(base) is tuple:
        items = typing.get_args(base)
        if items == (str, Ellipsis):
            return parse_names
        if items == (float, Ellipsis):
            return parse_numbers
        return parse_size if items[0] is int else parse_intrinsics
    return base if base in (int, float) else None  # type: ignore[no-any-return]


def _help(cls: type[Any], f: dataclasses.Field[Any]) -> str:
    text = f.metadata.get(HELP)
    if text:
        return str(text)
    bounds = f.metadata.get(BOUNDS)
    where = f"{cls.__name__}.{f.name}"
    return where if bounds is None else f"{where}, in {list(bounds)} (default: the preset's)"


def flags() -> dict[str, str]:
    """The flag of each job option the CLI sets (named in error messages), e.g.
    ``{"budget.max_keyframes": "--max-keyframes"}``."""
    named: dict[str, str] = {}
    for group, members in GROUPS.items():
        for key, (cls, name) in members.items():
            flag = declared(cls, name).metadata.get(FLAG)
            if flag is not None:
                named[f"{group}.{key}"] = flag
    return named


def build(preset: str | PipelineConfig, options: Mapping[str, Any]) -> JobConfig:
    """The config of ``options`` through the one builder the API and the worker use
    (:func:`dcseg.options.build_config`); exits naming the flag of a refused value."""
    try:
        return build_config(preset, parse_options(options))
    except InputError as error:
        lines = [f"{_flag(p.path)}: {p.reason}" for p in error.problems]
        raise SystemExit("dcseg: " + "; ".join(lines)) from None


def rebuild(stored: PipelineConfig, options: Mapping[str, Any]) -> JobConfig:
    """A stored run's config with ``options`` (e.g. ``{"segment": {"scale": 0.5}}``), through
    the same builder and with the same error report as :func:`build`."""
    return build(stored, options)


def _flag(path: str) -> str:
    field = path.removeprefix("options.")
    for name, flag in flags().items():
        if field == name or field.startswith(name + "."):
            return f"{flag} ({path})"
    return path


def capture_options(args: argparse.Namespace) -> CaptureOptions:
    """:class:`CaptureOptions` from the capture flags (:func:`add_flags`)."""
    return build("fast", {"capture": given(args, "capture")}).capture
