"""Deciding stored diagnoses again: the same ranking from the same rules, new rules applied."""

import dataclasses
import json
import math

from sim2real.diagnosis import OPEN_SET_MARGIN, CandidateResult
from sim2real.report import json_safe
from sim2real.study.rescore import decide_again
from tests.sim2real.reports import as_diagnosis, joint_of


def _fit(name, score, stage="camera", strengths=(1.0, 2.0), kernel=0.9):
    """A stored candidate closing ``score`` of the classifier gap at its second strength
    (and ``kernel`` of the kernel distance on "pixel")."""
    scores = [score / 2, score]
    return CandidateResult(
        name, stage, strengths, {"pixel": [0.1, 0.1]}, {"pixel": [kernel / 2, kernel]}, scores
    )


def _report(fits, null_score=-0.2, kernel_rungs=("pixel",), shapley=None, stacked=None):
    """A stored report as JSON has it, ranked by today's rules at the default threshold."""
    from sim2real.diagnosis import rank_candidates

    null = _fit("S'", null_score, stage="null", strengths=(None, None))
    ranking = rank_candidates(fits, null, list(kernel_rungs))
    report = {
        "candidates": {f.name: {**f.to_json(), "best": f.best} for f in fits},
        "null": null.to_json(),
        "ranking": ranking.to_json(),
        "shapley": shapley,
        "stacked": stacked,
    }
    return as_diagnosis(json.loads(json.dumps(json_safe(report))))  # as run_diagnosis writes it


def _decided(report, **kwargs):
    out = decide_again(report, **kwargs)
    return dataclasses.replace(out, replayed=None), out.replayed


def test_today_s_rules_give_back_the_stored_ranking_ties_and_nan_included():
    undefined = dataclasses.replace(_fit("visual.d", 0.3), mmd2={"pixel": [math.nan, 0.1]})
    fits = [_fit("visual.a", 0.0), _fit("visual.b", 0.9), _fit("visual.c", 0.0), undefined]
    report = _report(fits, kernel_rungs=["pixel"])
    assert report.candidates["visual.d"]["mmd2"]["pixel"][0] is None  # JSON has no NaN
    report = dataclasses.replace(  # as stored
        report, candidates=dict(sorted(report.candidates.items(), reverse=True))
    )
    again, replayed = _decided(report)
    assert replayed and again == report.ranking
    assert again.ranking == ["visual.b", "visual.d", "visual.a", "visual.c"]  # ties: stored
    read = CandidateResult.from_json(report.candidates["visual.d"])
    assert math.isnan(read.mmd2["pixel"][0]) and read.mmd2["pixel"][1] == 0.1
    assert (read.strengths, read.closure, read.score) == (
        undefined.strengths,
        undefined.closure,
        undefined.score,
    )


def test_another_threshold_changes_only_the_open_set_decision():
    # blind round 10's 17030: frame rate closed 0.57 of an out-of-library effect's gap
    report = _report([_fit("visual.frame_rate", 0.57), _fit("visual.b", 0.1)])
    assert not report.ranking.explained  # today's threshold, 0.6
    lower, replayed = _decided(report, min_closure=0.5)
    assert replayed and lower.explained and lower.threshold == 0.5
    assert lower.ranking == report.ranking.ranking
    report = _report([_fit("visual.frame_rate", 0.57)], null_score=0.5)  # a noisy null draw
    assert _decided(report, min_closure=0.5)[0].threshold == 0.5 + OPEN_SET_MARGIN


def test_a_stored_coalition_or_stacked_fit_is_decided_again():
    shapley = {
        "coalitions": {"visual.a+visual.b": 0.8},
        "kernel_closure": {"visual.a+visual.b": 0.7},
    }
    fits = [_fit("visual.a", 0.4), _fit("visual.b", 0.3)]
    together, replayed = _decided(_report(fits, shapley=shapley))
    assert replayed and together.explained_by == ["visual.a", "visual.b"]
    assert not _decided(_report(fits, shapley=shapley), min_closure=0.7)[0].explained

    stacked = {"leader": "visual.a", "best": "visual.b", "score": 0.9, "kernel_closure": 0.8}
    pair, replayed = _decided(_report(fits, stacked=stacked))
    assert replayed and pair.explained_by == ["visual.a", "visual.b"]
    assert pair.explained_by_score == 0.9 and not pair.look_alike
    # the stored run named a cause alone, so it never fitted a partner: not replayable
    alone = _report([_fit("visual.a", 0.55), _fit("visual.b", 0.1)])
    lower, _ = _decided(alone, min_closure=0.5)
    assert lower.explained
    higher, replayed = _decided(alone, min_closure=0.6)
    assert not higher.explained and not replayed
    # a leader below the stacked fit's least closure needs none: replayed as unexplained
    weak, replayed = _decided(_report([_fit("visual.a", 0.2)]))
    assert not weak.explained and replayed


def test_a_stored_joint_fit_is_named_only_where_the_kernel_distance_sees_the_gap():
    from sim2real.study.rescore import decided_again

    joint = joint_of({"visual.a": 2.0}, 0.9)
    for rungs, named in [(("pixel",), {"visual.a": 2.0}), ((), {})]:
        report = _report([_fit("visual.a", 0.9)], kernel_rungs=rungs)
        report = dataclasses.replace(report, rungs={"pixel": {"corrected_auc": 0.3}}, joint=joint)
        assert decided_again(report).joint.named == named
