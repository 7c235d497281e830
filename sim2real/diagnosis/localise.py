"""Is there a gap, and on which rungs: every rung's tests, pooled by a harmonic mean."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np
from scipy import stats as sstats

from ..ladder import LadderFeatures
from ..rungs import hand_rung_names, rungs_revealing
from ..stats import (
    Gap,
    compare,
    median_bandwidth,
    standardize,
)

__all__ = ["harmonic_mean_p", "localise", "rung_gaps", "scored_rungs"]


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
            x,
            y,
            sim.groups,
            real.groups,
            reference=pooled,
            bandwidth=median_bandwidth(standardize(pooled)),
            n_perm=n_perm,
            n_boot=n_boot,
            n_floor=n_floor,
            rng=np.random.default_rng(np.append(seed, i)),  # flat: numpy >= 2.5 refuses nesting
        )
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
    return float(
        min(1.0, sstats.landau.sf(np.mean(1.0 / p), loc=math.log(count) + 0.874, scale=math.pi / 2))
    )


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
        if gap_p < alpha
        else []
    )
    layers = [n for n in names if n not in hand_rung_names()]
    first_layer = next((n for n in layers if n in significant), None)
    jump, rise = None, -math.inf
    image = [gaps[n].corrected_auc for n in rungs_revealing("image") if n in gaps]
    previous = max(image, default=0.0)
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
    layers = [n for n in significant if n not in hand_rung_names()]  # the first: as localise's

    def pick(accept: Callable[[str], bool]) -> list[str]:
        return [n for n in hand_rung_names() if n in significant and accept(n)] + next(
            ([n] for n in layers if accept(n)), []
        )

    return (scoreable is not None and pick(scoreable)) or pick(lambda _: True)
