"""Decide a stored diagnosis again from its measured closures, without building any set.

A diagnosis measures (every candidate's closures, the null draw's, the coalitions' and the
stacked fit's) and then decides (the open-set threshold, the kernel check, the coalition
and stacked-fit rules). :func:`decide_again` reruns only the second part on a stored
``report.json``, with today's rules or another open-set threshold, so that a change of a
threshold can be checked on every stored sealed set in seconds and by anyone
(``python -m sim2real.study.validate --rescore``). Run on a report the same code wrote, it gives
back the stored ranking exactly.

One decision cannot be replayed: the stacked fit runs only when nothing else explains the
gap and the leader closes at least :data:`~sim2real.stacking.STACK_MIN_LEADER`. When the
rules now call for a stacked fit that the stored run never made (it had named a cause
before), the decision is left unexplained and marked ``"replayed": False``: rerun the
diagnosis to know.

:func:`decided_again` returns the whole report so decided, with the residual stage of an
unexplained gap (:func:`~sim2real.diagnosis.stage_of_residual`) recomputed from the new
ranking.
"""

from __future__ import annotations

import dataclasses

from ..diagnosis import (
    OPEN_SET_MIN_CLOSURE,
    CandidateResult,
    explains_together,
    rank_candidates,
    stage_of_residual,
)
from ..pipeline import explained_together
from ..report import json_safe
from ..result import Diagnosis, Ranking
from ..stacking import STACK_MIN_LEADER, explained_by_stack

__all__ = ["decide_again", "decided_again"]


def decide_again(report: Diagnosis, *, min_closure: float = OPEN_SET_MIN_CLOSURE) -> Ranking:
    """The ranking of a stored ``report`` decided again at open-set threshold ``min_closure``.

    Returns the ranking as :func:`sim2real.pipeline.run_diagnosis` stores it, with
    ``replayed``: ``False`` when the decision needs a stacked fit that the stored run did
    not make (see the module docstring).
    """
    stored = report.ranking.ranking  # ties keep their stored order (a stable sort)
    order = sorted(report.candidates, key=lambda n: stored.index(n) if n in stored else 0)
    results = [CandidateResult.from_json(report.candidates[n]) for n in order]
    null = CandidateResult.from_json(report.null) if report.null else None
    ranking = rank_candidates(results, null, report.ranking.kernel_rungs, min_closure=min_closure)
    alone = {r.name: r.best_score for r in results}
    ranking = dataclasses.replace(explained_together(ranking, report.shapley, alone), replayed=True)
    top = ranking.top
    stacked = report.stacked
    if (
        ranking.explained
        or top is None
        or ranking.neutral_in_interval
        or alone[top] < STACK_MIN_LEADER
    ):
        pass
    elif stacked is None or stacked["leader"] != top:
        ranking = dataclasses.replace(ranking, replayed=False)
    elif stacked["best"] is not None and explains_together(
        stacked["score"],
        stacked["kernel_closure"],
        ranking.threshold,
        [alone[top], alone[stacked["best"]]],
    ):
        ranking = explained_by_stack(ranking, stacked)
    return Ranking.from_json(json_safe(ranking.to_json()))


def decided_again(report: Diagnosis, *, min_closure: float = OPEN_SET_MIN_CLOSURE) -> Diagnosis:
    """``report`` with its ranking, residual stage and joint fit's naming decided again.

    The ranking by :func:`decide_again`; the joint fit names factors only where a scored
    rung has a kernel gap (:attr:`~sim2real.diagnosis.joint.JointFit.kernel_gap`).
    """
    ranking = decide_again(report, min_closure=min_closure)
    gaps = {name: gap["corrected_auc"] for name, gap in report.rungs.items()}
    stage = stage_of_residual(report.location.to_json(), ranking.stage_scores, gaps)
    joint = report.joint
    if joint is not None:
        joint = dataclasses.replace(joint, kernel_gap=bool(ranking.kernel_rungs))
    return dataclasses.replace(report, ranking=ranking, residual_stage=stage, joint=joint)
