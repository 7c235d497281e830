"""Scalar material scores derived from class probabilities, for correlation with measurements.

The classes of a material set are ``class_id = stretch_index * bend_count + bend_index`` with
both multiplier lists increasing (the data's :class:`~common.grid.ClassGrid`), so the class
id *is* a position in a stiffness ordering: stretch-major, then bend. Thesis 7.7.2.2 correlates
the predicted class number (0..53 of its 6 x 9 grid, "the higher the number generally means the
cloth is stiffer") with both the measured stiffness and the measured density of real fabrics;
our definitions:

* ``material_score`` = expected class position under the predicted distribution,
  ``sum_c p_c * c`` in [0, classes - 1] (the argmax class id is also kept as
  ``predicted_class``; the expectation is the smooth version that Pearson r can use well);
* ``stretch_score`` = expected stretch index in [0, stretch_count - 1]; ``bend_score`` =
  expected bend index in [0, bend_count - 1] (bend is what Bouman et al.'s "stiffness"
  measures most directly);
* ``density_score`` = expected density index in [0, density_count - 1], for a grid of several
  densities only.

The thesis's set has one areal density (its basis fabric's; camel-ponte-roma's 0.284 kg/m²),
so there is no density class: as in the thesis, density is correlated with
``material_score``. A set with ``density_multipliers`` makes density a class axis of its own,
and then ``density_score`` is the score to hold against measured density. A video's scores are
its clips' probabilities averaged first, then scored.
"""

from __future__ import annotations

import torch

from common.grid import ClassGrid

from .metrics import grid_position

__all__ = [
    "CORRELATED_SCORES",
    "SCORE_NAMES",
    "correlated_scores",
    "material_scores",
]

SCORE_NAMES = ("material_score", "stretch_score", "bend_score", "predicted_class", "density_score")
CORRELATED_SCORES = ("material_score", "stretch_score", "bend_score")
"""Scores correlated with each measured column of a real set whose grid has one density.
``predicted_class`` (the argmax) is a coarse copy of ``material_score`` and is left out; there
is no density score then, so density is correlated with each of these, as in the thesis."""


def correlated_scores(grid: ClassGrid) -> tuple[str, ...]:
    """The scores to correlate for ``grid``.

    :data:`CORRELATED_SCORES`, and ``density_score`` when the grid has several densities.
    """
    return (*CORRELATED_SCORES, "density_score") if grid.density_count > 1 else CORRELATED_SCORES


def material_scores(probs: torch.Tensor, grid: ClassGrid) -> dict[str, torch.Tensor]:
    """Scores of class probabilities ``(N, classes)`` -> dict of ``(N,)`` tensors (module doc)."""
    count = grid.num_classes
    if probs.ndim != 2 or probs.shape[1] != count:
        raise ValueError(f"probs must have shape (N, {count}), got {tuple(probs.shape)}")
    classes = torch.arange(count, device=probs.device)
    stretch, bend, density = grid_position(classes, grid)
    out = {
        "material_score": probs @ classes.to(probs.dtype),
        "stretch_score": probs @ stretch.to(probs.dtype),
        "bend_score": probs @ bend.to(probs.dtype),
        "predicted_class": probs.argmax(dim=1).to(probs.dtype),
    }
    if grid.density_count > 1:
        out["density_score"] = probs @ density.to(probs.dtype)
    return out
