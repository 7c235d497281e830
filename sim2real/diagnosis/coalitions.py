"""Exact Shapley values of a closure over a few candidates, and best-subset worths."""

from __future__ import annotations

import itertools
import math

__all__ = ["best_subset_values", "shapley_values"]


def shapley_values(players: list[str], value: dict[frozenset, float]) -> dict[str, float]:
    """Exact Shapley values of a coalition game (few players: 2^n coalitions).

    ``value`` maps every coalition (frozenset of players, the empty one included) to its
    worth, here the share of the gap that the effects added together close. The values sum
    to the grand coalition's worth (efficiency); an effect that only matters together with
    another shares the joint gain with it instead of one of them taking it all.
    """
    count = len(players)
    out = {}
    for player in players:
        others = [p for p in players if p != player]
        total = 0.0
        for size in range(count):
            weight = math.factorial(size) * math.factorial(count - size - 1) / math.factorial(count)
            for subset in itertools.combinations(others, size):
                base = frozenset(subset)
                total += weight * (value[base | {player}] - value[base])
        out[player] = total
    return out


def best_subset_values(value: dict[frozenset, float]) -> dict[frozenset, float]:
    """Each coalition's worth as the best of its sub-coalitions' measured worths.

    A coalition is measured with every member at its own fitted strength; a strength fitted
    alone can overshoot once another effect closes part of the same gap, so adding a member
    can lower the measured closure. A joint fit may always leave a member at its neutral
    strength, so its worth is at least its best sub-coalition's: this (monotone) lower bound
    is the game whose Shapley values are reported. ``value`` must hold every sub-coalition.
    """
    out = {}
    for coalition in sorted(value, key=len):
        best = value[coalition]
        for member in coalition:
            best = max(best, out[coalition - {member}])
        out[coalition] = best
    return out
