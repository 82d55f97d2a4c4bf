"""Seeded mutations of a file's bytes, for tests that damaged inputs are named, never crash.

Each mutation is one of: cut the file short; replace a number with text, NaN, infinity, a huge,
negative or zero value or nothing; drop or repeat a line; overwrite a few of the first bytes;
empty the file; append binary garbage; and, for JSON, replace a value anywhere in the document
with one of another type (or delete its key).
"""

from __future__ import annotations

import json
import random
import re
from collections.abc import Iterator
from typing import Any

NUMBER = re.compile(rb"-?\d+(\.\d+)?(e-?\d+)?")
NUMBER_SUBSTITUTES = (b"abc", b"nan", b"inf", b"1e999", b"-1", b"0", b"-0.5", b"99999999999", b"")
JSON_SUBSTITUTES: tuple[Any, ...] = ("text", 7, -1, 0.5, [], {}, [1, 2], {"a": 1}, True, 1e308)


def mutate(data: bytes, rng: random.Random) -> tuple[str, bytes]:
    """``(what was done, the mutated bytes)``."""
    if rng.random() < 0.4:
        done = _mutate_json(data, rng)
        if done is not None:
            return done
    kind = rng.choice(["cut", "number", "number", "number", "drop", "repeat", "bytes", "garbage"])
    if kind == "cut" and data:
        at = rng.randrange(len(data))
        return f"cut at byte {at}", data[:at]
    numbers = list(NUMBER.finditer(data))
    if kind == "number" and numbers:
        found, new = rng.choice(numbers), rng.choice(NUMBER_SUBSTITUTES)
        return f"{found.group()!r} -> {new!r}", data[: found.start()] + new + data[found.end() :]
    lines = data.split(b"\n")
    if kind in ("drop", "repeat") and len(lines) > 1:
        i = rng.randrange(len(lines))
        lines[i:i + 1] = [] if kind == "drop" else [lines[i], lines[i]]  # fmt: skip
        return f"{kind} line {i + 1}", b"\n".join(lines)
    if kind == "bytes" and data:
        out = bytearray(data)
        for _ in range(rng.randint(1, 4)):
            out[rng.randrange(min(len(out), 200))] = rng.randrange(256)
        return "bytes overwritten", bytes(out)
    return "garbage appended", data + b"\n\x00garbage \xff\xfe 1 2\n"


def _mutate_json(data: bytes, rng: random.Random) -> tuple[str, bytes] | None:
    try:
        doc = json.loads(data)
    except (ValueError, UnicodeDecodeError):
        return None
    paths = [path for path, _ in _nodes(doc) if path]
    if not paths:
        return None
    path = rng.choice(paths)
    parent = doc
    for key in path[:-1]:
        parent = parent[key]
    if rng.random() < 0.15:
        del parent[path[-1]]
        return f"json {list(path)} deleted", json.dumps(doc).encode()
    parent[path[-1]] = new = rng.choice((None, *JSON_SUBSTITUTES))
    return f"json {list(path)} -> {new!r}", json.dumps(doc).encode()


def _nodes(value: Any, path: tuple[Any, ...] = ()) -> Iterator[tuple[tuple[Any, ...], Any]]:
    yield path, value
    if isinstance(value, dict):
        for key, child in value.items():
            yield from _nodes(child, (*path, key))
    elif isinstance(value, list):
        for index, child in enumerate(value[:20]):
            yield from _nodes(child, (*path, index))
