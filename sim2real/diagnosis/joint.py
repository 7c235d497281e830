"""Every factor calibrated together, then each factor's share of the gap.

Footage that differs from the simulation in several ways at once is not explained by any one
candidate: each closes a little of the gap and none is named. Here the candidates that close
some of it become *factors* of one calibrated simulator S*: coordinate ascent over their
strengths, each refitted with all the others in place (:func:`calibrate`), maximises the
share of the gap S* closes. At S* every factor is attributed its part: the gap that returns
when it alone is reset to nominal (:attr:`JointFit.reset`) and its exact Shapley value over
the factors that matter (:attr:`JointFit.shapley`), with group-bootstrap intervals. The
Shapley values sum to S*'s closure, so "the gap is 40 % scene, 30 % physics, ... and X % is
unexplained" reads straight off :meth:`JointFit.stage_shares`.

The measure is the share of S's classifier divergence to R that a set removes, over the
scored rungs (:func:`divergence_closure`): unlike the AUC, which sits near 1 until most of
several differences are removed, the divergence falls with each one. Nothing here builds
sets: the caller passes ``evaluate``, which builds and scores a batch of assignments.

Which candidates become factors is decided with the others in place (:func:`select`): an
effect can remove little of the gap alone and much once another is there (shadows matter
once the cloth hangs as R's does), so S* grows one factor at a time, each addition screened
cheaply (``screen``: the single-candidate set's shift of every simulation added to S*'s
features, no new simulation) and the most promising built and measured.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import math
from collections.abc import Callable, Iterable, Sequence

import numpy as np

from ..ladder import LadderFeatures
from ..stats import CI_LEVEL, bootstrap_draws
from .coalitions import shapley_values
from .ranking import OPEN_SET_MARGIN, OPEN_SET_MIN_CLOSURE
from .reference import Reference
from .scoring import CONFUSABLE_WITHIN, oof_divergence

__all__ = [
    "JOINT_TOLERANCE",
    "MATTERS",
    "NOMINAL",
    "Assignment",
    "Factor",
    "JointFit",
    "Screen",
    "Value",
    "assignment",
    "attribute",
    "calibrate",
    "closure_values",
    "divergence_closure",
    "fit_jointly",
    "midpoint",
    "nominal_scores",
    "point_closures",
    "rung_closures",
    "select",
    "strength_intervals",
]


JOINT_TOLERANCE = 0.01
"""A move of the coordinate ascent must raise the closure by more than this share of the gap."""

MATTERS = 0.05
"""A factor matters when resetting it alone to nominal gives back at least this share of the
gap; only factors that matter get Shapley values and stay in S*."""

Assignment = tuple[tuple[str, object], ...]
"""The applied factors and their strengths, sorted by name (absent factors are nominal). A
switch's strength is ``None``: on."""


class _Nominal:
    """The marker of a factor left at nominal (absent from an assignment)."""

    def __repr__(self) -> str:
        return "nominal"


NOMINAL = _Nominal()
"""A factor's strength when it is left out (a switch that is on has strength ``None``)."""


def assignment(strengths: dict[str, object]) -> Assignment:
    """The canonical form of ``{factor: strength}`` (:data:`NOMINAL` entries left out)."""
    return tuple(sorted((k, v) for k, v in strengths.items() if v is not NOMINAL))


def _shown(value) -> object:
    """A strength as the report shows it: ``on`` for a switch, ``nominal`` when left out."""
    return "on" if value is None else "nominal" if value is NOMINAL else value


@dataclasses.dataclass(frozen=True)
class Value:
    """The closure of one assignment's set: the point value and its bootstrap replicates."""

    closure: float
    """Share of the gap closed (1 = S* indistinguishable from R, 0 = no better than S)."""
    replicates: np.ndarray
    """The closure under each group-bootstrap draw, shape (B,); the same draws for every
    assignment, so differences and Shapley values get intervals too."""
    rungs: dict[str, float] = dataclasses.field(default_factory=dict)
    """Scored rung -> its share of the divergence removed (:func:`rung_closures`)."""
    kernel: float | None = None
    """Share of the kernel distance (MMD²) to R removed, averaged over the scored rungs with
    a kernel gap (:func:`~sim2real.diagnosis.ranking.kernel_rungs`); ``None`` without one."""


@dataclasses.dataclass(frozen=True)
class Factor:
    """One candidate as a factor of the joint fit."""

    name: str
    stage: str
    options: tuple
    """Strengths the ascent tries (a switch: ``(None,)``, on); nominal is always tried too."""
    start: object = NOMINAL
    """Where the ascent starts: the single-candidate fit, or :data:`NOMINAL`."""
    setting: str = ""
    """What the factor sets (e.g. ``registry.field``); two factors that set one thing are
    never applied together. Empty: the factor's name."""
    simulated: bool = False
    """True when the factor re-simulates the cloth (physics, scene): its set's trajectories
    differ from S's like a fresh draw's, so it must close more than S' does; a re-rendering
    factor sees S's own meshes and needs no such floor."""
    log_scale: bool = False
    """Strengths between two tried ones are geometric midpoints (else arithmetic)."""
    integer: bool = False
    """Strengths are whole numbers (a midpoint is rounded)."""

    def __post_init__(self):
        if not self.options:
            raise ValueError(f"factor {self.name}: needs at least one strength to try")
        if not self.setting:
            object.__setattr__(self, "setting", self.name)


Evaluate = Callable[[Sequence[Assignment]], list[Value]]
"""Builds (or finds cached) and scores a batch of assignments, in order."""

Screen = Callable[[Assignment, Sequence[tuple[str, object]]], list[float]]
"""Estimates, building nothing, the closure of an assignment already evaluated with one more
factor at one strength, for each ``(factor, strength)`` in order."""


def rung_closures(
    nominal_oof: dict[str, np.ndarray],
    set_oof: dict[str, np.ndarray],
    reference: Reference,
    weights: np.ndarray | None = None,
) -> dict[str, object]:
    """Per scored rung, the share of S's classifier divergence to R that a set removes.

    ``(D(S, R) - D(S_e, R)) / D(S, R)``, clipped to [-1, 1], from the out-of-fold scores of
    S's and the set's classifiers (``{rung: (repeats, n + m)}``). With ``weights`` (row
    weights (n + m, B)) one value per bootstrap replicate.
    """
    n = len(reference.nominal)
    out = {}
    for rung in reference.rungs:
        before = oof_divergence(nominal_oof[rung], n, weights)
        after = oof_divergence(set_oof[rung], n, weights)
        closed = np.clip((before - after) / np.maximum(before, 1e-3), -1.0, 1.0)
        out[rung] = np.nan_to_num(closed, nan=0.0)
    return out


def divergence_closure(
    nominal_oof: dict[str, np.ndarray],
    set_oof: dict[str, np.ndarray],
    reference: Reference,
    weights: np.ndarray | None = None,
):
    """Share of S's classifier divergence to R that a set removes, over the scored rungs.

    The :func:`rung_closures` weighted by the classifier gap each rung carries
    (:meth:`ReferenceScores.weights`). The divergence keeps falling with every difference
    removed where the AUC stays near 1, so several effects at once are resolved one by one.
    With ``weights`` one value per bootstrap replicate.
    """
    rung_weights = reference.before.weights(reference.gaps, reference.rungs)
    closed = rung_closures(nominal_oof, set_oof, reference, weights)
    total = 0.0 if weights is None else np.zeros(weights.shape[1])
    for r, rung in enumerate(reference.rungs):
        total = total + rung_weights[r] * closed[rung]
    return total


def nominal_scores(reference: Reference) -> dict[str, np.ndarray]:
    """S's own out-of-fold scores against R per scored rung, as every set's are measured."""
    scored = reference.score("S", "null", (None,), [reference.nominal])
    return {rung: scored.scores_oof[rung][0] for rung in reference.rungs}


def _set_scores(sets: Sequence[LadderFeatures], reference: Reference):
    """S's and each set's out-of-fold scores against R per scored rung, and kernel closures.

    One classifier fit; the kernel closures are :attr:`Value.kernel`.
    """
    sim = reference.nominal
    for features in sets:
        if features.groups.shape != sim.groups.shape or np.any(features.groups != sim.groups):
            raise ValueError("closure_values: every set must hold S's simulations, in S's order")
    scored = reference.score("joint", "joint", (None,) * (len(sets) + 1), [sim, *sets])
    nominal = {rung: oof[0] for rung, oof in scored.scores_oof.items()}
    own = [{rung: oof[i + 1] for rung, oof in scored.scores_oof.items()} for i in range(len(sets))]
    on = reference.kernel_rungs
    kernel = [
        float(np.mean([scored.closure[r][i + 1] for r in on])) if on else None
        for i in range(len(sets))
    ]
    return nominal, own, kernel


def point_closures(sets: Sequence[LadderFeatures], reference: Reference) -> list[float]:
    """The :func:`divergence_closure` of each set, without intervals (for screening)."""
    nominal, own, _ = _set_scores(sets, reference)
    return [float(divergence_closure(nominal, scores, reference)) for scores in own]


def closure_values(
    sets: Sequence[LadderFeatures], reference: Reference, *, n_boot: int, seed: int
) -> list[Value]:
    """The :func:`divergence_closure` of each set, with its group-bootstrap replicates.

    A replicate redraws S's simulations and R's videos by group (the same draws for every
    set: S_e holds S's simulations) and re-measures S's and the set's divergence from their
    out-of-fold scores (classifiers held fixed). S itself closes exactly 0, in every
    replicate.
    """
    sim, real = reference.nominal, reference.real
    nominal, own, kernel = _set_scores(sets, reference)
    rng = np.random.default_rng([seed, 64])
    codes_x = np.unique(sim.groups, return_inverse=True)[1].reshape(-1)
    codes_y = np.unique(real.groups, return_inverse=True)[1].reshape(-1)
    draws_x = bootstrap_draws(int(codes_x.max()) + 1, n_boot, rng)
    draws_y = bootstrap_draws(int(codes_y.max()) + 1, n_boot, rng)
    weights = np.concatenate([draws_x[codes_x], draws_y[codes_y]]).astype(np.float64)
    return [
        Value(
            float(divergence_closure(nominal, scores, reference)),
            divergence_closure(nominal, scores, reference, weights),
            {k: float(v) for k, v in rung_closures(nominal, scores, reference).items()},
            k,
        )
        for scores, k in zip(own, kernel, strict=True)
    ]


def _nominal(count: int) -> Value:
    return Value(0.0, np.zeros(count))


def calibrate(
    factors: Sequence[Factor],
    evaluate: Evaluate,
    *,
    rounds: int = 2,
    tolerance: float = JOINT_TOLERANCE,
) -> tuple[Assignment, Value, list[dict]]:
    """Coordinate ascent over the factors' strengths, each refitted with the others in place.

    Starts from every factor at its ``start``; a round visits the factors in order and, for
    each, scores nominal and every option with the others held (one batch, so the caller can
    build it in parallel), moving when the best beats the current closure by ``tolerance``.
    Stops after a round without a move or after ``rounds``.

    Returns:
        The calibrated assignment, its value, and the path (one entry per factor visit: the
        factor, the strengths tried, their closures and the one kept).
    """
    names = [f.name for f in factors]
    if len(set(names)) != len(names):
        raise ValueError(f"factors must have distinct names, got {names}")
    current = {f.name: f.start for f in factors}
    value = evaluate([assignment(current)])[0]
    path = []
    for round_ in range(rounds):
        moved = False
        for factor in factors:
            tried = [NOMINAL, *factor.options]
            batch = [assignment({**current, factor.name: s}) for s in tried]
            values = evaluate(batch)
            closures = [v.closure for v in values]
            best = int(np.nanargmax(np.nan_to_num(closures, nan=-np.inf)))
            if tried[best] != current[factor.name] and closures[best] > value.closure + tolerance:
                current[factor.name] = tried[best]
                value = values[best]
                moved = True
            path.append(
                {
                    "round": round_ + 1,
                    "factor": factor.name,
                    "tried": [_shown(t) for t in tried],
                    "closure": closures,
                    "kept": _shown(current[factor.name]),
                }
            )
        if not moved:
            break
    return assignment(current), value, path


def select(
    factors: Sequence[Factor],
    evaluate: Evaluate,
    screen: Screen,
    *,
    top: int,
    verify: int,
    gain: float = MATTERS,
    floor: float = 0.0,
    refit: int = 0,
    prune: int = 0,
    lookahead: int = 0,
) -> tuple[list[Factor], Assignment, Value, list[dict]]:
    """Greedy forward selection of the factors of S*, each chosen with the others in place.

    A step screens every open factor (none that shares a setting with a chosen one) at each
    of its strengths on top of the current assignment, measures ``verify`` of them at their
    best screened strengths, the best of each stage first (:func:`_round_robin`), and adds
    the best measured one that qualifies: it closes at least ``gain`` more of the gap, its
    group-bootstrap interval of the gain is above 0 and, for a factor that re-simulates, the
    closure beats ``floor`` (what S' closes by chance). It must also be told from every
    rival it does not clearly beat (:meth:`_Selection._substitutes`); additions that cannot
    be told apart are recorded as ``tied`` and the step takes the best one that can, if any
    (the tied ones stay in the pool: a later step, with more of S* in place, may tell them
    apart). Stops after ``top`` factors or a step without an addition.

    A step without an addition is followed, when ``refit`` > 0 and some factor is chosen, by a
    refit step (:meth:`_Selection._refit_step`): the ``refit`` additions that gained most
    when they were measured (at any step) are each added with every chosen strength refitted
    around them.
    Forward selection holds a chosen strength fixed, so an effect that the first factor stood
    in for (an over-strong codec mimicking a finer texture) adds nothing on top of it; with
    that strength relaxed it can.

    A stall that no refit ends, with some factor chosen and room for two more, is followed,
    at most ``lookahead`` times, by a lookahead step (:meth:`_Selection._lookahead`): the
    stalled step's best built addition that gained anything (bootstrap interval above 0) is
    put in S* provisionally and one forward step taken from there; both are added when that
    step adds a factor that qualifies. Two effects can each gain little on top of S* and much
    together (a smaller swatch and sensor noise on top of a gusty wind), and a step that
    adds one factor at a time needs each to qualify alone.

    Where the selection would stop (``top`` factors chosen, or a stall that no refit or
    lookahead ends) and ``prune`` > 0, a prune step (:meth:`_Selection.prune`) drops the
    chosen factor that matters least with the later ones in place, if it no longer matters
    (resetting it alone gives back less than ``gain``, the rule :func:`attribute` keeps a
    factor by), and the selection goes on from the rest. A factor chosen early as a stand-in
    for effects added after it would otherwise hold its place to the end. A dropped factor is
    not tried again; at most ``prune`` are dropped.

    Returns:
        The chosen factors (in the order added, each starting at its chosen strength), their
        assignment, its value, and the path (one entry per step).
    """
    by_name = {f.name: f for f in factors}
    if len(by_name) != len(factors):
        raise ValueError(f"factors must have distinct names, got {[f.name for f in factors]}")
    (value,) = evaluate([()])
    state = _Selection(
        factors,
        evaluate,
        screen,
        verify,
        gain,
        floor,
        refit,
        {},
        value,
        top=top,
        lookahead=lookahead,
    )
    while (len(state.current) < top and state.grow()) or (
        len(state.dropped) < prune and state.prune()
    ):
        pass
    chosen = [dataclasses.replace(by_name[n], start=s) for n, s in state.current.items()]
    return chosen, assignment(state.current), state.value, state.path


@dataclasses.dataclass(frozen=True)
class _Step:
    """One forward step of :func:`select`: its path entry and what it measured."""

    entry: dict
    chosen: str | None
    """The addition that qualifies and can be told from its rivals; ``None``: a stall."""
    measured: Value | None
    best: dict[str, tuple[float, object]]
    """Each open factor's best screened estimate and the strength it was screened at."""
    ranked: list[tuple[str, Value]]
    """The built additions, most closure first."""


@dataclasses.dataclass
class _Selection:
    """The state of :func:`select`: S* so far, its value, the path and the gains measured."""

    factors: Sequence[Factor]
    evaluate: Evaluate
    screen: Screen
    verify: int
    gain: float
    floor: float
    refit: int
    current: dict[str, object]
    value: Value
    path: list[dict] = dataclasses.field(default_factory=list)
    gains: dict[str, tuple[float, object]] = dataclasses.field(default_factory=dict)
    """The best gain each addition was measured at, and its strength."""
    refitted: set[str] = dataclasses.field(default_factory=set)
    dropped: list[str] = dataclasses.field(default_factory=list)
    """Factors a prune step took out of S*; never tried again."""
    top: int = 0
    """Most factors S* holds (a lookahead adds two)."""
    lookahead: int = 0
    """Most lookahead steps (:meth:`_lookahead`)."""
    looked: int = 0

    @functools.cached_property
    def by_name(self) -> dict[str, Factor]:
        return {f.name: f for f in self.factors}

    def grow(self) -> bool:
        """One forward step or, after a stall, a refit or a lookahead; whether S* grew."""
        step = self._forward(self.current, self.value)
        if step is None:
            return False
        self.path.append(step.entry)
        if step.chosen is not None:
            self.current = {**self.current, step.chosen: step.best[step.chosen][1]}
            self.value = step.measured
            return True
        return self._refit() or self._lookahead(step)

    def _forward(self, current: dict[str, object], value: Value) -> _Step | None:
        """Screen every open addition to ``current``, build the shortlist, pick one to add.

        ``None`` when no factor is open; otherwise the step, whose ``chosen`` is ``None``
        when no addition qualifies against ``value`` or every one that does is tied.
        """
        used = {self.by_name[n].setting for n in current}
        open_ = [
            f
            for f in self.factors
            if f.name not in current and f.name not in self.dropped and f.setting not in used
        ]
        additions = [(f.name, s) for f in open_ for s in f.options]
        if not additions:
            return None
        estimates = self.screen(assignment(current), additions)
        best: dict[str, tuple[float, object]] = {}
        for (name, strength), estimate in zip(additions, estimates, strict=True):
            if name not in best or estimate > best[name][0]:
                best[name] = (float(estimate), strength)
        shortlist = _round_robin(best, {f.name: f.stage for f in open_}, self.verify)
        trials = [assignment({**current, n: best[n][1]}) for n in shortlist]
        values = self.evaluate(trials)
        for n, v in zip(shortlist, values, strict=True):
            if n not in self.gains or v.closure - value.closure > self.gains[n][0]:
                self.gains[n] = (v.closure - value.closure, best[n][1])
        ranked = sorted(zip(shortlist, values, strict=True), key=lambda nv: -nv[1].closure)
        kept = [
            (n, v)
            for n, v in ranked
            if _qualifies(self.by_name[n], v, value, self.gain, self.floor)
        ]
        entry = {
            "step": len(self.path) + 1,
            "screened": {n: [_shown(best[n][1]), best[n][0]] for n in shortlist},
            "measured": {n: v.closure for n, v in zip(shortlist, values, strict=True)},
        }
        chosen, measured, tied, beaten = None, None, [], []
        values_of = dict(kept)
        for leader, lead in kept:  # the best that can be told from its rivals
            if leader in tied:
                continue
            others = [(n, v) for n, v in kept if n != leader]
            twins = self._substitutes(current, [(leader, lead), *others], best)
            if any(_kernel_apart(values_of[n], lead) for n in twins):
                beaten.append(leader)  # a twin removes clearly more of the kernel distance
                continue
            apart = [n for n in twins if _kernel_apart(lead, values_of[n])]
            if apart:
                entry.setdefault("kernel_apart", {})[leader] = apart
            twins = [n for n in twins if n not in apart]
            if not twins:
                chosen, measured = leader, lead
                break
            tied += [n for n in (leader, *twins) if n not in tied]
        entry["added"] = chosen
        if tied:
            entry["tied"] = tied
        if beaten:
            entry["kernel_beaten"] = beaten
        return _Step(entry, chosen, measured, best, ranked)

    def _refit(self) -> bool:
        """After a stall: the best runners-up, each with the chosen strengths refitted."""
        used = {self.by_name[n].setting for n in self.current}
        runners = sorted(
            (
                n
                for n in self.gains
                if n not in self.current
                and n not in self.refitted
                and n not in self.dropped
                and self.gains[n][0] > 0
                and self.by_name[n].setting not in used
            ),
            key=lambda n: -self.gains[n][0],
        )[: self.refit if self.current else 0]
        if not runners:
            return False
        self.refitted.update(runners)
        step, fitted, measured = self._refit_step(runners)
        step["step"] = len(self.path) + 1
        self.path.append(step)
        if fitted is None:
            return False
        self.current, self.value = fitted, measured
        return True

    def _lookahead(self, stalled: _Step) -> bool:
        """Two factors at once: the stalled step's best small gain, and one step beyond it.

        The addition built at the stalled step that closes most of those that gained anything
        (interval of the gain above 0; a factor that re-simulates above ``floor``) goes in
        provisionally, and one forward step is taken from there. Both are added when that
        step adds a factor, which must qualify on top of the provisional one; the provisional
        one then holds a place even where it alone adds little, and :func:`attribute` drops it
        from the named factors unless resetting it gives back at least ``gain``.
        """
        if self.looked >= self.lookahead or not self.current:
            return False
        if len(self.current) + 2 > self.top:
            return False
        through = next(
            (
                (n, v)
                for n, v in stalled.ranked
                if _qualifies(self.by_name[n], v, self.value, 0.0, self.floor)
            ),
            None,
        )
        if through is None:
            return False
        self.looked += 1
        name, provisional = through
        current = {**self.current, name: stalled.best[name][1]}
        step = self._forward(current, provisional)
        if step is None:
            return False
        step.entry["through"] = name
        self.path.append(step.entry)
        if step.chosen is None:
            return False
        self.current = {**current, step.chosen: step.best[step.chosen][1]}
        self.value = step.measured
        return True

    def prune(self) -> bool:
        """Drop the chosen factor that matters least, if it no longer matters; whether one was.

        With fewer than two chosen there is nothing to weigh one against (a lone factor
        gives back all it closes), and no step is recorded.
        """
        if len(self.current) < 2:
            return False
        names = list(self.current)
        without = self.evaluate(
            [assignment({k: v for k, v in self.current.items() if k != n}) for n in names]
        )
        reset = {n: self.value.closure - v.closure for n, v in zip(names, without, strict=True)}
        least = min(names, key=lambda n: reset[n])
        dropped = least if reset[least] < self.gain else None
        self.path.append({"step": len(self.path) + 1, "reset": reset, "dropped": dropped})
        if dropped is None:
            return False
        self.dropped.append(dropped)
        self.current = {n: s for n, s in self.current.items() if n != dropped}
        self.value = without[names.index(dropped)]
        return True

    def _substitutes(
        self,
        current: dict[str, object],
        kept: list[tuple[str, Value]],
        best: dict[str, tuple[float, object]],
    ) -> list[str]:
        """The qualifying rivals the leader of a step cannot be told from (empty: add it).

        A rival is a qualifying addition whose closure the leader's does not beat by a
        group-bootstrap interval above 0. The leader is told from it only when, added on top of
        the rival, it still qualifies: it explains something the rival does not. Otherwise
        (a rival that shares its setting, or one that leaves the leader nothing to add) the
        data cannot say which of the two is at work, and naming the first in list order would
        be a guess.
        """
        if not kept:
            return []
        leader, lead = kept[0]
        rivals = [(n, v) for n, v in kept[1:] if _interval(lead.replicates - v.replicates)[0] <= 0]
        shared = [n for n, _ in rivals if self.by_name[n].setting == self.by_name[leader].setting]
        paired = [(n, v) for n, v in rivals if n not in shared]
        both = (
            self.evaluate(
                [assignment({**current, leader: best[leader][1], n: best[n][1]}) for n, _ in paired]
            )
            if paired
            else []
        )
        return shared + [
            n
            for (n, v), pair in zip(paired, both, strict=True)
            if not _qualifies(self.by_name[leader], pair, v, self.gain, self.floor)
        ]

    def _refit_step(self, runners: list[str]) -> tuple[dict, dict[str, object] | None, Value]:
        """Each runner added with every chosen strength refitted (one :func:`calibrate` round).

        A runner is added when it stays in the refitted assignment, that assignment qualifies
        against the current one (:func:`_qualifies`), and it can be told from every other runner
        that qualifies (a bootstrap interval of the difference above 0, or
        :func:`_kernel_apart`); otherwise the runners that cannot be told apart are tied.

        Returns:
            The path entry, the new strengths (``None``: nothing added) and their value.
        """
        fits = []
        for name in runners:
            factors = [
                dataclasses.replace(self.by_name[n], start=s) for n, s in self.current.items()
            ]
            factors.append(dataclasses.replace(self.by_name[name], start=self.gains[name][1]))
            fitted, measured, _ = calibrate(factors, self.evaluate, rounds=1)
            fits.append((name, dict(fitted), measured))
        step: dict = {
            "refit": {n: {k: _shown(v) for k, v in a.items()} for n, a, _ in fits},
            "measured": {n: v.closure for n, _, v in fits},
        }
        kept = sorted(
            (
                (n, a, v)
                for n, a, v in fits
                if n in a and _qualifies(self.by_name[n], v, self.value, self.gain, self.floor)
            ),
            key=lambda f: -f[2].closure,
        )
        if not kept:
            step["added"] = None
            return step, None, self.value
        leader, strengths, lead = kept[0]
        tied = [
            n
            for n, _, v in kept[1:]
            if _interval(lead.replicates - v.replicates)[0] <= 0 and not _kernel_apart(lead, v)
        ]
        if tied:
            step["added"], step["tied"] = None, [leader, *tied]
            return step, None, self.value
        step["added"] = leader
        return step, strengths, lead


def _kernel_apart(lead: Value, rival: Value) -> bool:
    """Whether the kernel distance tells a tied leader from a rival.

    It does when the leader removes at least
    :data:`~sim2real.diagnosis.scoring.CONFUSABLE_WITHIN` more of it, as the ranking orders a
    tie of classifier closures by the kernel distance.
    """
    if lead.kernel is None or rival.kernel is None:
        return False
    return lead.kernel - rival.kernel >= CONFUSABLE_WITHIN


def _qualifies(factor: Factor, measured: Value, current: Value, gain: float, floor: float) -> bool:
    """Whether the current assignment plus ``factor`` (``measured``) is a step of S*."""
    low, _ = _interval(measured.replicates - current.replicates)
    above = measured.closure > floor or not factor.simulated
    return measured.closure - current.closure >= gain and low > 0 and above


def _round_robin(
    estimates: dict[str, tuple[float, object]], stages: dict[str, str], count: int
) -> list[str]:
    """``count`` factors: each stage's best screened, then each stage's second, and so on.

    The screen adds features linearly, so it misjudges an effect whose change depends on
    another already in S* (a pose seen through defocus blur), most often across stages; a
    shortlist that spans the stages keeps such an effect in reach.
    """
    ranked = sorted(estimates, key=lambda n: -estimates[n][0])
    seen: dict[str, int] = {}
    place = {}
    for name in ranked:
        place[name] = seen.get(stages[name], 0)
        seen[stages[name]] = place[name] + 1
    return sorted(ranked, key=lambda n: (place[n], -estimates[n][0]))[:count]


def _interval(replicates: np.ndarray) -> tuple[float, float]:
    finite = replicates[np.isfinite(replicates)]
    if finite.size == 0:
        return (math.nan, math.nan)
    lo, hi = np.quantile(finite, [(1 - CI_LEVEL) / 2, (1 + CI_LEVEL) / 2])
    return (float(lo), float(hi))


@dataclasses.dataclass(frozen=True)
class JointFit:
    """The calibrated simulator S* and each factor's part of the gap it closes."""

    factors: dict[str, str]
    """Every factor fitted (name -> stage), in the order the ascent visited them."""
    strengths: dict[str, object]
    """The calibrated strengths of the factors that matter (the others are nominal; a
    switch's is ``None``, on)."""
    strength_interval: dict[str, tuple[float, float]]
    """Numeric factor -> its interval: the strengths outside it were told apart from the
    calibrated one (:func:`strength_intervals`)."""
    closure: float
    """Share of the gap S* closes."""
    closure_interval: tuple[float, float]
    rung_closure: dict[str, float]
    """Scored rung -> share of its divergence S* removes: where the rest of the gap lies."""
    reset: dict[str, float]
    """Factor -> share of the gap that returns when it alone is reset to nominal in S*."""
    reset_interval: dict[str, tuple[float, float]]
    shapley: dict[str, float]
    """Factor -> exact Shapley value of the closure over the factors that matter; they sum
    to :attr:`closure`."""
    shapley_interval: dict[str, tuple[float, float]]
    path: list[dict]
    """The selection's steps (:func:`select`), then the ascent's (:func:`calibrate`)."""
    sets: int
    """Distinct assignments scored."""
    tied: list[str] = dataclasses.field(default_factory=list)
    """Additions the selection could not tell apart and never chose: each closed the gap
    left as well as a rival, and neither added to the other."""
    floor: float = 0.0
    """Share of the gap a fresh nominal draw S' closes: how much sampling alone explains."""
    kernel_gap: bool = True
    """Whether the kernel distance lies above its floor on a scored rung; without it the gap
    is too weak to attribute and no factor is named (as for a single candidate,
    :func:`~sim2real.diagnosis.ranking.agrees`)."""

    @property
    def named(self) -> dict[str, object]:
        """The factors the answer names, with their strengths.

        Those of :attr:`strengths` when S* passes the open-set rule a single candidate must
        pass to be named: it closes at least
        :data:`~sim2real.diagnosis.ranking.OPEN_SET_MIN_CLOSURE` of the gap, and beats what
        a fresh nominal draw closes (:attr:`floor`) by
        :data:`~sim2real.diagnosis.ranking.OPEN_SET_MARGIN`, on a gap the kernel distance
        sees (:attr:`kernel_gap`). Else none: factors that close a little of a gap they leave
        mostly open, no more of it than sampling does, or a gap only the classifier sees, are
        reported, not named.
        """
        return dict(self.strengths) if self.kernel_gap and self.closure >= self.needed else {}

    @property
    def needed(self) -> float:
        """The closure S* needs for its factors to be named (:attr:`named`)."""
        return max(OPEN_SET_MIN_CLOSURE, self.floor + OPEN_SET_MARGIN)

    @property
    def unexplained(self) -> float:
        """Share of the gap S* leaves (1 - :attr:`closure`, at least 0)."""
        return max(0.0, 1.0 - self.closure)

    def stage_shares(self) -> dict[str, float]:
        """Stage -> share of the gap its factors close (Shapley values summed), largest first."""
        shares: dict[str, float] = {}
        for name, value in self.shapley.items():
            stage = self.factors[name]
            shares[stage] = shares.get(stage, 0.0) + value
        return dict(sorted(shares.items(), key=lambda kv: -kv[1]))

    def sentence(self) -> str:
        """The answer in words: the factors with their shares, then the unexplained rest."""
        tied = (
            f" ({', '.join(self.tied)} each close it as well as the others, and the data "
            "cannot tell which is at work)"
            if self.tied
            else ""
        )
        if not self.shapley:
            return (
                "no combination of candidates closes a share of the gap that matters"
                f" and can be told from the rest{tied}: "
                f"{100 * self.unexplained:.0f} % is unexplained"
            )
        parts = [
            f"{100 * v:.0f} % {self.factors[n]} ({n}"
            + ("" if self.strengths[n] is None else f" at {self.strengths[n]!r}")
            + ")"
            for n, v in sorted(self.shapley.items(), key=lambda kv: -kv[1])
        ]
        short = (
            ""
            if self.named
            else f" (below {100 * self.needed:.0f} %: no factor is named)"
            if self.kernel_gap
            else " (the kernel distance does not see the gap: no factor is named)"
        )
        return (
            f"the calibrated simulator closes {100 * self.closure:.0f} % of the gap{short}: "
            + ", ".join(parts)
            + f"; {100 * self.unexplained:.0f} % is unexplained{tied}"
        )

    def to_json(self) -> dict:
        """Plain JSON (strengths as given, intervals as lists)."""
        out = dataclasses.asdict(self)
        for key in ("reset_interval", "shapley_interval", "strength_interval"):
            out[key] = {k: list(v) for k, v in out[key].items()}
        out["closure_interval"] = list(self.closure_interval)
        out["unexplained"] = self.unexplained
        out["stage_shares"] = self.stage_shares()
        out["sentence"] = self.sentence()
        return out

    @classmethod
    def from_json(cls, data: dict) -> JointFit:
        """The fit :meth:`to_json` wrote."""

        def number(v) -> float:
            return math.nan if v is None else float(v)

        def pairs(values: dict) -> dict[str, tuple[float, float]]:
            return {k: (number(v[0]), number(v[1])) for k, v in values.items()}

        return cls(
            factors=dict(data["factors"]),
            strengths=dict(data["strengths"]),
            strength_interval=pairs(data.get("strength_interval", {})),
            closure=number(data["closure"]),
            rung_closure={k: number(v) for k, v in data.get("rung_closure", {}).items()},
            closure_interval=(
                number(data["closure_interval"][0]),
                number(data["closure_interval"][1]),
            ),
            reset={k: number(v) for k, v in data["reset"].items()},
            reset_interval=pairs(data["reset_interval"]),
            shapley={k: number(v) for k, v in data["shapley"].items()},
            shapley_interval=pairs(data["shapley_interval"]),
            path=list(data["path"]),
            sets=int(data["sets"]),
            tied=list(data.get("tied", [])),
            floor=number(data.get("floor", 0.0)),
            kernel_gap=bool(data.get("kernel_gap", True)),
        )


def attribute(
    calibrated: Assignment, value: Value, evaluate: Evaluate, *, matters: float = MATTERS
) -> tuple[dict, dict, dict, dict, Assignment, Value]:
    """Reset each factor of ``calibrated`` alone, keep those that matter, Shapley over them.

    Returns:
        (reset, reset intervals, Shapley values, Shapley intervals, the assignment of the
        factors that matter, its value).
    """
    strengths = dict(calibrated)
    alone = evaluate([assignment({**strengths, n: NOMINAL}) for n in strengths])
    reset = {n: value.closure - v.closure for n, v in zip(strengths, alone, strict=True)}
    reset_interval = {
        n: _interval(value.replicates - v.replicates) for n, v in zip(strengths, alone, strict=True)
    }
    kept = {n: s for n, s in strengths.items() if reset[n] >= matters}
    players = sorted(kept)
    coalitions = [
        frozenset(c) for k in range(len(players) + 1) for c in itertools.combinations(players, k)
    ]
    values = evaluate([assignment({n: kept[n] for n in c}) for c in coalitions])
    by_coalition = dict(zip(coalitions, values, strict=True))
    if not players:
        return reset, reset_interval, {}, {}, (), _nominal(len(value.replicates))
    point = shapley_values(players, {c: v.closure for c, v in by_coalition.items()})
    draws = np.stack(
        [
            list(
                shapley_values(
                    players, {c: float(v.replicates[b]) for c, v in by_coalition.items()}
                ).values()
            )
            for b in range(len(value.replicates))
        ]
    )
    intervals = {n: _interval(draws[:, i]) for i, n in enumerate(players)}  # players' order
    full = by_coalition[frozenset(players)]
    return reset, reset_interval, point, intervals, assignment(kept), full


def midpoint(a: float, b: float, *, log_scale: bool = False, integer: bool = False) -> float:
    """The strength halfway between ``a`` and ``b``: geometric on a log scale, else arithmetic."""
    mid = math.sqrt(a * b) if log_scale and a > 0 and b > 0 else 0.5 * (a + b)
    return round(mid) if integer else float(f"{mid:.6g}")


def _is_number(value) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def strength_intervals(
    factors: Sequence[Factor],
    calibrated: Assignment,
    value: Value,
    evaluate: Evaluate,
    *,
    refine: int = 0,
) -> dict[str, tuple[float, float]]:
    """Each numeric factor's interval: the strengths S* is not shown to be told apart from.

    A strength is told apart when S* (the others held) beats it by a group-bootstrap interval
    above 0. Among the tried strengths, those not told apart span ``[low, high]`` (with the
    calibrated one); the nearest told apart beyond each end bound the interval, so every
    strength outside it was told apart, while one inside may not have been tried (the
    ascent's grid is coarse). Each bound is then bisected ``refine`` times against its end
    (:func:`midpoint`; every factor's probes of one round are one batch). An end with no
    strength told apart beyond it is the last one tried. Switches and choices get none.
    """
    strengths = dict(calibrated)
    numeric = {}
    for f in factors:
        grid = sorted({o for o in f.options if _is_number(o)})
        if _is_number(strengths.get(f.name, NOMINAL)) and len(grid) >= 2:
            numeric[f.name] = grid
    by_name = {f.name: f for f in factors}

    def held(batch: list[tuple[str, float]]) -> list[bool]:
        values = evaluate([assignment({**strengths, n: s}) for n, s in batch])
        return [_interval(value.replicates - v.replicates)[0] <= 0 for v in values]

    grid = [(n, o) for n, options in numeric.items() for o in options]
    accepted = {(n, o) for (n, o), ok in zip(grid, held(grid), strict=True) if ok}
    # per factor: [low held, high held, told apart below (or None), told apart above]
    ends = {}
    for name, options in numeric.items():
        inside = [o for o in options if (name, o) in accepted] + [strengths[name]]
        low, high = min(inside), max(inside)
        below = [o for o in options if o < low]
        above = [o for o in options if o > high]
        ends[name] = [low, high, below[-1] if below else None, above[0] if above else None]
    for _ in range(refine):
        probes = []
        for name, (low, high, below, above) in ends.items():
            f = by_name[name]
            for side, inner, outer in ((0, low, below), (1, high, above)):
                if outer is None:
                    continue
                mid = midpoint(inner, outer, log_scale=f.log_scale, integer=f.integer)
                if mid != inner and mid != outer:
                    probes.append((name, side, mid))
        if not probes:
            break
        for (name, side, mid), ok in zip(probes, held([(n, m) for n, _, m in probes]), strict=True):
            ends[name][side if ok else side + 2] = mid
    return {
        n: (float(low if below is None else below), float(high if above is None else above))
        for n, (low, high, below, above) in ends.items()
    }


def fit_jointly(
    factors: Sequence[Factor],
    evaluate: Evaluate,
    *,
    screen: Screen | None = None,
    top: int = 0,
    verify: int = 4,
    floor: float = 0.0,
    rounds: int = 2,
    tolerance: float = JOINT_TOLERANCE,
    matters: float = MATTERS,
    interval_refine: int = 0,
    refit: int = 0,
    prune: int = 0,
    lookahead: int = 0,
) -> JointFit:
    """:func:`select` (with ``screen``), :func:`calibrate`, then :func:`attribute` at S*.

    Without ``screen`` every factor is calibrated from its start; with it ``factors`` is the
    pool :func:`select` draws at most ``top`` factors from, and the ascent refits those.
    ``evaluate`` is wrapped in a memo, so an assignment met twice (nominal in every batch,
    S* again during attribution) is scored once.
    """
    memo: dict[Assignment, Value] = {}

    def cached(batch: Iterable[Assignment]) -> list[Value]:
        batch = list(batch)
        todo = list(dict.fromkeys(a for a in batch if a not in memo))
        if todo:
            memo.update(zip(todo, evaluate(todo), strict=True))
        return [memo[a] for a in batch]

    path: list[dict] = []
    tied: list[str] = []
    if screen is not None:
        factors, _, _, path = select(
            factors,
            cached,
            screen,
            top=top,
            verify=verify,
            gain=matters,
            floor=floor,
            refit=refit,
            prune=prune,
            lookahead=lookahead,
        )
        chosen = {f.name for f in factors}
        tied = list(dict.fromkeys(n for step in path for n in step.get("tied", [])))
        tied = [n for n in tied if n not in chosen]
    calibrated, value, steps = calibrate(factors, cached, rounds=rounds, tolerance=tolerance)
    reset, reset_interval, shapley, shapley_interval, kept, full = attribute(
        calibrated, value, cached, matters=matters
    )
    intervals = strength_intervals(factors, kept, full, cached, refine=interval_refine)
    return JointFit(
        factors={f.name: f.stage for f in factors},
        strengths=dict(kept),
        strength_interval=intervals,
        closure=full.closure,
        closure_interval=_interval(full.replicates),
        rung_closure=dict(full.rungs),
        reset=reset,
        reset_interval=reset_interval,
        shapley=shapley,
        shapley_interval=shapley_interval,
        path=path + steps,
        sets=len(memo),
        tied=tied,
        floor=max(0.0, floor),
    )
