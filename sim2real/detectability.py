"""What the diagnosis could have seen: each candidate strength tested sim against sim.

"No significant gap", or a candidate ranked last, says nothing about an effect too weak to show
at the set sizes in use. So every candidate set S_e the diagnosis built is tested against S',
the nominal scene under independent simulation seeds and of S's size, with the diagnosis's own
gap test (:func:`sim2real.diagnosis.localise`: the harmonic mean of every rung's kernel and
classifier p-values), as if S_e were the real set. A strength this test does not pick up is
hard to tell from the nominal simulation, so "no gap" does not rule it out.

It is conservative as an estimate of what the diagnosis sees: the gap test itself compares the
real set with S and S' pooled, more rows on both sides, though real footage also has nuisances
S' lacks (decision record: docs/design/sim2real-detectability.md).

A candidate set whose features equal S's on every rung is *inert*: S_e shares S's simulation
seeds and render draws, so an effect that changes nothing leaves every feature bit for bit
the same. No set of footage can reveal an inert effect. (Self-collision in the wind scene makes
no contact, yet it is not inert: switching it on changes the step's round-off, which reaches
the features; its sets differ from S by at most 0.012 of the between-video spread.)
"""

from __future__ import annotations

import math

import numpy as np

from .candidates import Candidate
from .diagnosis import localise, rung_gaps
from .ladder import LadderFeatures

__all__ = ["candidate_detectability", "detectable_at", "detection_p", "is_inert"]


def is_inert(nominal: LadderFeatures, features: LadderFeatures) -> bool:
    """True when ``features`` equal ``nominal``'s on every rung (the effect changed nothing)."""
    return set(nominal.rungs) == set(features.rungs) and all(
        np.array_equal(nominal.rungs[n], features.rungs[n]) for n in nominal.rungs
    )


def detection_p(null: LadderFeatures, features: LadderFeatures, *, n_perm: int, seed) -> float:
    """The diagnosis's combined gap p-value of ``features`` against ``null``.

    :func:`~sim2real.diagnosis.rung_gaps` without the bootstrap and floors, which the
    p-values do not use.
    """
    gaps = rung_gaps(null, features, n_perm=n_perm, n_boot=1, n_floor=0, seed=seed)
    return localise(gaps)["gap_p"]


def candidate_detectability(
    plan: list[tuple[Candidate, tuple]],
    sets: dict[str, LadderFeatures],
    nominal: LadderFeatures,
    null: LadderFeatures,
    label,
    *,
    alpha: float,
    n_perm: int,
    seed: int,
) -> dict[str, dict]:
    """Per candidate: which of its built strengths the gap test would pick up.

    Args:
        plan: (candidate, strengths) pairs, as the diagnosis built them.
        sets: Features per set label.
        nominal: S.
        null: S' (the nominal scene under other simulation seeds).
        label: ``label(candidate, strength)`` -> the set's key in ``sets``.
        alpha: Level of the gap test.
        n_perm: Group permutations per rung (see :func:`~sim2real.diagnosis.rung_gaps`).
        seed: Seed of the permutations.

    Returns:
        ``{name: {"stage", "strengths", "log_scale", "p", "detected", "inert", "verdict"}}``,
        lists in the plan's strength order; verdict ``inert`` (every strength inert), ``undetected``
        (none picked up), ``detected`` (all picked up) or ``partly``. An inert strength is
        not tested (p 1).
    """
    out = {}
    for i, (candidate, values) in enumerate(plan):
        p, inert = [], []
        for j, value in enumerate(values):
            features = sets[label(candidate, value)]
            inert.append(is_inert(nominal, features))
            p.append(
                1.0
                if inert[-1]
                else detection_p(null, features, n_perm=n_perm, seed=[seed, 11, i, j])
            )
        detected = [v < alpha for v in p]
        if all(inert):
            verdict = "inert"
        elif not any(detected):
            verdict = "undetected"
        else:
            verdict = "detected" if all(detected) else "partly"
        out[candidate.name] = {
            "stage": candidate.stage,
            "strengths": list(values),
            "log_scale": candidate.log_scale,
            "p": p,
            "detected": detected,
            "inert": inert,
            "verdict": verdict,
        }
    return out


def detectable_at(entry: dict, strength) -> bool:
    """Whether ``entry`` (one candidate of :func:`candidate_detectability`) picks up ``strength``.

    The answer at the nearest strength tried (in log scale for log-spaced candidates); a
    choice or a binary switch must match a tried value exactly, else False.
    """
    log_scale = entry["log_scale"]
    values = entry["strengths"]
    if strength is None or isinstance(strength, str):
        return any(d for v, d in zip(values, entry["detected"], strict=True) if v == strength)

    def where(v):
        return math.log(v) if log_scale and v > 0 else v

    numeric = [
        (abs(where(v) - where(strength)), d)
        for v, d in zip(values, entry["detected"], strict=True)
        if isinstance(v, int | float)
    ]
    return bool(min(numeric)[1]) if numeric else False
