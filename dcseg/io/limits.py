"""Problems caused by a resource limit (a cap on entries, bytes or pixels), told apart from
other input problems so that callers can name the setting behind the limit."""

from __future__ import annotations

from dataclasses import dataclass

from dcseg.errors import InputError, Problem

__all__ = ["MAX_DECOMPRESSED_BYTES", "LimitProblem", "limit_error"]


@dataclass(frozen=True)
class LimitProblem(Problem):
    """An input refused because it exceeds a limit.

    Attributes:
        limit: the keyword argument that sets the limit (e.g. ``"max_entries"`` of
            :func:`dcseg.io.archive.safe_extract`), so that a service can name its own setting.
    """

    limit: str = ""


def limit_error(path: str, reason: str, limit: str) -> InputError:
    """An :class:`InputError` holding one :class:`LimitProblem`."""
    return InputError([LimitProblem(path, reason, limit)])


MAX_DECOMPRESSED_BYTES = 400_000_000
"""Largest buffer one compressed frame file (a Record3D ``.depth`` or ``.conf``, LZFSE) may
decompress to. Each file is decoded into a buffer of exactly the size its metadata implies
(``dw * dh * 4`` bytes of float32 depth, ``dw * dh`` bytes of confidence); a file that would
decode to more is refused without allocating more (zip-bomb safe). This cap bounds that implied
size itself (400 MB = 100 Mpx of float32, the per-image pixel limit)."""
