"""A diagnosis as a typed value: the one place where the shape of ``report.json`` is defined.

:func:`sim2real.pipeline.run_diagnosis` returns a :class:`Diagnosis`; its :meth:`to_json` is
what ``report.json`` holds, and :meth:`Diagnosis.from_json` reads a stored report back for the
commands that work on finished diagnoses (the report writer, validation, rescoring, shrinking,
the power study). The steps the readers decide on (where the gap lies, which candidate is
named) are typed (:class:`Location`, :class:`Ranking`, :class:`DiagnosisInputs`); the
per-rung and per-candidate tables keep their JSON form (``Gap.to_json``,
``CandidateResult.to_json``), documented where they are made. Keys a newer or older report
holds that this version does not know are kept (``extra``), so a report round-trips
unchanged.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import Any, ClassVar

from .diagnosis.joint import JointFit
from .diagnosis.ranking import Ranking
from .section import Section, fields_of, split_known

__all__ = ["Diagnosis", "DiagnosisInputs", "Location", "Ranking"]


@dataclasses.dataclass(frozen=True)
class Location(Section):
    """Is there a gap, and on which rungs (:func:`sim2real.diagnosis.localise`)."""

    alpha: float
    """Family-wise level of the gap test."""
    gap_p: float
    """Harmonic-mean p-value over every rung's tests (R against S and S' pooled)."""
    threshold: float
    """Bonferroni level over the rungs (``alpha`` / rung count)."""
    significant: list[str]
    """Rungs that show the gap (a test below alpha, a statistic above its floor)."""
    bonferroni: list[str]
    """Rungs that also pass Bonferroni on their own."""
    first_significant_layer: str | None
    """The first network layer that shows the gap."""
    jump_layer: str | None
    """The network layer with the largest rise in floor-corrected AUC."""
    jump_rise: float | None
    """That rise."""
    extra: dict = dataclasses.field(default_factory=dict)
    section: ClassVar[str] = "location"


@dataclasses.dataclass(frozen=True)
class DiagnosisInputs(Section):
    """What a diagnosis was run on, and how: enough to rebuild any of its sets."""

    real_dir: str
    run: str
    checkpoint: str
    data_dir: str | None
    mesh_cache: str
    cache_dir: str
    clip_len: int
    clip_stride: int
    real_videos: int
    real_clips: int
    real_skipped: list[str]
    sim_clips: int
    sim_groups: int
    budget: str
    budget_settings: dict
    box: list[int]
    training_spec_key: str
    nominal_spec: dict
    alpha: float
    seed: int
    sim_seed: int
    device: str
    checkpoint_digest: str | None = None
    """sha256 of the checkpoint's bytes (first 16 hex digits): which trained model answered,
    so rows of one validation round can be checked to share it (``None`` in older reports)."""
    extra: dict = dataclasses.field(default_factory=dict)
    section: ClassVar[str] = "inputs"

    @property
    def real_path(self) -> Path:
        """The real footage folder."""
        return Path(self.real_dir)


_TYPED = {"location": Location, "ranking": Ranking, "inputs": DiagnosisInputs}


@dataclasses.dataclass(frozen=True)
class Diagnosis:
    """A finished diagnosis: every section of ``report.json``."""

    name: str
    inputs: DiagnosisInputs
    rungs: dict[str, dict]
    """Per rung, R against S: ``Gap.to_json`` (MMD², AUC, tests, intervals, floors)."""
    detection_rungs: dict[str, dict]
    """Per rung, R against S and S' pooled (the gap test)."""
    location: Location
    scored_rungs: list[str]
    """The rungs candidates are scored on."""
    reference_auc: dict[str, float]
    """S against R's domain-classifier AUC on each scored rung."""
    reference_classifier: dict
    """The scored rungs' AUC, divergence and which are saturated."""
    candidates: dict[str, dict]
    """Per candidate: ``CandidateResult.to_json`` with ``best`` and ``kernel_closure``."""
    null: dict
    """The fresh nominal draw S' scored as a candidate (chance)."""
    ranking: Ranking
    residual: dict | None
    """The gap tests between R and the top candidate's best set."""
    shapley: dict | None
    """Coalitions of the best candidates: closures and Shapley values."""
    stacked: dict | None
    """The stacked fit on the leader, when it ran."""
    counterfactuals: dict
    """The stage swaps: R's camera on S, batch-norm statistics re-estimated on R."""
    residual_stage: str
    """Where an unexplained gap lies, in words."""
    detectability: dict
    """Per candidate and strength: whether the gap test picks it up against S'."""
    probes: dict
    """Per rung: the class probe's transfer to R."""
    sets: dict[str, int]
    """Candidate sets built and read from the cache."""
    timing: dict[str, float]
    """Seconds per step."""
    shrink: dict | None = None
    """Section 3, added by ``sim2real.shrink``."""
    joint: JointFit | None = None
    """Every factor calibrated together and attributed (:mod:`sim2real.diagnosis.joint`);
    ``None`` when fewer than two candidates close part of the gap (or in older reports)."""
    extra: dict = dataclasses.field(default_factory=dict)

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> Diagnosis:
        """Read a stored ``report.json``.

        Raises:
            ValueError: naming the first missing or malformed section.
        """
        known, extra = split_known(cls, data, "report")
        for name, kind in _TYPED.items():
            known[name] = kind.from_json(known[name])
        if known.get("joint") is not None:
            known["joint"] = JointFit.from_json(known["joint"])
        return cls(**known, extra=extra)

    def to_json(self) -> dict:
        """What ``report.json`` holds (before ``json_safe``)."""
        out = {**self.extra}
        for name in fields_of(type(self)):
            value = getattr(self, name)
            if name in ("shrink", "joint") and value is None:
                continue
            out[name] = value.to_json() if name in _TYPED or name == "joint" else value
        return out

    @property
    def top(self) -> dict | None:
        """The top candidate's entry of :attr:`candidates`."""
        return None if self.ranking.top is None else self.candidates[self.ranking.top]
