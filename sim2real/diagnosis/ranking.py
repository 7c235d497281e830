"""The rules that name a cause: open-set threshold, kernel check, neutral rule, ties."""

from __future__ import annotations

import dataclasses
import math
from typing import Any, ClassVar

import numpy as np

from ..candidates import STAGES
from ..section import Section, fields_of
from ..stats import Gap
from .scoring import CONFUSABLE_WITHIN, CandidateResult, _mmd2_floor

__all__ = [
    "KERNEL_MIN_CLOSURE",
    "NEUTRAL_RULE",
    "OPEN_SET_MARGIN",
    "OPEN_SET_MIN_CLOSURE",
    "SATURATED_TIE",
    "Ranking",
    "agrees",
    "explains_together",
    "kernel_closure",
    "kernel_rungs",
    "kernel_strengths",
    "rank_candidates",
]


OPEN_SET_MIN_CLOSURE = 0.6
"""A candidate must close at least this share of the floor-corrected classifier gap, and beat
a fresh nominal draw S' by :data:`OPEN_SET_MARGIN`, to be named the cause; else the answer is
"unexplained residual" (docs/design/sim2real-open-set.md)."""


OPEN_SET_MARGIN = 0.15


KERNEL_MIN_CLOSURE = OPEN_SET_MIN_CLOSURE
"""A named cause must also close this share of the kernel distance (:func:`kernel_closure`),
at a strength inside its interval (:func:`kernel_strengths`): a look-alike moves the few
directions the classifier sees but not the whole distribution. Where no scored rung's kernel
distance lies above its floor, the gap is too weak to attribute and nothing is named
(docs/design/sim2real-kernel-check.md)."""


NEUTRAL_RULE = (
    "a candidate whose strength interval holds its neutral value is not named: the data "
    "cannot tell it from its absence"
)
"""Why a top candidate may close the gap and still not be named (:attr:`CandidateResult.
holds_neutral`): an interval that holds "no change" cannot tell the effect from its absence
(docs/design/sim2real-neutral-rule.md)."""


SATURATED_TIE = (
    "candidates with equal classifier closures are ordered first by whether they can be told "
    "from their absence (NEUTRAL_RULE), then by their kernel distance to R (mean MMD² over "
    "the scored rungs at the best strength, nearest first)"
)
"""How :func:`rank_candidates` orders a tie of clipped classifier closures: the kernel
distance is the second, independent statistic of every comparison
(docs/design/sim2real-ties.md)."""


def kernel_rungs(gaps: dict[str, Gap], rungs: list[str]) -> list[str]:
    """The scored ``rungs`` where S vs R's MMD² lies above its floor (a closure is defined)."""
    return [r for r in rungs if gaps[r].mmd2 > _mmd2_floor(gaps[r])]


def kernel_closure(
    result: CandidateResult, rungs: list[str], *, threshold: float | None = None
) -> float | None:
    """Mean MMD² closure of ``result`` over ``rungs`` (:func:`kernel_rungs`).

    At its best strength; with ``threshold``, the largest at any of
    :func:`kernel_strengths` (the strengths the classifier cannot tell from the best that
    close ``threshold`` of its gap). ``None`` when there is no such rung: the kernel
    distance then cannot confirm or refute.
    """
    return _kernel_confirmation(result, rungs, threshold)[0]


def _kernel_confirmation(result: CandidateResult, rungs: list[str], threshold: float | None):
    """(:func:`kernel_closure`, the index of the strength it is measured at)."""
    if not rungs:
        return None, result.best
    indices = [result.best] if threshold is None else kernel_strengths(result, threshold)
    at = {i: float(np.mean([result.closure[r][i] for r in rungs])) for i in indices}
    i = max(indices, key=lambda i: (at[i], result.score[i]))  # ties: the better classifier fit
    return at[i], i


def kernel_strengths(result: CandidateResult, threshold: float) -> list[int]:
    """Indices of the grid strengths at which the kernel check may confirm ``result``.

    The best one, and every other inside :attr:`CandidateResult.interval` (the data's
    classifier closures cannot tell it from the best) whose classifier closure reaches
    ``threshold``: a cause must close most of the gap by both statistics at one strength,
    not necessarily at the one where the classifier's noise put its maximum.
    """
    low, high = result.interval
    inside = [
        i
        for i, (s, v) in enumerate(zip(result.strengths, result.score, strict=True))
        if low is not None and isinstance(s, int | float) and low <= s <= high and v >= threshold
    ]
    return sorted({result.best, *inside})


def agrees(kernel: float | None) -> bool:
    """Whether a kernel closure (:func:`kernel_closure`) confirms a cause.

    ``None`` (no scored rung's kernel distance above its floor) does not: a gap only the
    classifier sees is one noisy statistic, and effect-free twins showed that any candidate
    that widens S can close it.
    """
    return kernel is not None and kernel >= KERNEL_MIN_CLOSURE


def explains_together(
    score: float, kernel: float | None, threshold: float, without: list[float]
) -> bool:
    """Whether candidates measured together (a coalition, a stacked pair) explain the gap.

    Their closure ``score`` clears the open-set ``threshold`` by :data:`OPEN_SET_MARGIN`
    (their strengths are all fitted, so they close more by chance than one candidate), the
    kernel closure agrees (:func:`agrees`), and every member adds: the group closes more
    than each of ``without``, the closures of the group without one member.
    """
    return (
        score >= threshold + OPEN_SET_MARGIN
        and agrees(kernel)
        and all(score > other for other in without)
    )


_EXPLAINED_BY = ("explained_by", "explained_by_score", "explained_by_kernel_closure")


@dataclasses.dataclass(frozen=True)
class Ranking(Section):
    """The candidates in order and whether the top one is named the cause.

    Made by :func:`sim2real.diagnosis.rank_candidates`; a coalition or a stacked pair that
    explains the gap with the top candidate sets ``explained_by``.
    """

    ranking: list[str]
    """Candidate names, best first."""
    threshold: float
    """The least classifier closure that names a cause: max(0.6, S' + 0.15)."""
    null_score: float
    """The closure of a fresh nominal draw S' (chance)."""
    explained: bool
    """Whether a cause is named (the top candidate, or ``explained_by``)."""
    top: str | None
    """The best candidate."""
    kernel_rungs: list[str]
    """The scored rungs with a kernel gap: where the kernel check measures."""
    kernel_closure: float | None
    """The top candidate's kernel closure at the strength that confirms it."""
    kernel_strength: Any
    """That strength."""
    kernel_threshold: float
    """The least kernel closure that confirms a cause."""
    look_alike: bool
    """The top candidate closes the classifier gap but not the kernel distance (or, with no
    :attr:`kernel_rungs`, the kernel distance does not see the gap)."""
    neutral_in_interval: bool
    """The top candidate's interval holds its neutral strength (not named)."""
    confusable_with_top: list[str]
    """Candidates within 0.1 of the top."""
    stage_scores: dict[str, float | None]
    """The best closure of each stage's candidates."""
    explained_by: list[str] | None = None
    """The candidates that explain the gap together (a coalition or a stacked pair)."""
    explained_by_score: float | None = None
    """Their joint closure."""
    explained_by_kernel_closure: float | None = None
    """Their joint kernel closure."""
    replayed: bool | None = None
    """Set by a rescoring: whether every step could be decided again from stored closures."""
    extra: dict = dataclasses.field(default_factory=dict)
    section: ClassVar[str] = "ranking"

    def to_json(self) -> dict:
        """The ``ranking`` section of a report (optional keys only where set)."""
        out = {**self.extra}
        for name in fields_of(type(self)):
            value = getattr(self, name)
            if name in _EXPLAINED_BY and self.explained_by is None:
                continue
            if name == "replayed" and value is None:
                continue
            out[name] = value
        return out


def rank_candidates(
    results: list[CandidateResult],
    null: CandidateResult | None,
    on: list[str],
    *,
    min_closure: float = OPEN_SET_MIN_CLOSURE,
) -> Ranking:
    """Ranking, open-set decision, stage verdict and confusable pairs.

    The top candidate is named the cause (``explained``) when its classifier closure reaches
    the threshold (``min_closure``, or the null draw's closure plus
    :data:`OPEN_SET_MARGIN` when higher) and its kernel closure over ``on`` (the scored
    rungs with a kernel gap, :func:`kernel_rungs`) confirms it (:data:`KERNEL_MIN_CLOSURE`);
    one that passes the first test and fails the second is reported as a ``look_alike``.
    A top candidate whose strength interval holds its neutral value is never named
    (``neutral_in_interval``, :data:`NEUTRAL_RULE`).
    """
    ranked = sorted(
        results,
        key=lambda r: (r.best_score, not r.holds_neutral, -_distance_at_best(r)),
        reverse=True,
    )
    null_score = null.best_score if null is not None else 0.0
    threshold = max(min_closure, null_score + OPEN_SET_MARGIN)
    top = ranked[0] if ranked else None
    kernel, kernel_at = (None, None) if top is None else _kernel_confirmation(top, on, threshold)
    closes = top is not None and top.best_score >= threshold
    indistinct = top is not None and top.holds_neutral
    confusable = [
        r.name
        for r in ranked[1:]
        if top is not None and r.best_score >= top.best_score - CONFUSABLE_WITHIN
    ]
    stages = {}
    for stage in STAGES:
        inside = [r for r in ranked if r.stage == stage]
        stages[stage] = max((r.best_score for r in inside), default=None)
    return Ranking(
        ranking=[r.name for r in ranked],
        threshold=threshold,
        null_score=null_score,
        explained=closes and agrees(kernel) and not indistinct,
        top=None if top is None else top.name,
        kernel_rungs=on,
        kernel_closure=kernel,
        kernel_strength=None if top is None else top.strengths[kernel_at],
        kernel_threshold=KERNEL_MIN_CLOSURE,
        look_alike=closes and not agrees(kernel),
        neutral_in_interval=indistinct,
        confusable_with_top=confusable,
        stage_scores=stages,
    )


def _distance_at_best(result: CandidateResult) -> float:
    """Mean MMD² to R over the scored rungs at the best strength (:data:`SATURATED_TIE`)."""
    values = [result.mmd2[r][result.best] for r in result.closure_auc if r in result.mmd2]
    values = [v for v in values if math.isfinite(v)]
    return float(np.mean(values)) if values else math.inf
