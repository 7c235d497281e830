"""How much of the gap a candidate set closes: floor-corrected classifier and kernel closures."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..ladder import LadderFeatures
from ..stats import (
    Gap,
    auc_above_floor,
    auc_score,
    classifier_divergence,
    domain_scores,
    gap_closed,
    mmd2_unbiased,
    standardize,
)
from .localise import scored_rungs

__all__ = [
    "AUC_REPEATS",
    "CONFUSABLE_WITHIN",
    "GAP_WEIGHTED",
    "SATURATED_AUC",
    "CandidateResult",
    "ReferenceScores",
    "candidate_result",
    "oof_auc",
    "oof_divergence",
    "reference_scores",
    "score_reference",
]


GAP_WEIGHTED = (
    "a candidate's score is its classifier closure on each scored rung, weighted by the "
    "classifier gap that rung carries (S vs R's AUC above its floor)"
)
"""How :func:`candidate_result` combines the scored rungs (:meth:`ReferenceScores.weights`):
the score is the share of the whole classifier gap closed, so a rung that barely shows the
gap counts little (docs/design/sim2real-closure-score.md)."""


CONFUSABLE_WITHIN = 0.1
"""Candidates whose scores lie within this of the best are reported as confusable with it."""


def _scaled(ref: np.ndarray, *arrays: np.ndarray) -> list[np.ndarray]:
    """``arrays`` standardized with ``ref``'s statistics (the same scaling as ``compare``)."""
    return [standardize(ref, a)[1] for a in arrays]


def score_reference(
    location: dict, gaps: dict[str, Gap], sim: LadderFeatures, real: LadderFeatures
) -> tuple[list[str], ReferenceScores]:
    """The scored rungs and S's domain classifier on them (:func:`reference_scores`).

    The pooled test (S and S' against R) finds where the gap lies, but candidates are scored
    against S alone, whose classifier can sit at its within-domain floor on a rung where
    the pooled test sees a weak gap. There every candidate closes 0 of nothing
    (:func:`sim2real.stats.gap_closed`): the rung carries no information and only dilutes the
    score, and when every scored rung is such a rung nothing can explain the gap. Such rungs
    are passed over: pixel or motion is dropped, and the network layer becomes the first
    significant one where S's classifier is above its floor (or saturated) (decision record:
    docs/design/sim2real-closure-score.md).
    """
    significant = list(location["significant"])
    before = reference_scores(sim, real, significant)

    def scoreable(rung: str) -> bool:
        return before.saturated(rung) or before.auc[rung] > _auc_floor(gaps[rung])

    rungs = scored_rungs(location, scoreable)  # significant rungs only, so measured above
    return rungs, ReferenceScores(
        auc={r: before.auc[r] for r in rungs},
        divergence={r: before.divergence[r] for r in rungs},
    )


def _distance(sim: LadderFeatures, a: LadderFeatures, real: LadderFeatures, rung: str, bw: float):
    """MMD² of set ``a`` to R on ``rung`` with the scaling and kernel of :func:`rung_gaps`."""
    pooled = np.concatenate([sim.rungs[rung], real.rungs[rung]])
    xa, xb = _scaled(pooled, a.rungs[rung], real.rungs[rung])
    return mmd2_unbiased(xa, xb, bw)


@dataclasses.dataclass(frozen=True)
class CandidateResult:
    """One candidate's fit: per strength, the MMD² to R and the closure per rung."""

    name: str
    stage: str
    strengths: tuple
    mmd2: dict[str, list[float]]
    """Rung -> MMD²(S_e, R) per strength."""
    closure: dict[str, list[float]]
    """Rung -> fraction of the floor-corrected gap closed, per strength."""
    score: list[float]
    """Classifier closure (:attr:`closure_auc`) over the scored rungs, per strength: their
    mean weighted by the classifier gap each carries (:data:`GAP_WEIGHTED`)."""
    closure_auc: dict[str, list[float]] = dataclasses.field(default_factory=dict)
    """Scored rung -> fraction of the floor-corrected domain-classifier AUC closed, per
    strength: (AUC(S, R) - AUC(S_e, R)) / (AUC(S, R) - floor AUC); on a saturated rung
    (:data:`SATURATED_AUC`) the classifier divergence's (floor 0) instead."""
    fitted: float | None = None
    """Continuous strength fit (:func:`fit_strength`); ``None``: not fitted (switch, choice)."""
    fit_interval: tuple[float, float] | None = None
    """95 % group-bootstrap interval of :attr:`fitted`."""
    neutral: float | None = None
    """The strength at which the candidate changes nothing, when it lies inside or at the
    edge of its range (:attr:`sim2real.candidates.Candidate.neutral`); else ``None``."""
    scores_oof: dict = dataclasses.field(default=None, repr=False, compare=False)
    """Rung -> per strength the classifier's out-of-fold scores (repeats, n + m), kept for
    :func:`fit_strength`'s bootstrap; not part of the JSON."""

    @property
    def best(self) -> int:
        """Index of the fitted strength."""
        return int(np.argmax(self.score)) if self.score else 0

    @property
    def best_score(self) -> float:
        """Score at the fitted strength."""
        return self.score[self.best] if self.score else 0.0

    @property
    def best_strength(self):
        """The fitted strength (``None`` for a switch)."""
        return self.strengths[self.best]

    @property
    def interval(self) -> tuple:
        """(lowest, highest) strength the data cannot tell from the best.

        The group-bootstrap interval of the continuous fit when :func:`fit_strength` ran;
        else the grid strengths scoring within :data:`CONFUSABLE_WITHIN` of the best;
        ``(None, None)`` for switches and choices.
        """
        if self.fit_interval is not None:
            return tuple(self.fit_interval)
        values = [
            s
            for s, v in zip(self.strengths, self.score, strict=True)
            if isinstance(s, int | float) and v >= self.best_score - CONFUSABLE_WITHIN
        ]
        return (min(values), max(values)) if values else (None, None)

    @property
    def holds_neutral(self) -> bool:
        """Whether :attr:`interval` holds :attr:`neutral` (:data:`NEUTRAL_RULE`).

        The data then cannot tell the candidate from its absence.
        """
        low, high = self.interval
        return self.neutral is not None and low is not None and low <= self.neutral <= high

    @property
    def fitted_strength(self):
        """The continuous fit when there is one, else the best grid strength."""
        return self.best_strength if self.fitted is None else self.fitted

    def to_json(self) -> dict:
        """Plain JSON."""
        out = {
            f.name: getattr(self, f.name)
            for f in dataclasses.fields(self)
            if f.name != "scores_oof"
        }
        out.update(
            best_strength=self.best_strength,
            best_score=self.best_score,
            fitted_strength=self.fitted_strength,
            strength_interval=list(self.interval),
        )
        return out

    @classmethod
    def from_json(cls, data: dict) -> CandidateResult:
        """The result :meth:`to_json` wrote (without the out-of-fold scores).

        A stored report writes NaN as ``null``; it is read back as NaN.
        """

        def numbers(values: list) -> list[float]:
            return [math.nan if v is None else v for v in values]

        def per_rung(values: dict) -> dict[str, list[float]]:
            return {rung: numbers(v) for rung, v in values.items()}

        interval = data.get("fit_interval")
        return cls(
            name=data["name"],
            stage=data["stage"],
            strengths=tuple(data["strengths"]),
            mmd2=per_rung(data["mmd2"]),
            closure=per_rung(data["closure"]),
            score=numbers(data["score"]),
            closure_auc=per_rung(data.get("closure_auc", {})),
            fitted=data.get("fitted"),
            fit_interval=None if interval is None else tuple(interval),
            neutral=data.get("neutral"),
        )


AUC_REPEATS = 2
"""Grouped-CV repetitions (other fold draws) averaged in a candidate's classifier closure."""


def _oof(sim: LadderFeatures, features: LadderFeatures, real: LadderFeatures, rung: str):
    """Out-of-fold domain scores of ``features`` vs R on ``rung``, shape (AUC_REPEATS, n + m).

    Scaled like every comparison of the rung (S and R pooled); fold draws are fixed per
    repetition, so R's folds are the same for every candidate set.
    """
    pooled = np.concatenate([sim.rungs[rung], real.rungs[rung]])
    xs, ys = _scaled(pooled, features.rungs[rung], real.rungs[rung])
    return np.stack(
        [
            domain_scores(xs, ys, features.groups, real.groups, rng=np.random.default_rng([r, 17]))
            for r in range(AUC_REPEATS)
        ]
    )


def _labels(scores: np.ndarray, n: int) -> np.ndarray:
    return np.r_[np.zeros(n), np.ones(scores.shape[1] - n)]


def oof_auc(scores: np.ndarray, n: int) -> float:
    """The domain classifier's AUC over its CV repeats' out-of-fold scores (first n: S)."""
    labels = _labels(scores, n)
    return float(np.mean([auc_score(row, labels) for row in scores]))


def oof_divergence(scores: np.ndarray, n: int, weights: np.ndarray | None = None):
    """The classifier divergence over the CV repeats' out-of-fold scores (first n: S).

    With row weights (n + m, B): one value per bootstrap replicate, shape (B,).
    """
    labels = _labels(scores, n)
    if weights is None:
        return float(np.mean([classifier_divergence(row, labels) for row in scores]))
    return np.mean([classifier_divergence(row, labels, weights) for row in scores], axis=0)


SATURATED_AUC = 0.99
"""A scored rung whose AUC(S, R) reaches this is scored by the classifier divergence instead.

With two strong effects in R, S is told apart from R perfectly, and so is S plus either
effect alone, so every AUC closure is 0; the divergence
(:func:`sim2real.stats.classifier_divergence`) still falls when one of the two effects is
added (decision record: docs/design/sim2real-saturated-rungs.md)."""


@dataclasses.dataclass(frozen=True)
class ReferenceScores:
    """The domain classifier on S vs R per scored rung, measured as every candidate's."""

    auc: dict[str, float]
    divergence: dict[str, float]
    """Classifier divergence [nats]: mean held-out logit of R minus that of S."""

    def saturated(self, rung: str) -> bool:
        """Whether ``rung`` is scored by the divergence (:data:`SATURATED_AUC`)."""
        return self.auc[rung] >= SATURATED_AUC

    def closure(self, rung: str, scores: np.ndarray, n: int, gap: Gap) -> float:
        """Fraction of the classifier gap that a candidate with out-of-fold ``scores`` closes.

        The AUC above its within-domain floor; on a saturated rung the divergence above 0,
        the value of sets the classifier cannot tell apart.
        """
        if self.saturated(rung):
            return gap_closed(self.divergence[rung], oof_divergence(scores, n), 0.0)
        return gap_closed(self.auc[rung], oof_auc(scores, n), _auc_floor(gap))

    def weight(self, rung: str, gap: Gap) -> float:
        """How much classifier gap ``rung`` carries (:data:`GAP_WEIGHTED`).

        S vs R's AUC above its within-domain floor, as a share of what lies above the floor
        (1: fully separable, also on a saturated rung): the span a candidate's closure on
        the rung is a fraction of.
        """
        return auc_above_floor(self.auc[rung], _auc_floor(gap))

    def weights(self, gaps: dict[str, Gap], rungs: list[str]) -> np.ndarray:
        """:meth:`weight` of each of ``rungs``, summing to 1 (equal when no rung has a gap)."""
        values = np.array([self.weight(r, gaps[r]) for r in rungs], dtype=np.float64)
        total = values.sum()
        return values / total if total > 1e-9 else np.full(len(rungs), 1.0 / max(1, len(rungs)))

    def to_json(self) -> dict:
        """Plain JSON."""
        return {
            "auc": self.auc,
            "divergence": self.divergence,
            "saturated": [r for r in self.auc if self.saturated(r)],
        }


def reference_scores(
    sim: LadderFeatures, real: LadderFeatures, rungs: list[str]
) -> ReferenceScores:
    """AUC and divergence of S vs R per scored rung, measured as every candidate's (``_oof``)."""
    oof = {r: _oof(sim, sim, real, r) for r in rungs}
    return ReferenceScores(
        auc={r: oof_auc(scores, len(sim)) for r, scores in oof.items()},
        divergence={r: oof_divergence(scores, len(sim)) for r, scores in oof.items()},
    )


def candidate_result(
    name: str,
    stage: str,
    strengths: tuple,
    sets: list[LadderFeatures],
    sim: LadderFeatures,
    real: LadderFeatures,
    gaps: dict[str, Gap],
    rungs: list[str],
    before: ReferenceScores | None = None,
    *,
    neutral: float | None = None,
) -> CandidateResult:
    """Score the candidate's sets (one per strength) against R.

    On every rung the MMD² to R and its closure; on the scored ``rungs`` the classifier
    closure, which makes the score. The kernel statistic spreads its power over every
    feature, while a domain classifier finds the few directions an effect moves, so it
    tells candidates apart where the MMD² barely sees the gap; a candidate that adds a
    difference R does not have is caught by it too. ``before``: :func:`reference_scores`
    (computed here when not given); on saturated rungs the classifier closure is that of
    the divergence (:data:`SATURATED_AUC`). ``neutral``: the candidate's neutral strength
    (:attr:`CandidateResult.neutral`).
    """
    before = before if before is not None else reference_scores(sim, real, rungs)
    mmd2 = {r: [] for r in gaps}
    closure = {r: [] for r in gaps}
    closure_auc = {r: [] for r in rungs}
    oof = {r: [] for r in rungs}
    for features in sets:
        for rung, gap in gaps.items():
            after = _distance(sim, features, real, rung, gap.bandwidth)
            mmd2[rung].append(after)
            closure[rung].append(gap_closed(gap.mmd2, after, _mmd2_floor(gap)))
        for rung in rungs:
            scores = _oof(sim, features, real, rung)
            oof[rung].append(scores)
            closure_auc[rung].append(before.closure(rung, scores, len(features), gaps[rung]))
    weights = before.weights(gaps, rungs)
    score = [
        float(np.dot(weights, [closure_auc[r][i] for r in rungs])) if rungs else 0.0
        for i in range(len(sets))
    ]
    return CandidateResult(
        name,
        stage,
        tuple(strengths),
        mmd2,
        closure,
        score,
        closure_auc=closure_auc,
        neutral=neutral,
        scores_oof=oof,
    )


def _mmd2_floor(gap: Gap) -> float:
    return gap.floor_mmd2 if math.isfinite(gap.floor_mmd2) else 0.0


def _auc_floor(gap: Gap) -> float:
    return gap.floor_auc if math.isfinite(gap.floor_auc) else 0.5
