"""A finished diagnosis reopened: score any combination of candidates against its R.

The diagnosis stores what its comparisons rest on (the nominal spec, the cloth box, the
budget, the seeds) and caches every set's features, so S, R and the reference classifier
come back in seconds. With them any assignment of candidate strengths (one effect, several,
the withheld effects of a sealed set) is built, or read from the cache, and scored exactly as
the diagnosis scores its own candidates (:func:`sim2real.diagnosis.joint.closure_values`).
The validation uses this to measure the truth's attribution after the answer is opened;
``benchmarks/gap_resolution.py`` to show the gap measure resolving effects added one by one.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from datasets.spec import DatasetSpec

from .candidates import Candidate, candidate_library
from .diagnosis.joint import Assignment, Value, closure_values
from .diagnosis.reference import Reference, compare_domains
from .diagnosis.scoring import oof_auc, oof_divergence
from .domains import real_clips
from .ladder import LadderFeatures, file_digest
from .pipeline import (
    Budget,
    SetContext,
    SetJob,
    assignment_job,
    nominal_path,
    null_job,
    real_ladder,
    run_jobs,
)
from .result import Diagnosis, DiagnosisInputs

__all__ = ["Reopened", "reopen", "report_context", "report_real_features"]


@dataclasses.dataclass(frozen=True)
class Reopened:
    """What a diagnosis compared its candidate sets with, ready to score more of them."""

    spec: DatasetSpec
    """The nominal set's spec (S)."""
    library: dict[str, Candidate]
    context: SetContext
    reference: Reference
    """S, S' and R compared, as the diagnosis compared them."""
    budget: Budget
    seed: int

    def jobs(self, batch: Sequence[Assignment]) -> list[SetJob]:
        """The sets the non-empty assignments of ``batch`` need."""
        return [assignment_job(self.spec, self.library, a) for a in batch if a]

    def features(
        self, batch: Sequence[Assignment], *, n_jobs: int = 1, progress: bool = False
    ) -> list[LadderFeatures]:
        """Each assignment's set (S for the empty one), built where not cached."""
        jobs = self.jobs(batch)
        built, _ = run_jobs(jobs, self.context, n_jobs, progress, {})
        labels = iter(j.label for j in jobs)
        return [built[next(labels)] if a else self.reference.nominal for a in batch]

    def values(
        self, batch: Sequence[Assignment], *, n_jobs: int = 1, progress: bool = False
    ) -> list[Value]:
        """Each assignment's closure of the gap with its bootstrap replicates."""
        sets = self.features(batch, n_jobs=n_jobs, progress=progress)
        return closure_values(sets, self.reference, n_boot=self.budget.n_boot, seed=self.seed)

    def classifier(self, batch: Sequence[Assignment], *, n_jobs: int = 1) -> list[dict]:
        """Per assignment and scored rung: the domain classifier's AUC and divergence to R."""
        sets = self.features(batch, n_jobs=n_jobs)
        ref = self.reference
        scored = ref.score("any", "any", (None,) * len(sets), sets)
        return [
            {
                rung: {
                    "auc": oof_auc(scored.scores_oof[rung][i], len(sets[i])),
                    "divergence": oof_divergence(scored.scores_oof[rung][i], len(sets[i])),
                }
                for rung in ref.rungs
            }
            for i in range(len(sets))
        ]


def report_context(inputs: DiagnosisInputs) -> SetContext:
    """How a stored diagnosis built its sets (box, network, caches, clip cut), on the CPU."""
    return SetContext(
        box=tuple(int(v) for v in inputs.box),
        checkpoint=inputs.checkpoint,
        checkpoint_digest=file_digest(Path(inputs.checkpoint)),
        mesh_cache=inputs.mesh_cache,
        cache_dir=inputs.cache_dir,
        clip_len=inputs.clip_len,
        clip_stride=inputs.clip_stride,
        device="cpu",
    )


def report_real_features(inputs: DiagnosisInputs) -> LadderFeatures:
    """The real clips of a stored diagnosis (its report's ``inputs``) on every rung.

    Cut and boxed as that diagnosis cut them, and read from its feature cache when present.
    """
    context = report_context(inputs)
    real_dir = Path(inputs.real_dir)
    size = inputs.nominal_spec["camera"]["height"]
    fps = inputs.nominal_spec["preset"]["fps"]
    clips_per = inputs.budget_settings["clips_per_sim"]
    real = real_clips(
        real_dir,
        size=size,
        clip_len=context.clip_len,
        clip_stride=context.clip_stride,
        fps=fps,
        max_clips_per_video=clips_per,
    )
    return real_ladder(real_dir, real, context, fps=fps, max_clips=clips_per)


def reopen(diagnosis: Diagnosis) -> Reopened:
    """The comparisons of a stored diagnosis, from its inputs and the feature cache.

    Raises:
        ValueError: When the nominal set's features are no longer in the cache (the cache
            folder was moved or cleared: rerun the diagnosis).
    """
    info = diagnosis.inputs
    spec = DatasetSpec.from_json(info.nominal_spec)
    context = report_context(info)
    path = nominal_path(spec, context)
    if not path.is_file():
        raise ValueError(
            f"cache_dir: {info.cache_dir} no longer holds the nominal set's features; "
            "rerun the diagnosis"
        )
    nominal = LadderFeatures.load(path)
    null = run_jobs([null_job(spec)], context, 1, False, {})[0]["S'"]
    budget = Budget(
        **{k: tuple(v) if isinstance(v, list) else v for k, v in info.budget_settings.items()}
    )
    reference = compare_domains(
        nominal,
        null,
        report_real_features(info),
        n_perm=budget.n_perm,
        n_boot=budget.n_boot,
        n_floor=budget.n_floor,
        seed=info.seed,
        alpha=info.alpha,
    )
    if reference.rungs != list(diagnosis.scored_rungs) or not np.allclose(
        [reference.before.auc[r] for r in reference.rungs],
        [diagnosis.reference_auc[r] for r in reference.rungs],
        atol=1e-9,
    ):
        raise ValueError("cache_dir: the cached features no longer match the stored diagnosis")
    return Reopened(spec, candidate_library(spec), context, reference, budget, info.seed)
