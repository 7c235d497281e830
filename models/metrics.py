"""Classification metrics over the stretch x bend class grid (thesis Table 7.2 and more).

Pure torch functions of logits ``(N, classes)`` and labels ``(N,)``; the Lightning module and
the evaluation entry both use them, so training logs and reports agree. The grid is a
:class:`ClassGrid` of plain numbers that comes with the data (a dataset manifest's material
set, the datamodule's ``class_grid``) or with a checkpoint's hyper-parameters; nothing here
knows the simulator's 6 x 9 grid of 54 classes.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any

import torch

__all__ = [
    "BREAKDOWNS", "ClassGrid", "breakdown_metrics", "classification_metrics",
    "confusion_matrix", "grid_position",
]  # fmt: skip


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


def grid_position(classes: torch.Tensor, grid: ClassGrid) -> tuple[torch.Tensor, torch.Tensor]:
    """Class ids -> (stretch index, bend index) in ``grid``."""
    return torch.div(classes, grid.bend_count, rounding_mode="floor"), torch.remainder(
        classes, grid.bend_count
    )


def confusion_matrix(
    labels: torch.Tensor, predicted: torch.Tensor, num_classes: int
) -> torch.Tensor:
    """(classes, classes) counts; row = true class, column = predicted class."""
    flat = labels.long() * num_classes + predicted.long()
    return torch.bincount(flat, minlength=num_classes**2).view(num_classes, num_classes)


def classification_metrics(
    logits: torch.Tensor, labels: torch.Tensor, grid: ClassGrid
) -> dict[str, float]:
    """Top-1/top-5 accuracy, stretch- and bend-factor accuracy and grid errors.

    ``grid_mae`` is the mean L1 distance between the true and predicted cells of the
    stretch x bend grid (|d stretch index| + |d bend index|); ``stretch_mae`` and ``bend_mae``
    are its two parts. Accuracies are fractions in [0, 1].
    """
    classes = grid.num_classes
    if logits.ndim != 2 or logits.shape[1] != classes or labels.shape != logits.shape[:1]:
        raise ValueError(
            f"logits must be (N, {classes}) and labels (N,), got {tuple(logits.shape)} "
            f"and {tuple(labels.shape)}"
        )
    if labels.numel() == 0:
        raise ValueError("metrics need at least one sample")
    labels = labels.long()
    predicted = logits.argmax(dim=1)
    top5 = logits.topk(min(5, classes), dim=1).indices
    true_s, true_b = grid_position(labels, grid)
    pred_s, pred_b = grid_position(predicted, grid)
    stretch_err = (true_s - pred_s).abs().double()
    bend_err = (true_b - pred_b).abs().double()
    return {
        "acc": (predicted == labels).double().mean().item(),
        "top5": (top5 == labels[:, None]).any(dim=1).double().mean().item(),
        "stretch_acc": (stretch_err == 0).double().mean().item(),
        "bend_acc": (bend_err == 0).double().mean().item(),
        "grid_mae": (stretch_err + bend_err).mean().item(),
        "stretch_mae": stretch_err.mean().item(),
        "bend_mae": bend_err.mean().item(),
    }


BREAKDOWNS = {"by_wind_level": "wind_level", "by_clip_index": "clip_index"}
"""Result key -> sample field whose values get metrics of their own: the wind strength, and the
clip's position in its simulation (the arm's first flexion is clip 0; later clips are the next
strokes or the settling cloth)."""


def breakdown_metrics(
    logits: torch.Tensor, labels: torch.Tensor, meta: list[dict], grid: ClassGrid
) -> dict[str, dict[str, dict]]:
    """:func:`classification_metrics` (and ``clips``) per value of each :data:`BREAKDOWNS` field.

    A field enters the result only when the samples take more than one value of it.
    """
    out = {}
    for key, field in BREAKDOWNS.items():
        groups: dict[int, list[int]] = {}
        for i, sample in enumerate(meta):
            groups.setdefault(int(sample[field]), []).append(i)
        if len(groups) > 1:
            out[key] = {
                str(value): {
                    "clips": len(idx),
                    **classification_metrics(logits[idx], labels[idx], grid),
                }
                for value, idx in sorted(groups.items())
            }
    return out
