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

The steps live in modules of their own: :mod:`.localise` (is there a gap, on which rungs),
:mod:`.scoring` (how much of it a candidate set closes), :mod:`.fit` (the strength and its
interval), :mod:`.ranking` (the rules that name a cause: the open-set threshold, the kernel
check, the neutral rule, ties), :mod:`.coalitions` (Shapley values), :mod:`.residual` (the
stage of an unexplained gap) and :mod:`.probes` (does the class signal transfer).
"""

from __future__ import annotations

from .coalitions import best_subset_values, shapley_values
from .fit import fit_strength
from .localise import harmonic_mean_p, localise, rung_gaps, scored_rungs
from .probes import probe_transfer
from .ranking import (
    KERNEL_MIN_CLOSURE,
    NEUTRAL_RULE,
    OPEN_SET_MARGIN,
    OPEN_SET_MIN_CLOSURE,
    Ranking,
    agrees,
    explains_together,
    kernel_closure,
    kernel_rungs,
    kernel_strengths,
    rank_candidates,
)
from .residual import RESIDUAL_MOTION_SHARE, RESIDUAL_STAGE_MIN_CLOSURE, stage_of_residual
from .scoring import (
    SATURATED_AUC,
    CandidateResult,
    ReferenceScores,
    candidate_result,
    reference_scores,
    score_reference,
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
    "Ranking",
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
