"""The particle swarm optimiser of *thesis* §3.2.2.6 (an SPSO-2011 variant, Clerc 2012).

* Adaptive random topology: every particle informs itself and ``K`` = 3 particles drawn at
  random; the links are re-drawn after an iteration that did not improve the swarm's best.
* Velocity from a hypersphere around the centre of gravity
  ``G = x + c (p + l - 2x) / 3`` (``G = x + c (p - x) / 2`` when the particle is its own
  best informant): ``x' ~ U(H(G, |G - x|))``, ``v <- w v + x' - x``, ``x <- x + v``,
  with ``w = 1 / (2 ln 2)``, ``c = 1/2 + ln 2`` (*thesis* eqs. 3.17-3.19).
* Bounds: the search runs in the unit box (each parameter scaled by its range); a particle
  leaving it is put back on the boundary and that velocity component is halved and reversed.
* The objective is called once per iteration with the whole swarm, ``f(x (S, D)) -> (S,)``,
  so a swarm of forward simulations is one batch of instances.

Pure numpy/torch and deterministic for a given seed.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np
import torch

__all__ = ["PSO_C", "PSO_W", "PSOResult", "ParticleSwarm", "pso_minimize"]

PSO_W = 1.0 / (2.0 * math.log(2.0))
"""Inertia weight w = 1 / (2 ln 2)."""
PSO_C = 0.5 + math.log(2.0)
"""Acceleration constant c = 1/2 + ln 2."""


@dataclasses.dataclass(frozen=True)
class PSOResult:
    """Outcome of :func:`pso_minimize`."""

    best_x: np.ndarray
    """Best position found, shape (D,)."""
    best_f: float
    """Objective at ``best_x``."""
    iterations: int
    """Swarm iterations run (objective calls)."""
    evaluations: int
    """Objective evaluations (iterations x swarm size)."""
    history: np.ndarray
    """Best objective after each iteration, shape (iterations,)."""
    best_x_history: np.ndarray
    """Best position after each iteration, shape (iterations, D)."""


class ParticleSwarm:
    """Ask/tell PSO state (see the module docstring for the update rules)."""

    def __init__(
        self,
        lower: np.ndarray | list[float],
        upper: np.ndarray | list[float],
        *,
        swarm_size: int = 40,
        informants: int = 3,
        seed: int = 0,
        inertia: float = PSO_W,
        acceleration: float = PSO_C,
    ):
        lo = np.asarray(lower, dtype=np.float64).reshape(-1)
        hi = np.asarray(upper, dtype=np.float64).reshape(-1)
        if lo.shape != hi.shape or lo.size == 0:
            raise ValueError(
                f"bounds: lower and upper must be non-empty with equal shapes, got "
                f"{lo.shape} and {hi.shape}"
            )
        if not (np.isfinite(lo).all() and np.isfinite(hi).all()):
            raise ValueError("bounds: lower and upper must be finite")
        if np.any(lo >= hi):
            d = int(np.argmax(lo >= hi))
            raise ValueError(
                f"bounds: lower[{d}] = {lo[d]} must be < upper[{d}] = {hi[d]} (min >= max)"
            )
        if swarm_size < 2:
            raise ValueError(f"swarm_size must be >= 2, got {swarm_size}")
        if not 1 <= informants < swarm_size:
            raise ValueError(f"informants must lie in [1, swarm_size), got {informants}")
        self.lower, self.upper = lo, hi
        self.dim, self.size, self.k = lo.size, int(swarm_size), int(informants)
        self.w, self.c = float(inertia), float(acceleration)
        self.rng = np.random.default_rng(seed)
        self.x = self.rng.uniform(0.0, 1.0, (self.size, self.dim))
        self.v = self.rng.uniform(-self.x, 1.0 - self.x)
        self.p = self.x.copy()
        self.pf = np.full(self.size, np.inf)
        self.links = self._draw_links()
        self.best_f = np.inf
        self._told = False

    def _draw_links(self) -> np.ndarray:
        """``links[i, j]``: particle j informs particle i (each informs itself and K others)."""
        links = np.eye(self.size, dtype=bool)
        targets = self.rng.integers(0, self.size, (self.size, self.k))
        links[targets.ravel(), np.repeat(np.arange(self.size), self.k)] = True
        return links

    def _scale(self, unit: np.ndarray) -> np.ndarray:
        return self.lower + unit * (self.upper - self.lower)

    def ask(self) -> np.ndarray:
        """Positions to evaluate, in the original units, shape (S, D)."""
        return self._scale(self.x)

    def tell(self, values: np.ndarray) -> None:
        """Feed the objective at :meth:`ask`'s positions (S,) and move the swarm."""
        f = np.asarray(values, dtype=np.float64).reshape(-1)
        if f.shape != (self.size,):
            raise ValueError(f"values must have shape ({self.size},), got {f.shape}")
        f = np.where(np.isfinite(f), f, np.inf)
        better = f < self.pf
        self.p[better], self.pf[better] = self.x[better], f[better]
        prev_best = self.best_f
        self.best_f = float(self.pf.min())
        if not self.best_f < prev_best:
            self.links = self._draw_links()
        # Best informant of each particle.
        masked = np.where(self.links, self.pf[None, :], np.inf)
        informant = np.argmin(masked, axis=1)
        local = self.p[informant]
        own = informant == np.arange(self.size)
        x = self.x
        centre = np.where(
            own[:, None],
            x + self.c * (self.p - x) / 2.0,
            x + self.c * (self.p + local - 2.0 * x) / 3.0,
        )
        radius = np.linalg.norm(centre - x, axis=1)
        direction = self.rng.normal(size=(self.size, self.dim))
        direction /= np.linalg.norm(direction, axis=1, keepdims=True).clip(1e-300)
        r = radius * self.rng.uniform(0.0, 1.0, self.size) ** (1.0 / self.dim)
        sample = centre + r[:, None] * direction
        self.v = self.w * self.v + sample - x
        x_new = x + self.v
        out = (x_new < 0.0) | (x_new > 1.0)
        self.x = np.clip(x_new, 0.0, 1.0)
        self.v = np.where(out, -0.5 * self.v, self.v)
        self._told = True

    @property
    def best_x(self) -> np.ndarray:
        """Best position found so far, in the original units, shape (D,)."""
        return self._scale(self.p[int(np.argmin(self.pf))])

    def spread(self) -> float:
        """Largest distance of a personal best from the best one, in unit-box coordinates."""
        best = self.p[int(np.argmin(self.pf))]
        return float(np.linalg.norm(self.p - best, axis=1).max())


def pso_minimize(
    objective: Callable[[np.ndarray], np.ndarray | torch.Tensor],
    lower: np.ndarray | list[float],
    upper: np.ndarray | list[float],
    *,
    swarm_size: int = 40,
    informants: int = 3,
    max_iters: int = 200,
    seed: int = 0,
    f_target: float | None = None,
    x_tol: float | None = None,
    patience: int | None = None,
    callback: Callable[[int, ParticleSwarm], None] | None = None,
) -> PSOResult:
    """Minimise a batched objective with the *thesis* PSO variant.

    Args:
        objective: ``f(x (S, D)) -> (S,)``, the whole swarm in one call.
        lower: lower bounds, shape (D,).
        upper: upper bounds (> lower), shape (D,).
        swarm_size: S (thesis: 40).
        informants: K (thesis: 3).
        max_iters: iteration cap.
        seed: RNG seed (same seed, same result).
        f_target: stop once the best value is <= this.
        x_tol: stop once every personal best lies within ``x_tol`` of the best one
            (unit-box coordinates, i.e. relative to each parameter's range).
        patience: stop after this many iterations without improving the best value.
        callback: called as ``callback(iteration, swarm)`` after each iteration.

    Raises:
        ValueError: for bounds with min >= max (names the dimension), bad sizes.
    """
    swarm = ParticleSwarm(lower, upper, swarm_size=swarm_size, informants=informants, seed=seed)
    history, xs = [], []
    stale, best = 0, np.inf
    it = 0
    for it in range(1, max_iters + 1):
        values = objective(swarm.ask())
        if isinstance(values, torch.Tensor):
            values = values.detach().cpu().double().numpy()
        swarm.tell(values)
        history.append(swarm.best_f)
        xs.append(swarm.best_x)
        if callback is not None:
            callback(it, swarm)
        stale = stale + 1 if not swarm.best_f < best else 0
        best = min(best, swarm.best_f)
        if f_target is not None and swarm.best_f <= f_target:
            break
        if x_tol is not None and swarm.spread() <= x_tol:
            break
        if patience is not None and stale >= patience:
            break
    return PSOResult(
        swarm.best_x, swarm.best_f, it, it * swarm.size, np.asarray(history), np.asarray(xs)
    )
