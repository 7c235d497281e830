"""Scoring sealed sets with several withheld effects (``multi``) and none at all (``twin``).

The diagnosis answers such a set with its joint calibration (:mod:`sim2real.diagnosis.joint`):
the factors that matter, each with its share of the gap. Scored against the answer:

* which factors: precision and recall of the named factors against the withheld library
  effects, their F1, and the F1 against only the withheld effects that matter (resetting one
  at the truth gives back at least :data:`~sim2real.diagnosis.joint.MATTERS` of the gap; an
  effect that moves nothing cannot be found);
* how much: the stage shares of the gap against the truth's, in points. The truth's shares
  are measured after the answer is opened: the withheld effects, their strengths refitted
  from the sealed ones (the seal's image effects are second implementations on their own
  scales), are built and attributed exactly as the diagnosis attributes its own fit (reset
  and exact Shapley values, :func:`truth_attribution`);
* how strong: whether each named true factor's strength lies in the joint fit's strength
  interval (:func:`strengths_in_intervals`);
* an effect-free twin counts as a false attribution when any factor or effect is named.

Every sealed set's fabrics differ in areal density (the answer's ``density_range``), which a
simulator of one density per class lacks: that spread is a true difference of every such set,
the library's ``physics.density_variation`` at the spread ln(high / low)
(:func:`answer_effects`). It is scored as a withheld effect of a ``multi`` set, and naming it
is not a false attribution (a twin's or an open set's); answers without a range have no such
entry.
"""

from __future__ import annotations

import math

import numpy as np

from ..diagnosis.joint import MATTERS, Factor, assignment, attribute, calibrate
from ..reopen import reopen
from ..result import Diagnosis
from .image_twins import TWIN_EFFECTS

__all__ = [
    "FABRIC_SPREAD",
    "answer_effects",
    "named_factors",
    "predicted_stage_shares",
    "score_multi",
    "strengths_in_intervals",
    "truth_attribution",
]

FABRIC_SPREAD = "physics.density_variation"
"""The library effect that the fabrics' own density spread is."""


def answer_effects(answer: dict) -> list[dict]:
    """The answer's withheld effects plus its fabrics' density spread, when it has one."""
    effects = list(answer["effects"])
    low, high = answer.get("density_range", (1.0, 1.0))
    if high > low and all(e["name"] != FABRIC_SPREAD for e in effects):
        spread = float(f"{math.log(high / low):.4g}")
        effects.append(
            {"name": FABRIC_SPREAD, "stage": "physics", "strength": spread, "library": True}
        )
    return effects


def named_factors(result: Diagnosis) -> set[str]:
    """The factors a diagnosis names: its joint fit's, else its named effect (or coalition)."""
    if result.joint is not None and result.joint.named:
        return set(result.joint.named)
    ranking = result.ranking
    if not ranking.explained:
        return set()
    return set(ranking.explained_by or [ranking.top])


def predicted_stage_shares(result: Diagnosis) -> dict[str, float]:
    """Stage -> share of the gap the diagnosis puts there."""
    if result.joint is not None and result.joint.named:
        return result.joint.stage_shares()
    ranking = result.ranking
    if not ranking.explained:
        return {}
    top = result.candidates[ranking.top]
    return {top["stage"]: float(top["best_score"])}


def _truth_factors(result: Diagnosis, answer: dict, spread: int) -> list[Factor]:
    """The withheld library effects as factors starting at their sealed strengths.

    Each also tries up to ``spread`` of the strengths the diagnosis scored it at: the seal
    applies image effects through second implementations whose strength scales differ from
    the candidates' (a sealed defocus radius is not the candidate's), so the truth is
    attributed at the strengths that reproduce it best with the library.
    """
    factors = []
    for effect in answer_effects(answer):
        if not effect["library"]:
            continue
        name, sealed = effect["name"], effect["strength"]
        scored = list(result.candidates.get(name, {}).get("strengths", []))
        if sealed is None or isinstance(sealed, str) or not scored:
            options = (sealed,)
        else:
            picked = {
                scored[round(v)] for v in np.linspace(0, len(scored) - 1, min(spread, len(scored)))
            }
            options = tuple(sorted(picked | {sealed}))
        factors.append(Factor(name, effect["stage"], options, start=sealed))
    return factors


def truth_attribution(result: Diagnosis, answer: dict, *, n_jobs: int = 1) -> dict | None:
    """The withheld library effects, refitted from their sealed strengths, attributed against R.

    The strengths are refitted by one round of the joint fit's coordinate ascent
    (:func:`_truth_factors`), then attributed exactly as the diagnosis attributes its own
    fit. ``None`` when the set has none or the diagnosis found no gap to score against.
    """
    factors = _truth_factors(result, answer, result.inputs.budget_settings["joint_strengths"])
    if not factors or not result.scored_rungs:
        return None
    reopened = reopen(result)
    memo: dict = {}

    def evaluate(batch):
        todo = [a for a in dict.fromkeys(batch) if a not in memo]
        if todo:
            memo.update(zip(todo, reopened.values(todo, n_jobs=n_jobs), strict=True))
        return [memo[a] for a in batch]

    sealed = assignment({f.name: f.start for f in factors})
    (at_sealed,) = evaluate([sealed])
    truth, value, _ = calibrate(factors, evaluate, rounds=1)
    reset, _, shapley, _, kept, full = attribute(truth, value, evaluate, matters=MATTERS)
    stages = {f.name: f.stage for f in factors}
    shares: dict[str, float] = {}
    for name, share in shapley.items():
        shares[stages[name]] = shares.get(stages[name], 0.0) + share
    return {
        "closure": value.closure,
        "closure_at_sealed": at_sealed.closure,
        "strengths": dict(truth),
        "reset": reset,
        "shapley": shapley,
        "matter": sorted(n for n, _ in kept),
        "stage_shares": shares,
        "closure_of_those_that_matter": full.closure,
    }


def _f1(named: set[str], truth: set[str]) -> tuple[float | None, float, float]:
    """Precision, recall and F1 of the named factors.

    Naming nothing where something was withheld has no precision (no factor named was
    wrong; ``None``, left out of the round's mean) and F1 0 (recall 0).
    """
    hit = len(named & truth)
    precision = hit / len(named) if named else (1.0 if not truth else None)
    recall = hit / len(truth) if truth else 1.0
    if precision is None or precision + recall == 0:
        return precision, recall, 0.0
    return precision, recall, 2 * precision * recall / (precision + recall)


def f1_ceiling(row: dict) -> float | None:
    """F1 of a multi set's row had exactly the effects that matter been named (no truth: None).

    A withheld effect that gives back under 5 % of the gap once the others are in place leaves
    no trace the diagnosis can name, so this bounds what any answer held to that rule scores.
    """
    if row.get("truth_matter") is None or not row.get("truth_strengths"):
        return None
    return _f1(set(row["truth_matter"]), set(row["truth_strengths"]))[2]


def strengths_in_intervals(result: Diagnosis, answer: dict, truth: dict | None) -> tuple[int, int]:
    """How many named true factors have a strength interval, and how many hold the truth.

    The truth is the sealed strength, except for an image effect the seal applied through its
    second implementation (:data:`~sim2real.study.image_twins.TWIN_EFFECTS`, on its own
    scale), whose truth is the library strength that reproduces it best (the truth
    attribution's refit; not checked without one).
    """
    if result.joint is None:
        return 0, 0
    twinned = answer.get("image_effects") == "twins"
    refit = (truth or {}).get("strengths", {})
    checked = inside = 0
    for effect in answer_effects(answer):
        name = effect["name"]
        named = effect["library"] and name in result.joint.named
        if not named or name not in result.joint.strength_interval:
            continue
        if twinned and name.removeprefix("visual.") in TWIN_EFFECTS:
            true = refit.get(name)
        else:
            true = effect["strength"]
        if not isinstance(true, int | float) or isinstance(true, bool):
            continue
        low, high = result.joint.strength_interval[name]
        checked += 1
        inside += int(low <= float(true) <= high)
    return checked, inside


def score_multi(result: Diagnosis, answer: dict, truth: dict | None) -> dict:
    """The factor and share scores of a ``multi`` or ``twin`` set (``truth``: its attribution)."""
    named = named_factors(result)
    withheld = {e["name"] for e in answer_effects(answer) if e["library"]}
    row: dict = {"named": sorted(named)}
    if answer["kind"] == "twin":
        row["false_attribution"] = bool(named - withheld)
        row["named_fabric_spread"] = FABRIC_SPREAD in named
        return row
    row["factor_precision"], row["factor_recall"], row["factor_f1"] = _f1(named, withheld)
    row["joint_closure"] = None if result.joint is None else result.joint.closure
    row["strengths_checked"], row["strengths_in_interval"] = strengths_in_intervals(
        result, answer, truth
    )
    if truth is None:
        return row
    row["truth_strengths"] = dict(truth.get("strengths", {}))
    if result.joint is not None:
        row["strength_intervals"] = {
            n: list(result.joint.strength_interval[n])
            for n in sorted(named)
            if n in result.joint.strength_interval
        }
    row["truth_closure"] = truth["closure"]
    row["truth_matter"] = truth["matter"]
    row["factor_f1_matter"] = _f1(named, set(truth["matter"]))[2]
    predicted = predicted_stage_shares(result)
    stages = set(predicted) | set(truth["stage_shares"])
    row["stage_share_error_pts"] = max(
        (100 * abs(predicted.get(s, 0.0) - truth["stage_shares"].get(s, 0.0)) for s in stages),
        default=0.0,
    )
    row["stage_shares"] = predicted
    row["truth_stage_shares"] = truth["stage_shares"]
    return row
