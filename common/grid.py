"""A stretch x bend (x density) grid of material classes, as a classifier and a dataset see it.

Class ``id = (stretch_index * bend_count + bend_index) * density_count + density_index``; the
multipliers of the basis fabric's stretching, bending and areal density name the axes. A grid
with one density (the thesis's 54 classes) has ``id = stretch_index * bend_count + bend_index``
and writes no density keys, so its JSON is that of a stretch x bend grid. The simulator's
material set (:class:`simulator.cloth.material.MaterialSet`) has one; a trained classifier
stores one in its checkpoint; a dataset's manifest carries its set's. Plain numbers only.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from numbers import Integral
from typing import Any

__all__ = ["ClassGrid"]


@dataclasses.dataclass(frozen=True)
class ClassGrid:
    """The classes a classifier predicts: a stretch x bend x density grid, ids stretch-major.

    ``class_id = (stretch_index * bend_count + bend_index) * density_count + density_index``;
    the multipliers of the basis fabric's stretching, bending and density name the axes.
    """

    stretch_multipliers: tuple[float, ...]
    bend_multipliers: tuple[float, ...]
    density_multipliers: tuple[float, ...] = (1.0,)

    def __post_init__(self):
        for field in ("stretch_multipliers", "bend_multipliers", "density_multipliers"):
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
    def density_count(self) -> int:
        """Densities per (stretch, bend) cell; 1 for the thesis's grid."""
        return len(self.density_multipliers)

    @property
    def num_classes(self) -> int:
        """Classes: ``stretch_count * bend_count * density_count``."""
        return self.stretch_count * self.bend_count * self.density_count

    def position(self, class_id: int) -> tuple[int, int, int]:
        """(stretch index, bend index, density index) of a class id (checked)."""
        top = self.num_classes - 1
        if (
            isinstance(class_id, bool)
            or not isinstance(class_id, Integral)
            or not (0 <= int(class_id) <= top)
        ):
            raise ValueError(f"class_id must be an integer in [0, {top}], got {class_id!r}")
        cell, density = divmod(int(class_id), self.density_count)
        stretch, bend = divmod(cell, self.bend_count)
        return stretch, bend, density

    def class_id(self, stretch_index: int, bend_index: int, density_index: int = 0) -> int:
        """Class id of grid indices (the inverse of :meth:`position`)."""
        counts = (self.stretch_count, self.bend_count, self.density_count)
        indices = (stretch_index, bend_index, density_index)
        if not all(0 <= int(i) < n for i, n in zip(indices, counts, strict=True)):
            raise ValueError(f"grid indices {indices} outside the grid's counts {counts}")
        return (int(stretch_index) * self.bend_count + int(bend_index)) * self.density_count + int(
            density_index
        )

    def to_json(self) -> dict:
        """Plain JSON: the multipliers and the counts (a checkpoint's ``class_grid``).

        The density keys appear only where the densities are not the basis's alone, so a
        stretch x bend grid reads and hashes as before they existed.
        """
        out = {
            "stretch_multipliers": list(self.stretch_multipliers),
            "bend_multipliers": list(self.bend_multipliers),
            "num_classes": self.num_classes,
            "stretch_count": self.stretch_count,
            "bend_count": self.bend_count,
        }
        if self.density_multipliers != (1.0,):
            out["density_multipliers"] = list(self.density_multipliers)
            out["density_count"] = self.density_count
        return out

    @classmethod
    def from_json(cls, data: Any, field: str = "class_grid") -> ClassGrid:
        """The grid of a mapping with ``stretch_multipliers`` and ``bend_multipliers``.

        A dataset's material set (:meth:`~datasets.datamodule.ClothVideoDataModule.class_grid`,
        a manifest's ``material_set``) qualifies; other keys are ignored except the counts
        ``num_classes``, ``stretch_count``, ``bend_count`` and ``density_count``, which must
        agree; ``density_multipliers`` is optional (one density, multiplier 1, without it).
        """
        if isinstance(data, ClassGrid):
            return data
        keys = set(data) if isinstance(data, Mapping) else set()
        if not {"stretch_multipliers", "bend_multipliers"} <= keys:
            raise ValueError(f"{field} must have stretch_multipliers and bend_multipliers")
        grid = cls(
            tuple(data["stretch_multipliers"]),
            tuple(data["bend_multipliers"]),
            tuple(data.get("density_multipliers", (1.0,))),
        )
        names = ("num_classes", "stretch_count", "bend_count", "density_count")
        counts = {k: data[k] for k in names if k in data}
        stored = {**grid.to_json(), "density_count": grid.density_count}
        if any(int(v) != stored[k] for k, v in counts.items()):
            raise ValueError(f"{field}: counts {counts} do not match its multipliers")
        return grid

    def describe(self) -> str:
        """``54 (the 6 x 9 stretch x bend classes)``, for messages."""
        if self.density_count == 1:
            return (
                f"{self.num_classes} (the {self.stretch_count} x {self.bend_count} stretch x "
                "bend classes)"
            )
        return (
            f"{self.num_classes} (the {self.stretch_count} x {self.bend_count} x "
            f"{self.density_count} stretch x bend x density classes)"
        )
