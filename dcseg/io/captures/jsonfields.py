"""Reading JSON capture descriptions field by field, collecting every problem with its JSON path.

Messages look like ``capture.json: frames[3].c2w: missing`` so that a user can find the field.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dcseg.errors import InputError, Problem
from dcseg.io.folders import inside

__all__ = ["JsonFields", "load_json"]


def load_json(path: Path, shown: str) -> Any:
    """Parse a JSON file, raising :class:`InputError` naming ``shown`` on any failure."""
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError.single(shown, "missing") from None
    except UnicodeDecodeError:
        raise InputError.single(shown, "not UTF-8 text") from None
    except json.JSONDecodeError as exc:
        raise InputError.single(
            shown, f"invalid JSON ({exc.msg} at line {exc.lineno} column {exc.colno})"
        ) from None
    except OSError as exc:
        raise InputError.single(shown, f"cannot read file ({exc.strerror})") from None


def join(where: str, key: str | int) -> str:
    """The JSON path of ``key`` inside ``where`` (``frames[3]`` + ``c2w`` -> ``frames[3].c2w``)."""
    if isinstance(key, int):
        return f"{where}[{key}]"
    return f"{where}.{key}" if where else key


class JsonFields:
    """Typed access to fields of one JSON file; problems are collected, not raised.

    Every getter returns None when the field is absent or invalid (and records why), so a reader
    can walk the whole document and report everything at once.
    """

    def __init__(self, shown: str) -> None:
        self.shown = shown
        self.problems: list[Problem] = []

    def add(self, where: str, reason: str) -> None:
        """Record a problem at JSON path ``where`` (once: a top-level field every frame reads
        is reported once)."""
        problem = Problem(self.shown, f"{where}: {reason}" if where else reason)
        if problem not in self.problems:
            self.problems.append(problem)

    def raise_if_any(self) -> None:
        """Raise one InputError with every problem recorded so far."""
        if self.problems:
            raise InputError(self.problems)

    def get(self, obj: dict[str, Any], key: str, where: str, required: bool = True) -> Any:
        """``obj[key]``; records ``missing`` when required and absent, ``null`` when required
        and null (an optional null field reads as absent)."""
        if key in obj:
            if obj[key] is None and required:
                self.add(join(where, key), "must not be null")
            return obj[key]
        if required:
            self.add(join(where, key), "missing")
        return None

    def mapping(self, value: Any, where: str) -> dict[str, Any] | None:
        """``value`` if it is a JSON object, else record the problem."""
        if isinstance(value, dict):
            return value
        self.add(where, f"must be an object, got {_kind(value)}")
        return None

    def array(self, value: Any, where: str) -> list[Any] | None:
        """``value`` if it is a JSON array, else record the problem."""
        if isinstance(value, list):
            return value
        self.add(where, f"must be an array, got {_kind(value)}")
        return None

    def number(
        self, obj: dict[str, Any], key: str, where: str, required: bool = True
    ) -> float | None:
        """A finite number field."""
        value = self.get(obj, key, where, required)
        if value is None:
            return None
        numeric = isinstance(value, int | float) and not isinstance(value, bool)
        if not numeric or not math.isfinite(value):
            self.add(join(where, key), f"must be a finite number, got {value!r}")
            return None
        return float(value)

    def integer(
        self, obj: dict[str, Any], key: str, where: str, required: bool = True
    ) -> int | None:
        """A positive integer field (image sizes)."""
        value = self.number(obj, key, where, required)
        if value is None:
            return None
        if value != int(value) or value < 1:
            self.add(join(where, key), f"must be a positive integer, got {value!r}")
            return None
        return int(value)

    def string(
        self, obj: dict[str, Any], key: str, where: str, required: bool = True
    ) -> str | None:
        """A non-empty string field."""
        value = self.get(obj, key, where, required)
        if value is None:
            return None
        if not isinstance(value, str) or not value:
            self.add(join(where, key), f"must be a non-empty string, got {value!r}")
            return None
        return value

    def matrix3(self, obj: dict[str, Any], key: str, where: str) -> NDArray[np.float64] | None:
        """A 3x3 matrix (intrinsics) given as 3 rows of 3 finite numbers."""
        matrix = self._numbers(obj, key, where)
        if matrix is None:
            return None
        if matrix.shape != (3, 3) or not np.isfinite(matrix).all():
            self.add(join(where, key), "must be a 3x3 array of finite numbers (rows of 3)")
            return None
        return matrix

    def matrix4(self, obj: dict[str, Any], key: str, where: str) -> NDArray[np.float64] | None:
        """A 4x4 matrix given as 4 rows of 4 finite numbers (3 rows: ``[0 0 0 1]`` is added)."""
        matrix = self._numbers(obj, key, where)
        if matrix is None:
            return None
        if matrix.shape == (3, 4):
            matrix = np.vstack([matrix, [0.0, 0.0, 0.0, 1.0]])
        if matrix.shape != (4, 4):
            self.add(join(where, key), "must be a 4x4 array of numbers (rows of 4)")
            return None
        if not np.isfinite(matrix).all():
            self.add(join(where, key), "must hold finite numbers (no NaN or infinity)")
            return None
        return matrix

    def _numbers(self, obj: dict[str, Any], key: str, where: str) -> NDArray[np.float64] | None:
        """``obj[key]`` as a float array (empty when it is not nested lists of numbers); None
        when absent or null (recorded by :meth:`get`)."""
        value = self.get(obj, key, where)
        if value is None:
            return None
        try:
            return np.array(value, dtype=np.float64)
        except (TypeError, ValueError):
            return np.zeros(0)

    def relative_file(self, root: Path, value: str | None, where: str) -> Path | None:
        """``root / value`` when ``value`` is a relative path staying inside ``root``."""
        if value is None:
            return None
        path = inside(root, value)
        if path is None:
            self.add(where, f"path {value!r} must be relative to and inside the capture folder")
        return path


def _kind(value: Any) -> str:
    names = {dict: "an object", list: "an array", str: "a string", bool: "a boolean"}
    if value is None:
        return "null"
    return names.get(type(value), "a number" if isinstance(value, int | float) else "a value")
