"""A report section as a frozen dataclass: its known keys typed, the rest kept as they were."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any, ClassVar

__all__ = ["Section", "fields_of", "split_known"]


def fields_of(cls) -> list[str]:
    """The section's typed fields (``extra`` holds the rest)."""
    return [f.name for f in dataclasses.fields(cls) if f.name != "extra"]


def split_known(cls, data: Mapping[str, Any], what: str) -> tuple[dict, dict]:
    """``data`` as the constructor's known fields and the rest."""
    if not isinstance(data, Mapping):
        raise ValueError(f"{what} must be a mapping, got {type(data).__name__}")
    names = set(fields_of(cls))
    known = {k: v for k, v in data.items() if k in names}
    missing = [
        f.name
        for f in dataclasses.fields(cls)
        if f.name in names
        and f.name not in known
        and f.default is dataclasses.MISSING
        and f.default_factory is dataclasses.MISSING
    ]
    if missing:
        raise ValueError(f"{what} lacks {missing[0]!r}")
    return known, {k: v for k, v in data.items() if k not in names}


class Section:
    """A section of a report: its known keys as typed fields, the rest kept in ``extra``."""

    section: ClassVar[str]
    extra: dict

    @classmethod
    def from_json(cls, data: Mapping[str, Any]):
        """Read this section of a report."""
        known, extra = split_known(cls, data, cls.section)
        return cls(**known, extra=extra)

    def to_json(self) -> dict:
        """This section of a report."""
        return {**self.extra, **{k: getattr(self, k) for k in fields_of(type(self))}}
