"""The API's option models, generated from the config dataclasses' field declarations.

Each field a job may set is declared once, with :func:`dcseg.fields.option` (bounds, allowed
values, help, flag); this module turns those declarations into strict pydantic models (the
JSON schema of ``POST /v1/jobs``) and :mod:`dcseg.cli._options` turns them into flags. Must
never import torch: the HTTP service imports it.
"""

from __future__ import annotations

import dataclasses
import typing
from collections.abc import Iterable, Mapping
from types import NoneType
from typing import Annotated, Any, Literal

from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    PlainValidator,
    StrictBool,
    WithJsonSchema,
    create_model,
)

from dcseg.fields import ABOVE, BOUNDS, CHOICES, FIXED, GROUP, HELP, NONE_WORD

Member = tuple[type[Any], str]
"""A settable field: its dataclass and its name."""

MAX_NAMES = 256
"""The most names a list option (``tuple[str, ...]``, e.g. stuff classes) may hold."""
MAX_NUMBERS = 16
"""The most numbers a list-of-numbers option (``tuple[float, ...]``, e.g. lens distortion
coefficients) may hold."""


def _plain_name(name: str) -> str:
    if name != name.strip() or "\n" in name:
        raise ValueError(f"a name must not start or end with blanks or hold a newline: {name!r}")
    return name


NAME = Annotated[
    str,
    # the pattern documents _plain_name in the schema (clients and fuzzers generate to it);
    # the validator checks it, with its own message
    Field(min_length=1, max_length=200, json_schema_extra={"pattern": r"^\S([^\n]*\S)?$"}),
    AfterValidator(_plain_name),
]
"""One name of a list option: non-blank, without leading or trailing blanks (the vocabulary
reader strips its names, so a padded name would never match one)."""


class Strict(BaseModel):
    """Unknown fields and non-finite numbers are refused."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


def declared(cls: type[Any], name: str) -> dataclasses.Field[Any]:
    """The dataclass field ``name`` of ``cls``."""
    return next(f for f in dataclasses.fields(cls) if f.name == name)


def settable(cls: type[Any]) -> dict[str, Member]:
    """Every field of ``cls`` a job may set (all but those declared ``fixed``)."""
    return {f.name: (cls, f.name) for f in dataclasses.fields(cls) if not f.metadata.get(FIXED)}


def grouped(group: str, classes: Iterable[type[Any]]) -> dict[str, Member]:
    """The fields of ``classes`` declared with ``group=group`` (:func:`dcseg.fields.option`)."""
    return {
        f.name: (cls, f.name)
        for cls in classes
        for f in dataclasses.fields(cls)
        if f.metadata.get(GROUP) == group
    }


def values_model(
    name: str,
    doc: str,
    members: Mapping[str, Member],
    *,
    overrides: bool,
    nullable: bool = False,
) -> type[Strict]:
    """A model with one field per member, typed and bounded by its declaration.

    ``overrides``: every field defaults to None (unset = the preset's value, described by its
    bounds when it has no help); otherwise fields default to the dataclass's default.
    ``nullable``: every field also accepts None (= unset).
    """
    fields: dict[str, Any] = {}
    for key, (cls, field_name) in members.items():
        f = declared(cls, field_name)
        hint = typing.get_type_hints(cls)[field_name]
        default = None if overrides else f.default
        kind = field_type(f, hint)
        kind = kind | None if nullable and not _takes_none(kind) else kind
        fields[key] = (kind, Field(default=default, description=_describe(f)))
    model: type[Strict] = create_model(name, __base__=Strict, **fields)
    model.__doc__ = doc
    return model


def _takes_none(kind: Any) -> bool:
    args = typing.get_args(kind)
    return NoneType in args or (bool(args) and NoneType in typing.get_args(args[0]))


def _describe(f: dataclasses.Field[Any]) -> str | None:
    bounds = f.metadata.get(BOUNDS)
    help_text: str | None = f.metadata.get(HELP)
    return help_text or (None if bounds is None else f"bounds {list(bounds)}")


def field_type(f: dataclasses.Field[Any], hint: Any) -> Any:
    """The pydantic type of a declared field (bounded, finite; optional when it may be None)."""
    meta = f.metadata
    args = typing.get_args(hint)
    optional = NoneType in args
    base = next(a for a in args if a is not NoneType) if optional else hint
    if meta.get(CHOICES):
        choices: Any = Literal.__getitem__(tuple(meta[CHOICES]))
        return choices | None if optional else choices
    if meta.get(NONE_WORD):
        low, high = meta[BOUNDS]
        return _cap(int(low), int(high), meta[NONE_WORD])
    inner = _inner(f.name, base, meta)
    return inner | None if optional else inner


def _inner(name: str, base: Any, meta: Mapping[str, Any]) -> Any:
    bounds = meta.get(BOUNDS)
    if base is bool:
        return StrictBool
    if base in (int, float):
        if bounds is None:
            raise TypeError(f"option {name} has no bounds")
        low, high = bounds
        lower = {"gt": low} if meta.get(ABOVE) else {"ge": low}
        return Annotated[base, Field(**lower, le=high, allow_inf_nan=False)]
    if typing.get_origin(base) is tuple:
        return _tuple(typing.get_args(base), bounds)
    raise TypeError(f"no option type for {name}: {base}")


def _tuple(items: tuple[Any, ...], bounds: tuple[float, float] | None) -> Any:
    """A list of names (``tuple[str, ...]``) or a fixed-length tuple of numbers."""
    if items == (str, Ellipsis):
        return Annotated[tuple[NAME, ...], Field(max_length=MAX_NAMES)]
    if items == (float, Ellipsis):  # coefficients: a few finite numbers
        number = Annotated[float, Field(allow_inf_nan=False)]
        return Annotated[tuple[number, ...], Field(min_length=1, max_length=MAX_NUMBERS)]
    element: Any
    if items[0] is int and bounds is not None:
        element = Annotated[int, Field(ge=bounds[0], le=bounds[1])]
    else:
        element = Annotated[float, Field(allow_inf_nan=False)]
    return tuple[tuple(element for _ in items)]  # type: ignore[misc]


def _cap(low: int, high: int, word: str) -> Any:
    """An ``int`` in ``[low, high]`` or the word ``word`` (no cap), with one precise error."""

    def check(value: Any) -> int | str | None:
        if value is None or value == word:
            return value  # type: ignore[no-any-return]
        if isinstance(value, float) and value.is_integer():
            value = int(value)  # 196.0 is an integer in JSON Schema, as the schema says
        if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
            raise ValueError(f"must be an integer in [{low}, {high}] or {word!r}, got {value!r}")
        return value

    schema = {
        "anyOf": [
            {"type": "integer", "minimum": low, "maximum": high},
            {"const": word},
            {"type": "null"},
        ]
    }
    return Annotated[int | str | None, PlainValidator(check), WithJsonSchema(schema)]
