"""A candidate's strength: the measured peak of its score curve and a bootstrap interval."""

from __future__ import annotations

import dataclasses

import numpy as np

from ..ladder import LadderFeatures
from ..stats import (
    CI_LEVEL,
    Gap,
    bootstrap_draws,
    classifier_divergence,
    weighted_auc,
)
from .scoring import CandidateResult, ReferenceScores, _auc_floor, reference_scores

__all__ = ["fit_strength"]


def _resolved_interval(
    u: np.ndarray, score: np.ndarray, fitted: float, lo: float, hi: float
) -> tuple[float, float]:
    """The bootstrap interval ``(lo, hi)`` of a fit, widened to what the grid ``u`` resolves.

    The grid resolves no finer than half its local spacing: a parabola through three coarse
    points can put its vertex that far off. And where several strengths tie at the best
    score (closures clip at 1, so a plateau is common) the data cannot order them, while the
    fit and every bootstrap peak take the first: the interval spans the plateau, half a
    spacing beyond each end (decision record: docs/design/sim2real-strength-fit.md).
    """
    step = np.diff(u)
    local = step[min(max(int(np.searchsorted(u, fitted)) - 1, 0), len(step) - 1)]
    tied = np.flatnonzero(np.isclose(score, score.max(), rtol=0.0, atol=1e-9))
    first, last = tied[0], tied[-1]
    low = min(fitted - local / 2, (u[first] + u[max(first - 1, 0)]) / 2)
    high = max(fitted + local / 2, (u[last] + u[min(last + 1, len(u) - 1)]) / 2)
    return max(min(lo, low), u[0]), min(max(hi, high), u[-1])


def _peak(u: np.ndarray, score: np.ndarray) -> float:
    """Position of the maximum of a sampled curve.

    The vertex of the parabola through the best sample and its two neighbours (clipped to
    them), or the best sample when it lies at an end.
    """
    i = int(np.argmax(score))
    if i == 0 or i == len(u) - 1:
        return float(u[i])
    a, b, _ = np.polyfit(u[i - 1 : i + 2], score[i - 1 : i + 2], 2)
    if not a < 0:
        return float(u[i])
    return float(np.clip(-b / (2 * a), u[i - 1], u[i + 1]))


def fit_strength(
    result: CandidateResult,
    sets: list[LadderFeatures],
    sim: LadderFeatures,
    real: LadderFeatures,
    gaps: dict[str, Gap],
    rungs: list[str],
    *,
    log_scale: bool,
    n_boot: int,
    rng: np.random.Generator,
    before: ReferenceScores | None = None,
) -> CandidateResult:
    """``result`` with a continuous strength fit and its group-bootstrap interval.

    The fit is the peak of the score curve over the strengths tried (a parabola through the
    best strength and its neighbours, in log strength when ``log_scale``). The interval is
    the central 95 % of that peak over ``n_boot`` replicates that redraw R's videos and the
    candidate's simulations by group (one draw shared by all strengths: they hold the same
    simulations), each replicate re-scoring every strength's classifier AUC from its
    out-of-fold scores (classifiers held fixed) against the rung's fixed floor, widened to at
    least half the grid's local spacing on each side of the fit (the grid's resolution). A
    flat curve gives a wide interval: the data cannot pin the strength down. On a saturated
    rung (``before``, :func:`reference_scores`, computed when not given) the replicates
    re-score the classifier divergence instead of the AUC, as :func:`candidate_result` does.
    Switches, choices and candidates with one strength are returned unchanged.
    """
    strengths = result.strengths
    numeric = all(isinstance(v, int | float) and not isinstance(v, bool) for v in strengths)
    if not numeric or len(strengths) < 2 or not rungs or not result.scores_oof:
        return result
    values = np.asarray(strengths, dtype=np.float64)
    if log_scale and not np.all(values > 0):
        raise ValueError(f"{result.name}: log-scale strengths must be > 0, got {strengths}")
    u = np.log(values) if log_scale else values
    groups_x = np.unique(sets[0].groups)
    shared = all(np.array_equal(np.unique(f.groups), groups_x) for f in sets)
    codes_y = np.unique(real.groups, return_inverse=True)[1].reshape(-1)
    draws_y = bootstrap_draws(int(codes_y.max()) + 1, n_boot, rng)
    draws_x = bootstrap_draws(len(groups_x), n_boot, rng) if shared else None
    before = before if before is not None else reference_scores(sim, real, rungs)
    closed = np.zeros((len(rungs), len(sets), n_boot))
    for r, rung in enumerate(rungs):
        gap = gaps[rung]
        saturated = before.saturated(rung)
        reference, floor, measure = (
            (before.divergence[rung], 0.0, classifier_divergence)
            if saturated
            else (gap.auc, _auc_floor(gap), weighted_auc)
        )
        span = max(reference - floor, 1e-3)
        for i, features in enumerate(sets):
            codes_x = np.unique(features.groups, return_inverse=True)[1].reshape(-1)
            rows_x = (
                draws_x
                if draws_x is not None
                else bootstrap_draws(int(codes_x.max()) + 1, n_boot, rng)
            )[codes_x]
            weights = np.concatenate([rows_x, draws_y[codes_y]]).astype(np.float64)
            labels = np.r_[np.zeros(len(codes_x)), np.ones(len(codes_y))]
            scores = result.scores_oof[rung][i]
            after = np.mean([measure(row, labels, weights) for row in scores], axis=0)
            closed[r, i] = np.clip((reference - after) / span, -1.0, 1.0)
    rung_weights = before.weights(gaps, rungs)  # GAP_WEIGHTED, as the score
    curves = np.tensordot(rung_weights, closed, axes=1)  # (strengths, replicates)
    curves = np.nan_to_num(curves, nan=-1.0)
    peaks = np.array([_peak(u, curves[:, b]) for b in range(n_boot)])
    lo, hi = np.quantile(peaks, [(1 - CI_LEVEL) / 2, (1 + CI_LEVEL) / 2])
    fitted = _peak(u, np.asarray(result.score))
    lo, hi = _resolved_interval(u, np.asarray(result.score), fitted, lo, hi)
    back = np.exp if log_scale else (lambda v: v)
    return dataclasses.replace(
        result,
        fitted=float(f"{float(back(fitted)):.4g}"),
        fit_interval=(float(f"{float(back(lo)):.4g}"), float(f"{float(back(hi)):.4g}")),
    )
