"""Scalar material scores derived from class probabilities, for correlation with measurements.

The 54 classes are ``class_id = stretch_index * 9 + bend_index`` with both multiplier lists
increasing (``simulator.cloth.material``), so the class id *is* a position in a stiffness
ordering: stretch-major, then bend. Thesis 7.7.2.2 correlates the predicted class number
(0..53, "the higher the number generally means the cloth is stiffer") with both the measured
stiffness and the measured density of real fabrics; our definitions:

* ``material_score`` = expected class position under the predicted distribution,
  ``sum_c p_c * c`` in [0, 53] (the argmax class id is also kept as ``predicted_class``;
  the expectation is the smooth version that Pearson r can use well);
* ``stretch_score`` = expected stretch index in [0, 5]; ``bend_score`` = expected bend
  index in [0, 8] (bend is what Bouman et al.'s "stiffness" measures most directly).

The subspace has one areal density (camel-ponte-roma's 0.284 kg/m²), so there is no density
class: as in the thesis, density is correlated with ``material_score``. A video's scores are
its clips' probabilities averaged first, then scored.
"""

from __future__ import annotations

import torch

from simulator.cloth.material import CLASS_COUNT

from .metrics import grid_position

__all__ = ["CORRELATED_SCORES", "SCORE_NAMES", "material_scores"]

SCORE_NAMES = ("material_score", "stretch_score", "bend_score", "predicted_class")
CORRELATED_SCORES = ("material_score", "stretch_score", "bend_score")
"""Scores correlated with each measured column of a real set. ``predicted_class`` (the argmax)
is a coarse copy of ``material_score`` and is left out; there is no density score (one
density in the subspace), so density is correlated with each of these, as in the thesis."""


def material_scores(probs: torch.Tensor) -> dict[str, torch.Tensor]:
    """Scores of class probabilities ``(N, 54)`` -> dict of ``(N,)`` tensors (see module doc)."""
    if probs.ndim != 2 or probs.shape[1] != CLASS_COUNT:
        raise ValueError(f"probs must have shape (N, {CLASS_COUNT}), got {tuple(probs.shape)}")
    classes = torch.arange(CLASS_COUNT, device=probs.device)
    stretch, bend = grid_position(classes)
    return {
        "material_score": probs @ classes.to(probs.dtype),
        "stretch_score": probs @ stretch.to(probs.dtype),
        "bend_score": probs @ bend.to(probs.dtype),
        "predicted_class": probs.argmax(dim=1).to(probs.dtype),
    }
