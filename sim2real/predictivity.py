"""Sim-to-real predictivity (Kadian et al. 2020): does the simulator rank models as reality does?

A simulator is useful for model selection when a model that scores better on simulated test
clips also scores better on real footage. Across several checkpoints (the run's own and the
fine-tuned ones after section 3), the sim-vs-real correlation coefficient (SRCC) is the
Spearman correlation between each checkpoint's score on simulated clips and its score on R.
It is measured twice: with the nominal simulator S (before) and with S plus the identified
effect (after); a simulator that now models what the real footage has should predict the
real ranking better.

A checkpoint's score on a clip set is the same on both sides: the Spearman ρ between its
per-group material score (the expected class position, :mod:`models.scores`) and the group's
stiffness (the bending multiplier for simulations, the measured stiffness for real videos).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy import stats

from common.grid import ClassGrid

from .counterfactuals import group_scores
from .domains import ClipSet
from .network import clip_logits

__all__ = ["MIN_CHECKPOINTS", "predictivity", "stiffness_rho"]

MIN_CHECKPOINTS = 3
"""Fewer checkpoints give no SRCC (a rank correlation of two points says nothing)."""


def stiffness_rho(clips: ClipSet, logits: np.ndarray, grid: ClassGrid) -> float:
    """Spearman ρ of the per-group material score with the group's stiffness (0.0 if flat)."""
    per_group = group_scores(clips.groups, logits, clips.stiffness, clips.density, grid)
    score, stiffness = per_group["material_score"], per_group["stiffness"]
    if np.std(score) == 0 or np.std(stiffness) == 0:
        return 0.0
    return float(stats.spearmanr(score, stiffness)[0])


def _srcc(sim: list[float], real: list[float], rounds: int, seed: int) -> dict:
    """SRCC with a bootstrap interval over checkpoints."""
    x, y = np.asarray(sim), np.asarray(real)
    if len(x) < MIN_CHECKPOINTS or np.std(x) == 0 or np.std(y) == 0:
        return {"srcc": None, "ci": None, "checkpoints": len(x)}
    rng = np.random.default_rng(seed)
    draws = []
    for _ in range(rounds):
        pick = rng.integers(len(x), size=len(x))
        if np.std(x[pick]) > 0 and np.std(y[pick]) > 0:
            draws.append(stats.spearmanr(x[pick], y[pick])[0])
    ci = np.percentile(draws, [2.5, 97.5]).tolist() if len(draws) > 1 else None
    return {"srcc": float(stats.spearmanr(x, y)[0]), "ci": ci, "checkpoints": len(x)}


def predictivity(
    checkpoints: list[str | Path],
    sim: ClipSet,
    sim_effect: ClipSet,
    real: ClipSet,
    *,
    device: str = "cpu",
    rounds: int = 1000,
    seed: int = 0,
) -> dict:
    """SRCC before (S) and after (S with the effect) over ``checkpoints``.

    Args:
        checkpoints: Classifier checkpoints (``train.py`` runs), at least
            :data:`MIN_CHECKPOINTS` for an SRCC.
        sim: Nominal simulated clips S (groups = simulations, stiffness = bend multiplier).
        sim_effect: The same simulations with the identified effect.
        real: The real clips R (groups = videos, measured stiffness).
        device: Where the networks run.
        rounds: Bootstrap resamples of the checkpoints for the intervals.
        seed: Bootstrap seed.

    Returns:
        ``{"rows": [per checkpoint: sim, sim_effect, real], "before": {...}, "after": {...}}``.
    """
    from models.evaluate import module_grid
    from models.material_classifier import load_classifier

    rows = []
    for checkpoint in checkpoints:
        module = load_classifier(checkpoint)
        net, grid = module.net, module_grid(module)
        rows.append(
            {
                "checkpoint": str(checkpoint),
                "sim": stiffness_rho(sim, clip_logits(net, sim.frames, device=device), grid),
                "sim_effect": stiffness_rho(
                    sim_effect, clip_logits(net, sim_effect.frames, device=device), grid
                ),
                "real": stiffness_rho(real, clip_logits(net, real.frames, device=device), grid),
            }
        )
    real_scores = [r["real"] for r in rows]
    return {
        "rows": rows,
        "before": _srcc([r["sim"] for r in rows], real_scores, rounds, seed),
        "after": _srcc([r["sim_effect"] for r in rows], real_scores, rounds, seed),
    }
