"""A stretch x bend grid of material classes, as a classifier and a dataset both see it.

Class ``id = stretch_index * bend_count + bend_index``; the multipliers of the basis fabric's
stretching and bending name the rows and columns. The simulator's material set
(:class:`simulator.cloth.material.MaterialSet`) has one; a trained classifier stores one in its
checkpoint; a dataset's manifest carries its set's. Plain numbers only.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any

__all__ = ["ClassGrid"]


@dataclasses.dataclass(frozen=True)
class ClassGrid:
    """The classes a classifier predicts: a stretch x bend grid, ids stretch-major.

    ``class_id = stretch_index * bend_count + bend_index``; the multipliers of the basis
    fabric's stretching and bending name the rows and columns in reports.
    """

    stretch_multipliers: tuple[float, ...]
    bend_multipliers: tuple[float, ...]

    def __post_init__(self):
        for field in ("stretch_multipliers", "bend_multipliers"):
            values = getattr(self, field)
            try:
                numbers = tuple(float(v) for v in values)
            except (TypeError, ValueError):
                numbers = ()
            if not numbers or not all(math.isfinite(v) and v > 0 for v in numbers):
                raise ValueError(
                    f"class_grid.{field} must be a non-empty list of numbers > 0, got {values!r}"
                )
            object.__setattr__(self, field, numbers)

    @property
    def stretch_count(self) -> int:
        """Rows of the grid."""
        return len(self.stretch_multipliers)

    @property
    def bend_count(self) -> int:
        """Columns of the grid."""
        return len(self.bend_multipliers)

    @property
    def num_classes(self) -> int:
        """Classes: ``stretch_count * bend_count``."""
        return self.stretch_count * self.bend_count

    def to_json(self) -> dict:
        """Plain JSON: the multipliers and the counts (a checkpoint's ``class_grid``)."""
        return {
            "stretch_multipliers": list(self.stretch_multipliers),
            "bend_multipliers": list(self.bend_multipliers),
            "num_classes": self.num_classes,
            "stretch_count": self.stretch_count,
            "bend_count": self.bend_count,
        }

    @classmethod
    def from_json(cls, data: Any, field: str = "class_grid") -> ClassGrid:
        """The grid of a mapping with ``stretch_multipliers`` and ``bend_multipliers``.

        A dataset's material set (:meth:`~datasets.datamodule.ClothVideoDataModule.class_grid`,
        a manifest's ``material_set``) qualifies; other keys are ignored except the counts
        ``num_classes``, ``stretch_count`` and ``bend_count``, which must agree.
        """
        if isinstance(data, ClassGrid):
            return data
        keys = set(data) if isinstance(data, Mapping) else set()
        if not {"stretch_multipliers", "bend_multipliers"} <= keys:
            raise ValueError(f"{field} must have stretch_multipliers and bend_multipliers")
        grid = cls(tuple(data["stretch_multipliers"]), tuple(data["bend_multipliers"]))
        counts = {k: data[k] for k in ("num_classes", "stretch_count", "bend_count") if k in data}
        if any(int(v) != grid.to_json()[k] for k, v in counts.items()):
            raise ValueError(f"{field}: counts {counts} do not match its multipliers")
        return grid

    def describe(self) -> str:
        """``54 (the 6 x 9 stretch x bend classes)``, for messages."""
        return (
            f"{self.num_classes} (the {self.stretch_count} x {self.bend_count} stretch x bend "
            "classes)"
        )
