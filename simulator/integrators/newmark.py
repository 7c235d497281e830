"""Implicit Newmark integration as minimisation of an incremental potential (*thesis* §4.2.2).

Newmark's scheme with parameters ``beta``, ``gamma``::

    x_{n+1} = x_n + h v_n + h² ((1/2 - beta) a_n + beta a_{n+1})
    v_{n+1} = v_n + h ((1 - gamma) a_n + gamma a_{n+1}),   M a_{n+1} = f(x_{n+1}, v_{n+1})

is, for conservative forces, the stationarity condition of
``1/(2 beta h²) |x - x_pred|²_M + E(x)`` with ``x_pred = x_n + h v_n + (1/2 - beta) h² a_n``,
so it runs on the same :class:`IncrementalPotential` and Newton solver as backward Euler
(inertial time scale ``h sqrt(beta)``). The linearised damping forces act at ``v_{n+1}``,
which is affine in ``x`` with slope ``gamma / (beta h)``. The default average-acceleration
rule (beta = 1/4, gamma = 1/2, the trapezoidal rule) is second-order accurate, unconditionally
stable and conserves the energy of linear undamped systems; backward Euler is first order and
damps. The acceleration is carried in :attr:`SimState.acc`; a state without one gets it from
the equations of motion at the start of the first step.
"""

from __future__ import annotations

import dataclasses
import math

import torch

from ..model import SimModel, SimState
from .base import IncrementalPotential, Integrator, minimize_pinned

__all__ = ["IntegratorNewmark"]


@dataclasses.dataclass(frozen=True)
class IntegratorNewmark(Integrator):
    """Newmark-beta integrator on the shared Newton core; pure ``step`` like backward Euler."""

    beta: float = 0.25
    """Displacement weight of the end-of-step acceleration, in [gamma / 2, 1/2]."""
    gamma: float = 0.5
    """Velocity weight of the end-of-step acceleration, in [1/2, 2 beta]; > 1/2 damps."""

    def __post_init__(self):
        beta, gamma = self.beta, self.gamma
        if not 0.5 <= gamma <= 1.0:
            raise ValueError(
                f"IntegratorNewmark.gamma must lie in [0.5, 1] (below 0.5 the scheme amplifies "
                f"energy), got {gamma}"
            )
        if not 0.5 * gamma <= beta <= 0.5:
            raise ValueError(
                f"IntegratorNewmark.beta must lie in [gamma / 2, 0.5] = [{0.5 * gamma}, 0.5] "
                f"(unconditional stability; beta = 0 is explicit), got {beta}"
            )

    @staticmethod
    def acceleration(
        model: SimModel, state: SimState, energies: tuple, forces: tuple
    ) -> torch.Tensor:
        """``M^-1 f(x_n, v_n)`` [m/s²], shape (B, V, 3); zero at pinned vertices."""
        force = -sum(e.gradient(model, state.pos) for e in energies)
        for f in forces:
            force = force + f.force(state.vel)
        return force / model.vert_mass[..., None] * model.free_mask()

    def advance(self, model, state, control, dt, energies, step_forces, settings):
        """Newmark step from the step's bound energies and forces; the result carries ``acc``."""
        beta, gamma = self.beta, self.gamma
        acc = state.acc
        if acc is None:
            acc = self.acceleration(model, state, energies, step_forces)
        x_pred = state.pos + dt * state.vel + (0.5 - beta) * dt * dt * acc
        v_pred = state.vel + (1.0 - gamma) * dt * acc
        # v_{n+1} = v_pred + (x - x_pred) / h_v = (x - x_zero) / h_v with h_v = beta h / gamma.
        h_v = beta * dt / gamma
        x_zero = x_pred - h_v * v_pred
        objective = IncrementalPotential(
            model,
            energies,
            step_forces,
            x_zero,
            x_pred,
            dt * math.sqrt(beta),
            velocity_dt=h_v,
        )
        # Start from a_{n+1} = a_n.
        x, stats = minimize_pinned(
            model, objective, x_pred + beta * dt * dt * acc, control, settings
        )
        acc_new = (x - x_pred) / (beta * dt * dt)
        vel = v_pred + gamma * dt * acc_new
        return SimState(pos=x, vel=vel, time=state.time + dt, acc=acc_new), stats
