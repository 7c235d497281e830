"""The diagnosis itself: where the sim-to-real gap lies and which candidate effect closes it.

Given the real clips R, the trained run (its network and the spec of its training data) and
a candidate library, :func:`diagnose`:

1. builds the nominal simulated set S (the training data's settings on fresh simulations)
   and a second nominal draw S' (the chance level of every "closure"), cuts all of them into
   clips the same way, and measures every rung of the ladder (:mod:`sim2real.ladder`);
2. per rung, compares S with R (:func:`sim2real.stats.compare`: MMD², KID, domain AUC, group
   permutation p-value, bootstrap intervals, within-domain noise floor) and localises the gap
   (significant rungs; the first network layer where the floor-corrected AUC jumps);
3. per candidate and strength, builds S_e (visual effects re-render S's meshes, physical and
   scene ones re-simulate), measures its MMD² to R on each rung with S's scaling and kernel,
   and scores the fraction of the floor-corrected gap it closes on the scored rungs; the best
   strength is the fit; candidates are ranked, confusable ones listed, and the open-set
   answer is given when no candidate beats the threshold;
4. per rung, a linear probe trained on S (class position) is tested on R against measured
   stiffness and density: a gap on a rung whose probe still transfers is harmless.
"""

from __future__ import annotations

import dataclasses
import itertools
import logging
import math
from collections.abc import Callable, Sequence

import numpy as np
from scipy import stats as sstats

from .candidates import STAGES
from .ladder import LadderFeatures
from .stats import (
    CI_LEVEL,
    Gap,
    auc_above_floor,
    auc_score,
    bootstrap_draws,
    classifier_divergence,
    compare,
    domain_scores,
    gap_closed,
    median_bandwidth,
    mmd2_unbiased,
    standardize,
    weighted_auc,
)

__all__ = [
    "KERNEL_MIN_CLOSURE",
    "NEUTRAL_RULE",
    "OPEN_SET_MARGIN",
    "OPEN_SET_MIN_CLOSURE",
    "RESIDUAL_MOTION_SHARE",
    "RESIDUAL_STAGE_MIN_CLOSURE",
    "SATURATED_AUC",
    "CandidateResult",
    "ReferenceScores",
    "agrees",
    "best_subset_values",
    "candidate_result",
    "explains_together",
    "fit_strength",
    "harmonic_mean_p",
    "kernel_closure",
    "kernel_rungs",
    "kernel_strengths",
    "localise",
    "probe_transfer",
    "rank_candidates",
    "reference_scores",
    "rung_gaps",
    "score_reference",
    "scored_rungs",
    "shapley_values",
    "stage_of_residual",
]

log = logging.getLogger(__name__)

PIXEL_RUNGS = ("pixel", "motion")

OPEN_SET_MIN_CLOSURE = 0.6
"""A candidate must close at least this share of the floor-corrected classifier gap, and beat
a fresh nominal draw S' by :data:`OPEN_SET_MARGIN`, to be named the cause; else the answer is
"unexplained residual" (docs/design/sim2real-open-set.md)."""

OPEN_SET_MARGIN = 0.15

KERNEL_MIN_CLOSURE = OPEN_SET_MIN_CLOSURE
"""A named cause must also close this share of the kernel distance (:func:`kernel_closure`),
at a strength inside its interval (:func:`kernel_strengths`): a look-alike moves the few
directions the classifier sees but not the whole distribution
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

GAP_WEIGHTED = (
    "a candidate's score is its classifier closure on each scored rung, weighted by the "
    "classifier gap that rung carries (S vs R's AUC above its floor)"
)
"""How :func:`candidate_result` combines the scored rungs (:meth:`ReferenceScores.weights`):
the score is the share of the whole classifier gap closed, so a rung that barely shows the
gap counts little (docs/design/sim2real-closure-score.md)."""

CONFUSABLE_WITHIN = 0.1
"""Candidates whose scores lie within this of the best are reported as confusable with it."""

RESIDUAL_STAGE_MIN_CLOSURE = 0.10
"""Least share of the gap that a stage's best candidate must close for that stage to place an
unexplained residual (:func:`stage_of_residual`); below it the rung pattern decides. A fresh
nominal draw closes 10 % or more in about one set of twenty
(docs/design/sim2real-residual-stage.md)."""

RESIDUAL_MOTION_SHARE = 0.5
"""Where no candidate moves S toward R and both the pixel and the motion rung differ, a motion
gap at least this share of the pixel gap places the residual in "physics or scene": the cloth
moves differently, and its pixels follow (docs/design/sim2real-residual-stage.md)."""

_STAGE_PAIR = {
    "scene": "physics or scene",
    "physics": "physics or scene",
    "appearance": "appearance or camera",
    "camera": "appearance or camera",
}
"""The stages an unexplained residual is named by: what the user replicates or simulates
(scene, physics) against what the renderer and camera do (appearance, camera)."""


def _scaled(ref: np.ndarray, *arrays: np.ndarray) -> list[np.ndarray]:
    """``arrays`` standardized with ``ref``'s statistics (the same scaling as ``compare``)."""
    return [standardize(ref, a)[1] for a in arrays]


def rung_gaps(
    sim: LadderFeatures,
    real: LadderFeatures,
    *,
    n_perm: int,
    n_boot: int,
    n_floor: int,
    seed: int | Sequence[int],
) -> dict[str, Gap]:
    """S vs R on every rung (``seed``: an int or a sequence of ints, e.g. a caller's stream).

    Every rung's features are standardised with the pooled S and R rows and the RBF
    bandwidth is the median heuristic on them; both stay fixed for every S_e of the
    rung (:func:`candidate_result`), so all MMD² of one rung use one kernel. (Scaling by S
    alone saturates the kernel: a feature that S never varies, such as the noise level of a
    noise-free render, turns any real difference into an infinite distance, and no
    candidate strength could then look closer than another.)

    ``n_perm`` is raised where needed so that the smallest attainable p-value,
    1 / (n_perm + 1), is below the Bonferroni level of :func:`localise` at alpha 0.05.
    """
    n_perm = max(n_perm, math.ceil(2 * len(sim.rungs) / 0.05))
    out = {}
    for i, name in enumerate(sim.rungs):
        x, y = sim.rungs[name], real.rungs[name]
        pooled = np.concatenate([x, y])
        out[name] = compare(
            x, y, sim.groups, real.groups, reference=pooled,
            bandwidth=median_bandwidth(standardize(pooled)),
            n_perm=n_perm, n_boot=n_boot, n_floor=n_floor,
            rng=np.random.default_rng(np.append(seed, i)),  # flat: numpy >= 2.5 refuses nesting
        )  # fmt: skip
    return out


def harmonic_mean_p(p_values) -> float:
    """p-value of the harmonic mean of ``p_values`` (Wilson 2019), for "any of these tests".

    The mean of 1/p over L tests follows a Landau law with location log L + 0.874 and scale
    pi/2 under the global null; the combination stays valid when the tests are dependent (the
    rungs of one clip set are) and gains power where several tests carry a weak signal,
    which Bonferroni's minimum would waste.
    """
    p = np.asarray([v for v in p_values if math.isfinite(v)], dtype=float)
    if p.size == 0:
        return 1.0
    if np.any(p <= 0):
        return 0.0
    count = p.size
    return float(min(1.0, sstats.landau.sf(np.mean(1.0 / p), loc=math.log(count) + 0.874,
                                           scale=math.pi / 2)))  # fmt: skip


def localise(gaps: dict[str, Gap], *, alpha: float = 0.05) -> dict:
    """Whether there is a gap, which rungs show it, and the network layer where it jumps.

    The gap test combines both tests of every rung (:attr:`Gap.p_value`, the kernel test,
    and :attr:`Gap.p_c2st`, the classifier test) by their harmonic mean
    (:func:`harmonic_mean_p`); only when it passes at ``alpha`` do rungs count as showing the
    gap, those whose own :attr:`Gap.p_gap` is below ``alpha`` with the MMD² or the domain AUC
    above the noise floor (``significant``). ``bonferroni`` lists the rungs that pass on
    their own at ``alpha`` / (number of rungs). The jump layer is the network layer with
    the largest rise of the floor-corrected domain AUC over the rung before it (the first
    layer's predecessor is the pixel rung).
    """
    names = list(gaps)
    threshold = alpha / max(1, len(names))
    gap_p = harmonic_mean_p([p for n in names for p in (gaps[n].p_value, gaps[n].p_c2st)])

    def above_floor(gap: Gap) -> bool:
        return gap.corrected_mmd2 > 0 or gap.corrected_auc > 0

    bonferroni = [n for n in names if gaps[n].p_gap < threshold and above_floor(gaps[n])]
    significant = (
        [n for n in names if gaps[n].p_gap < alpha and above_floor(gaps[n])]
        if gap_p < alpha else []
    )  # fmt: skip
    layers = [n for n in names if n not in PIXEL_RUNGS]
    first_layer = next((n for n in layers if n in significant), None)
    jump, rise = None, -math.inf
    previous = gaps["pixel"].corrected_auc if "pixel" in gaps else 0.0
    for name in layers:
        value = gaps[name].corrected_auc
        value = 0.0 if math.isnan(value) else value
        previous = 0.0 if math.isnan(previous) else previous
        if value - previous > rise:
            jump, rise = name, value - previous
        previous = value
    return {
        "alpha": alpha,
        "gap_p": gap_p,
        "threshold": threshold,
        "significant": significant,
        "bonferroni": bonferroni,
        "first_significant_layer": first_layer,
        "jump_layer": jump,
        "jump_rise": None if jump is None else rise,
    }


def scored_rungs(location: dict, scoreable: Callable[[str], bool] | None = None) -> list[str]:
    """Rungs a candidate is scored on.

    Pixel and motion where they show the gap, plus the first network layer that shows it
    (one layer stands for the net: its layers are strongly correlated); none without a gap.
    ``scoreable`` (see :func:`score_reference`), when given, passes over the rungs it rejects;
    when it rejects every rung that shows the gap, the choice without it is kept.
    """
    significant = location["significant"]
    layers = [n for n in significant if n not in PIXEL_RUNGS]  # the first: as localise's

    def pick(accept: Callable[[str], bool]) -> list[str]:
        return [n for n in PIXEL_RUNGS if n in significant and accept(n)] + next(
            ([n] for n in layers if accept(n)), [])  # fmt: skip

    return (scoreable is not None and pick(scoreable)) or pick(lambda _: True)


def score_reference(
    location: dict, gaps: dict[str, Gap], sim: LadderFeatures, real: LadderFeatures
) -> tuple[list[str], ReferenceScores]:
    """The scored rungs and S's domain classifier on them (:func:`reference_scores`).

    The pooled test (S and S' against R) finds where the gap lies, but candidates are scored
    against S alone, whose classifier can sit at its within-domain floor on a rung where
    the pooled test sees a weak gap. There every candidate closes 0 of nothing
    (:func:`sim2real.stats.gap_closed`): the rung carries no information and only dilutes the
    score, and when every scored rung is such a rung nothing can explain the gap (blind set
    16014: lighting variation's gap on pixel and enc.block1, inside S's floor on both, while
    the deeper layers showed it clearly). Such rungs are passed over: pixel or motion is
    dropped, and the network layer becomes the first significant one where S's classifier
    is above its floor (or saturated).
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
            s for s, v in zip(self.strengths, self.score, strict=True)
            if isinstance(s, int | float) and v >= self.best_score - CONFUSABLE_WITHIN
        ]  # fmt: skip
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
        out = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)
               if f.name != "scores_oof"}  # fmt: skip
        out.update(
            best_strength=self.best_strength, best_score=self.best_score,
            fitted_strength=self.fitted_strength, strength_interval=list(self.interval),
        )  # fmt: skip
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
            name=data["name"], stage=data["stage"], strengths=tuple(data["strengths"]),
            mmd2=per_rung(data["mmd2"]), closure=per_rung(data["closure"]),
            score=numbers(data["score"]), closure_auc=per_rung(data.get("closure_auc", {})),
            fitted=data.get("fitted"),
            fit_interval=None if interval is None else tuple(interval),
            neutral=data.get("neutral"),
        )  # fmt: skip


AUC_REPEATS = 2
"""Grouped-CV repetitions (other fold draws) averaged in a candidate's classifier closure."""


def _oof(sim: LadderFeatures, features: LadderFeatures, real: LadderFeatures, rung: str):
    """Out-of-fold domain scores of ``features`` vs R on ``rung``, shape (AUC_REPEATS, n + m).

    Scaled like every comparison of the rung (S and R pooled); fold draws are fixed per
    repetition, so R's folds are the same for every candidate set.
    """
    pooled = np.concatenate([sim.rungs[rung], real.rungs[rung]])
    xs, ys = _scaled(pooled, features.rungs[rung], real.rungs[rung])
    return np.stack([
        domain_scores(xs, ys, features.groups, real.groups, rng=np.random.default_rng([r, 17]))
        for r in range(AUC_REPEATS)
    ])  # fmt: skip


def _over_repeats(measure, scores: np.ndarray, n: int) -> float:
    """``measure(row, labels)`` averaged over the repeats of out-of-fold scores (first n: S)."""
    labels = np.r_[np.zeros(n), np.ones(scores.shape[1] - n)]
    return float(np.mean([measure(row, labels) for row in scores]))


def _auc(scores: np.ndarray, n: int) -> float:
    return _over_repeats(auc_score, scores, n)


def _divergence(scores: np.ndarray, n: int) -> float:
    return _over_repeats(classifier_divergence, scores, n)


SATURATED_AUC = 0.99
"""A scored rung whose AUC(S, R) reaches this is scored by the classifier divergence instead.

With two strong effects in R, S is told apart from R perfectly, and so is S plus either
effect alone: every candidate's AUC stays at 1 and every closure at 0 (round 2 of the blind
validation, pair 8025: scene size + camera shake, no candidate and no coalition scored). The
divergence (:func:`sim2real.stats.classifier_divergence`) still falls when one of the two
effects is added."""


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
            return gap_closed(self.divergence[rung], _divergence(scores, n), 0.0)
        return gap_closed(self.auc[rung], _auc(scores, n), _auc_floor(gap))

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
        auc={r: _auc(scores, len(sim)) for r, scores in oof.items()},
        divergence={r: _divergence(scores, len(sim)) for r, scores in oof.items()},
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
    return CandidateResult(name, stage, tuple(strengths), mmd2, closure, score,
                           closure_auc=closure_auc, neutral=neutral, scores_oof=oof)  # fmt: skip


def _mmd2_floor(gap: Gap) -> float:
    return gap.floor_mmd2 if math.isfinite(gap.floor_mmd2) else 0.0


def _auc_floor(gap: Gap) -> float:
    return gap.floor_auc if math.isfinite(gap.floor_auc) else 0.5


def _resolved_interval(
    u: np.ndarray, score: np.ndarray, fitted: float, lo: float, hi: float
) -> tuple[float, float]:
    """The bootstrap interval ``(lo, hi)`` of a fit, widened to what the grid ``u`` resolves.

    The grid resolves no finer than half its local spacing: a parabola through three coarse
    points can put its vertex that far off (on the development sets the bootstrap alone
    missed a planted 0.6 shutter fitted at 0.55, [0.52, 0.58]). And where several strengths
    tie at the best score (closures clip at 1, so a plateau is common) the data cannot order
    them, while the fit and every bootstrap peak take the first: the interval spans the
    plateau, half a spacing beyond each end (blind round 9: vignetting 0.17 scored 100 % at
    0.05, 0.09 and 0.17 and was given 0.05-0.13).
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
            (before.divergence[rung], 0.0, classifier_divergence) if saturated
            else (gap.auc, _auc_floor(gap), weighted_auc)
        )  # fmt: skip
        span = max(reference - floor, 1e-3)
        for i, features in enumerate(sets):
            codes_x = np.unique(features.groups, return_inverse=True)[1].reshape(-1)
            rows_x = (draws_x if draws_x is not None else
                      bootstrap_draws(int(codes_x.max()) + 1, n_boot, rng))[codes_x]  # fmt: skip
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
        i for i, (s, v) in enumerate(zip(result.strengths, result.score, strict=True))
        if low is not None and isinstance(s, int | float) and low <= s <= high and v >= threshold
    ]  # fmt: skip
    return sorted({result.best, *inside})


def agrees(kernel: float | None) -> bool:
    """Whether a kernel closure (:func:`kernel_closure`) confirms a cause."""
    return kernel is None or kernel >= KERNEL_MIN_CLOSURE


def explains_together(
    score: float, kernel: float | None, threshold: float, without: list[float]
) -> bool:
    """Whether candidates measured together (a coalition, a stacked pair) explain the gap.

    Their closure ``score`` clears the open-set ``threshold`` by :data:`OPEN_SET_MARGIN`
    (their strengths are all fitted, so they close more by chance than one candidate), the
    kernel closure agrees (:func:`agrees`), and every member adds: the group closes more
    than each of ``without``, the closures of the group without one member.
    """
    return (score >= threshold + OPEN_SET_MARGIN and agrees(kernel)
            and all(score > other for other in without))  # fmt: skip


def rank_candidates(
    results: list[CandidateResult],
    null: CandidateResult | None,
    on: list[str],
    *,
    min_closure: float = OPEN_SET_MIN_CLOSURE,
) -> dict:
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
        results, key=lambda r: (r.best_score, not r.holds_neutral, -_distance_at_best(r)),
        reverse=True,
    )  # fmt: skip
    null_score = null.best_score if null is not None else 0.0
    threshold = max(min_closure, null_score + OPEN_SET_MARGIN)
    top = ranked[0] if ranked else None
    kernel, kernel_at = (None, None) if top is None else _kernel_confirmation(top, on, threshold)
    closes = top is not None and top.best_score >= threshold
    indistinct = top is not None and top.holds_neutral
    confusable = [
        r.name for r in ranked[1:]
        if top is not None and r.best_score >= top.best_score - CONFUSABLE_WITHIN
    ]  # fmt: skip
    stages = {}
    for stage in STAGES:
        inside = [r for r in ranked if r.stage == stage]
        stages[stage] = max((r.best_score for r in inside), default=None)
    return {
        "ranking": [r.name for r in ranked],
        "threshold": threshold,
        "null_score": null_score,
        "explained": closes and agrees(kernel) and not indistinct,
        "top": None if top is None else top.name,
        "kernel_rungs": on,
        "kernel_closure": kernel,
        "kernel_strength": None if top is None else top.strengths[kernel_at],
        "kernel_threshold": KERNEL_MIN_CLOSURE,
        "look_alike": closes and not agrees(kernel),
        "neutral_in_interval": indistinct,
        "confusable_with_top": confusable,
        "stage_scores": stages,
    }


def _distance_at_best(result: CandidateResult) -> float:
    """Mean MMD² to R over the scored rungs at the best strength (:data:`SATURATED_TIE`)."""
    values = [result.mmd2[r][result.best] for r in result.closure_auc if r in result.mmd2]
    values = [v for v in values if math.isfinite(v)]
    return float(np.mean(values)) if values else math.inf


def shapley_values(players: list[str], value: dict[frozenset, float]) -> dict[str, float]:
    """Exact Shapley values of a coalition game (few players: 2^n coalitions).

    ``value`` maps every coalition (frozenset of players, the empty one included) to its
    worth, here the share of the gap that the effects added together close. The values sum
    to the grand coalition's worth (efficiency); an effect that only matters together with
    another shares the joint gain with it instead of one of them taking it all.
    """
    count = len(players)
    out = {}
    for player in players:
        others = [p for p in players if p != player]
        total = 0.0
        for size in range(count):
            weight = math.factorial(size) * math.factorial(count - size - 1) / math.factorial(count)
            for subset in itertools.combinations(others, size):
                base = frozenset(subset)
                total += weight * (value[base | {player}] - value[base])
        out[player] = total
    return out


def best_subset_values(value: dict[frozenset, float]) -> dict[frozenset, float]:
    """Each coalition's worth as the best of its sub-coalitions' measured worths.

    A coalition is measured with every member at its own fitted strength; a strength fitted
    alone can overshoot once another effect closes part of the same gap, so adding a member
    can lower the measured closure. A joint fit may always leave a member at its neutral
    strength, so its worth is at least its best sub-coalition's: this (monotone) lower bound
    is the game whose Shapley values are reported. ``value`` must hold every sub-coalition.
    """
    out = {}
    for coalition in sorted(value, key=len):
        best = value[coalition]
        for member in coalition:
            best = max(best, out[coalition - {member}])
        out[coalition] = best
    return out


def stage_of_residual(
    location: dict, stage_scores: dict | None = None, gaps: dict | None = None
) -> str:
    """Stage named by an unexplained gap (no candidate closes enough of it).

    Where some candidate moves S toward R by at least :data:`RESIDUAL_STAGE_MIN_CLOSURE`,
    the stage of the one that closes most places the residual, in the pair it belongs to
    ("physics or scene" or "appearance or camera"): the library's partial closures say which
    way R lies even when none explains it. Only where no candidate moves S that far does the
    rung pattern decide. The pattern alone misleads for motion: a different wind changes the
    cloth's shading and silhouette, so the pixel statistics differ as much as for a camera
    effect (the out-of-library wind speeds of every blind round; docs/sim2real.md).

    The converse holds: where the motion differs and the pixel statistics do not, the
    appearance candidates' partial closures are not counted. The motion rung is
    appearance-free (optical flow and temporal spectra of the cloth), so a renderer change
    (lighting, texture, shading) cannot make it; what such a candidate closes then lies in the
    network's layers alone. In blind round 12 an air damping 0.055 (19005: motion and three
    layers differed, pixels did not) was placed in "appearance or camera" after lighting
    variation's 49 % on enc.fc6 (physics: air damping's 30 %). Decided again over that
    round's stored reports, this changed 19005's stage (to physics or scene) and no other.
    Camera candidates (frame rate, motion blur, shake) do change the motion and still count.

    Where the pixel statistics differ and the motion does not, the scene candidates' partial
    closures are not counted: framing, pinning, swatch size and wind direction move the
    cloth, and every sealed set with a scene difference in blind rounds 12 and 13 (nine) showed
    a motion gap. In round 13 two tone curves (20000, 20002: pixel-only) were placed in
    "physics or scene" after wind-yaw jitter's 50 % on a weak network rung. Physics
    candidates still count: an air damping 0.10 (20005) changed the pixels and not the
    measured motion. Decided again over rounds 12 and 13's stored reports (in-sample), the
    rule changed those two stages (to appearance or camera) and no other; blind test: round 14.

    Where nothing moves S that far and both the pixel statistics and the motion differ, the
    motion's share of the gap decides (``gaps``: floor-corrected AUC per rung; without them
    the pixel statistics decide as before): a motion gap of :data:`RESIDUAL_MOTION_SHARE` of
    the pixel gap or more says the cloth moves differently ("physics or scene"), a smaller one
    that the image is formed differently (see the constant for how far that holds).
    """
    if not location["significant"] and location["first_significant_layer"] is None:
        return "none (no significant gap)"
    moves = "motion" in location["significant"]
    if "pixel" in location["significant"]:
        by_pattern = "appearance or camera"
        pattern = "the pixel statistics differ" + ("" if moves else ", the motion does not")
    elif moves:
        by_pattern, pattern = "physics or scene", "the motion differs, the pixel statistics do not"
    else:
        by_pattern, pattern = "network features only", "pixel and motion statistics agree"
    scores = {k: v for k, v in (stage_scores or {}).items() if v is not None}
    if by_pattern == "physics or scene":
        scores.pop("appearance", None)  # the renderer does not move the cloth
    elif by_pattern == "appearance or camera" and not moves:
        scores.pop("scene", None)  # a scene change moves the cloth
    best = max(scores, key=scores.get) if scores else None
    if best is not None and scores[best] >= RESIDUAL_STAGE_MIN_CLOSURE:
        return (
            f"{_STAGE_PAIR[best]} (the {best} candidates close most of it, "
            f"{100 * scores[best]:.0f} %, too little to name one; {pattern})"
        )
    pixel, motion = ((gaps or {}).get(k) for k in ("pixel", "motion"))
    if moves and by_pattern == "appearance or camera" and None not in (pixel, motion):
        if motion >= RESIDUAL_MOTION_SHARE * pixel:
            return (
                f"physics or scene (no candidate moves S toward R; the motion differs about "
                f"as much as the pixel statistics: gaps {motion:.2f} and {pixel:.2f})"
            )
    return f"{by_pattern} ({pattern})"


def _ridge(x: np.ndarray, y: np.ndarray, l2: float = 1.0) -> np.ndarray:
    gram = x.T @ x + l2 * len(x) * np.eye(x.shape[1])
    return np.linalg.solve(gram, x.T @ (y - y.mean()))


def probe_transfer(sim: LadderFeatures, real: LadderFeatures, *, l2: float = 1.0) -> dict:
    """Per rung: a ridge probe of the class position trained on S, tested on R.

    The class id is a stiffness ordering (``models.scores``); on R the per-video mean
    prediction is correlated (Spearman) with the measured stiffness and density. A rung
    with a large gap whose probe still transfers carries a harmless gap; a probe that
    transfers on ``motion`` but not on the network's layers points at appearance.
    """
    out = {}
    videos = np.unique(real.groups)
    index = {v: i for i, v in enumerate(videos)}
    rows = np.array([index[g] for g in real.groups])
    counts = np.bincount(rows, minlength=len(videos)).astype(float)
    stiff = np.bincount(rows, real.stiffness, len(videos)) / counts
    dens = np.bincount(rows, real.density, len(videos)) / counts
    target = sim.class_id.astype(float)
    for name in sim.rungs:
        xs, xr = _scaled(sim.rungs[name], sim.rungs[name], real.rungs[name])
        weight = _ridge(xs, target, l2)
        pred = xr @ weight
        per_video = np.bincount(rows, pred, len(videos)) / counts
        fit = np.corrcoef(xs @ weight, target)[0, 1] if np.std(xs @ weight) > 0 else 0.0
        entry = {"sim_fit_r": float(fit)}
        for label, measured in (("stiffness", stiff), ("density", dens)):
            if len(videos) >= 3 and np.std(per_video) > 0 and np.std(measured) > 0:
                entry[f"{label}_spearman"] = float(sstats.spearmanr(per_video, measured)[0])
            else:
                entry[f"{label}_spearman"] = None
        out[name] = entry
    return out
