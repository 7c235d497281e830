"""Classification metrics over the stretch x bend (x density) class grid (thesis Table 7.2).

Pure torch functions of logits ``(N, classes)`` and labels ``(N,)``; the Lightning module and
the evaluation entry both use them, so training logs and reports agree. The grid is a
:class:`~common.grid.ClassGrid` of plain numbers that comes with the data (a dataset
manifest's material set, the datamodule's ``class_grid``) or with a checkpoint's
hyper-parameters; nothing here knows the simulator's 6 x 9 grid of 54 classes.
"""

from __future__ import annotations

import torch

from common.grid import ClassGrid

__all__ = [
    "BREAKDOWNS",
    "breakdown_metrics",
    "classification_metrics",
    "confusion_matrix",
    "grid_position",
]


def grid_position(
    classes: torch.Tensor, grid: ClassGrid
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Class ids -> (stretch index, bend index, density index) in ``grid``."""
    cells = torch.div(classes, grid.density_count, rounding_mode="floor")
    return (
        torch.div(cells, grid.bend_count, rounding_mode="floor"),
        torch.remainder(cells, grid.bend_count),
        torch.remainder(classes, grid.density_count),
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
    grid (|d stretch index| + |d bend index| + |d density index|); ``stretch_mae`` and
    ``bend_mae`` are its parts, and a grid of several densities adds ``density_acc`` and
    ``density_mae``. Accuracies are fractions in [0, 1].
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
    true = grid_position(labels, grid)
    pred = grid_position(predicted, grid)
    errors = [(t - p).abs().double() for t, p in zip(true, pred, strict=True)]
    stretch_err, bend_err, density_err = errors
    out = {
        "acc": (predicted == labels).double().mean().item(),
        "top5": (top5 == labels[:, None]).any(dim=1).double().mean().item(),
        "stretch_acc": (stretch_err == 0).double().mean().item(),
        "bend_acc": (bend_err == 0).double().mean().item(),
        "grid_mae": (stretch_err + bend_err + density_err).mean().item(),
        "stretch_mae": stretch_err.mean().item(),
        "bend_mae": bend_err.mean().item(),
    }
    if grid.density_count > 1:
        out["density_acc"] = (density_err == 0).double().mean().item()
        out["density_mae"] = density_err.mean().item()
    return out


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
