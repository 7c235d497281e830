"""Stacked fit: a second candidate fitted on top of the leading one.

Candidates are fitted one at a time, and a coalition (:func:`sim2real.pipeline._coalition_plan`)
joins each member at its own fitted strength, so a pair whose second effect alone widens the
gap joins no coalition: motion blur added to S, whose camera does not shake, moves it away
from an R filmed with camera shake and motion blur (decision record:
docs/design/sim2real-stacked-fit.md). Here, when the
leader closes part of the gap but not enough, it is held at its fitted strength and every
candidate that only re-renders (no simulation) is fitted on top of it over its grid; the
leader is then refitted under the best partner when it re-renders too. The pair explains
the gap under the coalition rules of :func:`sim2real.pipeline.explained_together`: it
clears the open-set threshold by a margin, its kernel closure agrees, and it closes more than
either member alone (:func:`sim2real.diagnosis.explains_together`).

The functions here are pure: the caller builds the sets (``build``) and scores them
(``score``), so the same cache and workers serve them as every other candidate set.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

from .candidates import Candidate
from .diagnosis import CandidateResult, Ranking, explains_together

__all__ = ["STACK_MIN_LEADER", "explained_by_stack", "stack_label", "stacked_fit"]

STACK_MIN_LEADER = 0.25
"""Least closure of the leader that starts a stacked fit: below it the leader is taken to be
no part of a cause (decision record: docs/design/sim2real-stacked-fit.md)."""


def stack_label(first: Candidate, first_value, second: Candidate, second_value) -> str:
    """Set label of ``first`` at ``first_value`` with ``second`` at ``second_value`` on top."""
    return f"stack:{first.name}@{first_value!r}+{second.name}@{second_value!r}"


def _stacked_spec(spec, first: Candidate, first_value, second: Candidate, second_value):
    return second.apply(first.apply(spec, first_value), second_value)


def stacked_fit(
    spec,
    leader: Candidate,
    leader_result: CandidateResult,
    leader_grid: tuple,
    partners: list[tuple[Candidate, tuple, float]],
    build: Callable[[dict], None],
    score: Callable[[str, str, tuple, list[str]], CandidateResult],
    kernel: Callable[[CandidateResult], float | None],
    threshold: float,
) -> dict:
    """Fit each partner on top of the leader, refit the leader under the best; decide.

    Args:
        spec: The nominal spec the candidates apply to.
        leader: The top candidate.
        leader_result: Its own fit (its best strength holds it during the partners' fits).
        leader_grid: The strengths to refit it over (only when it re-renders).
        partners: (candidate, strengths, its own best closure) of every other candidate
            that re-renders.
        build: Builds sets given ``{label: spec}`` (cached like every candidate set).
        score: ``(name, stage, strengths, labels) -> CandidateResult`` of built sets.
        kernel: The kernel closure of a result at its best strength (``None``: undefined).
        threshold: The ranking's open-set threshold.

    Returns:
        ``{"leader", "leader_strength", "partners": {name: {"strengths", "score"}},
        "best", "best_strength", "refit": {...} or None, "score", "kernel_closure",
        "explained"}``; ``best`` is ``None`` without partners.
    """
    strength = leader_result.best_strength
    jobs = {
        stack_label(leader, strength, c, v): _stacked_spec(spec, leader, strength, c, v)
        for c, values, _ in partners
        for v in values
    }
    build(jobs)
    fits = {
        c.name: score(
            c.name, c.stage, values, [stack_label(leader, strength, c, v) for v in values]
        )
        for c, values, _ in partners
    }
    out = {
        "leader": leader.name,
        "leader_strength": strength,
        "partners": {
            n: {"strengths": list(r.strengths), "score": r.score} for n, r in fits.items()
        },
        "best": None,
        "best_strength": None,
        "refit": None,
        "score": None,
        "kernel_closure": None,
        "explained": False,
    }
    if not fits:
        return out
    name = max(fits, key=lambda n: fits[n].best_score)
    partner, _, alone = next(p for p in partners if p[0].name == name)
    fit = fits[name]
    pair = fit
    if not leader.needs_simulation and len(leader_grid) > 1:
        value = fit.best_strength
        refit = {
            stack_label(partner, value, leader, u): _stacked_spec(spec, partner, value, leader, u)
            for u in leader_grid
        }
        build(refit)
        again = score(leader.name, leader.stage, tuple(leader_grid), list(refit))
        out["refit"] = {
            "strengths": list(again.strengths),
            "score": again.score,
            "best_strength": again.best_strength,
        }
        if again.best_score > fit.best_score:
            pair = again
    closes = kernel(pair)
    out.update(
        best=name, best_strength=fit.best_strength, score=pair.best_score, kernel_closure=closes
    )
    if pair is not fit:
        out["leader_strength"] = pair.best_strength
    out["explained"] = explains_together(
        pair.best_score, closes, threshold, [leader_result.best_score, alone]
    )
    return out


def explained_by_stack(ranking: Ranking, fit: dict) -> Ranking:
    """``ranking`` with its gap explained by a stacked ``fit``'s pair (the leader named first)."""
    return dataclasses.replace(
        ranking,
        explained=True,
        look_alike=False,
        explained_by=[ranking.top, fit["best"]],
        explained_by_score=fit["score"],
        explained_by_kernel_closure=fit["kernel_closure"],
    )
