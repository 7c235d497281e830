"""Stand-in diagnoses for tests of what reads them: a partial report, the rest defaulted."""

import dataclasses

from sim2real.diagnosis.joint import JointFit
from sim2real.result import Diagnosis, DiagnosisInputs, Ranking

RANKING = {
    "ranking": [],
    "threshold": 0.6,
    "null_score": 0.0,
    "explained": False,
    "top": None,
    "kernel_rungs": [],
    "kernel_closure": None,
    "kernel_strength": None,
    "kernel_threshold": 0.6,
    "look_alike": False,
    "neutral_in_interval": False,
    "confusable_with_top": [],
    "stage_scores": {},
}


def joint_of(strengths: dict, closure: float, **fields) -> JointFit:
    """A joint fit of ``strengths`` (name -> value) closing ``closure``, all of it theirs."""
    share = closure / len(strengths)
    values = {
        "factors": dict.fromkeys(strengths, "camera"),
        "strengths": dict(strengths),
        "strength_interval": {},
        "closure": closure,
        "closure_interval": (closure, closure),
        "rung_closure": {"pixel": closure},
        "reset": {},
        "reset_interval": {},
        "shapley": dict.fromkeys(strengths, share),
        "shapley_interval": {},
        "path": [],
        "sets": 2,
    }
    return JointFit(**{**values, **fields})


def ranking_of(**fields) -> Ranking:
    """A ranking with ``fields`` set, the rest as :data:`RANKING` has them."""
    return Ranking.from_json({**RANKING, **fields})


LOCATION = {
    "alpha": 0.05,
    "gap_p": 1.0,
    "threshold": 0.005,
    "significant": [],
    "bonferroni": [],
    "first_significant_layer": None,
    "jump_layer": None,
    "jump_rise": None,
}
REPORT = {
    "name": "test",
    "rungs": {},
    "detection_rungs": {},
    "scored_rungs": [],
    "reference_auc": {},
    "reference_classifier": {},
    "candidates": {},
    "null": {},
    "residual": None,
    "shapley": None,
    "stacked": None,
    "counterfactuals": {},
    "residual_stage": "",
    "detectability": {},
    "probes": {},
    "sets": {},
    "timing": {},
}


def as_diagnosis(partial: dict) -> Diagnosis:
    """A :class:`Diagnosis` holding ``partial``'s sections over neutral defaults."""
    inputs = {f.name: None for f in dataclasses.fields(DiagnosisInputs) if f.name != "extra"}
    merged = {**REPORT, **partial}
    merged["ranking"] = {**RANKING, **partial.get("ranking", {})}
    merged["location"] = {**LOCATION, **partial.get("location", {})}
    merged["inputs"] = {**inputs, **partial.get("inputs", {})}
    return Diagnosis.from_json(merged)
