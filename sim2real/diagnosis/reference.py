"""S against R: where the gap lies, and what every candidate set is scored against."""

from __future__ import annotations

import dataclasses

from ..ladder import LadderFeatures
from ..stats import Gap
from .localise import localise, rung_gaps
from .ranking import kernel_rungs
from .scoring import CandidateResult, ReferenceScores, candidate_result, score_reference

__all__ = ["Reference", "compare_domains"]


@dataclasses.dataclass(frozen=True)
class Reference:
    """The nominal simulation S (and its second draw S') compared with the real set R."""

    nominal: LadderFeatures
    """S: the training data's settings on fresh simulations."""
    null: LadderFeatures
    """S': S under other simulation seeds (chance, and the gap test's second draw)."""
    real: LadderFeatures
    """R."""
    detection: dict[str, Gap]
    """Per rung, R against S and S' pooled: the gap test."""
    location: dict
    """Where the gap lies (:func:`localise` of :attr:`detection`)."""
    gaps: dict[str, Gap]
    """Per rung, R against S: the size every candidate set is compared at."""
    rungs: list[str]
    """The scored rungs."""
    before: ReferenceScores
    """S's domain classifier against R on the scored rungs."""

    @property
    def kernel_rungs(self) -> list[str]:
        """The scored rungs whose S vs R MMD² lies above its floor (:func:`kernel_rungs`)."""
        return kernel_rungs(self.gaps, self.rungs)

    def score(
        self,
        name: str,
        stage: str,
        strengths: tuple,
        sets: list[LadderFeatures],
        *,
        neutral: float | None = None,
    ) -> CandidateResult:
        """Sets of S's size and seeds (one per strength) scored against R, as candidates are."""
        return candidate_result(
            name,
            stage,
            strengths,
            sets,
            self.nominal,
            self.real,
            self.gaps,
            self.rungs,
            self.before,
            neutral=neutral,
        )


def compare_domains(
    nominal: LadderFeatures,
    null: LadderFeatures,
    real: LadderFeatures,
    *,
    n_perm: int,
    n_boot: int,
    n_floor: int,
    seed: int,
    alpha: float,
) -> Reference:
    """Whether there is a gap, where, and S's classifier on the rungs that show it.

    The gap test pools S and S' against R (twice the simulations: on the validation's sealed
    sets this found the gap of weak effects that S alone missed); candidates are scored
    against S's own gaps, since every candidate set has S's size and seeds.
    """
    settings = {"n_perm": n_perm, "n_boot": n_boot, "n_floor": n_floor, "seed": seed}
    detection = rung_gaps(LadderFeatures.pooled(nominal, null), real, **settings)
    location = localise(detection, alpha=alpha)
    gaps = rung_gaps(nominal, real, **settings)
    rungs, before = score_reference(location, gaps, nominal, real)
    return Reference(nominal, null, real, detection, location, gaps, rungs, before)
