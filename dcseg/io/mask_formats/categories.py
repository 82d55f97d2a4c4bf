"""COCO category ids -> vocabulary indices, for the class maps of COCO and panoptic files.

With a ``categories`` list (``id``, ``name``) the names are looked up in the vocabulary, so the
files' own ids (COCO's 1..90, a detector's prompt order) need no renumbering; without one,
``category_id`` is the vocabulary index itself (detectron2's contiguous ids, DEVA's prompts).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from dcseg.types import Vocabulary

__all__ = ["CategoryMap"]


@dataclass(frozen=True)
class CategoryMap:
    """How one file's category ids name classes of one vocabulary.

    Attributes:
        vocabulary: the classes.
        names: ``{category id: name}`` from the file's ``categories``; None when it has none.
    """

    vocabulary: Vocabulary
    names: dict[int, str] | None

    @classmethod
    def of(cls, data: Any, vocabulary: Vocabulary) -> CategoryMap:
        """The map of a parsed COCO / COCO panoptic JSON (its ``categories``, if any)."""
        categories = data.get("categories") if isinstance(data, dict) else None
        if not isinstance(categories, list):
            return cls(vocabulary, None)
        names = {
            c["id"]: str(c.get("name"))
            for c in categories
            if isinstance(c, dict) and isinstance(c.get("id"), int)
        }
        return cls(vocabulary, names)

    def lookup(self, category: int) -> tuple[int, str]:
        """The vocabulary index of ``category``, or -1 and why it has none."""
        n = len(self.vocabulary)
        if self.names is None:
            if 0 <= category < n:
                return category, ""
            return -1, (
                f"category_id {category} is beyond the vocabulary of {n} classes (without "
                "'categories', category_id is the vocabulary index)"
            )
        if category not in self.names:
            return -1, f"category_id {category} is not in 'categories'"
        name = self.names[category]
        if name not in self.vocabulary.names:
            return -1, f"category {name!r} is not in the vocabulary"
        return self.vocabulary.names.index(name), ""
