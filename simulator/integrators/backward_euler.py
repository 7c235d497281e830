"""Implicit (backward) Euler as minimisation of the incremental potential.

``x_{n+1} = argmin 1/(2h²) |x - x_n - h v_n|²_M + E(x) + h Psi_n(v)``, with the
elastic, gravity and contact energies ``E`` and the per-step linearised
damping/drag potentials ``Psi_n``; ``v_{n+1} = (x_{n+1} - x_n) / h``. Pinned
vertices follow ``control.pin_pos`` exactly (Dirichlet). The step is pure: it
never mutates its inputs.
"""

from __future__ import annotations

import dataclasses

import torch

from ..model import SimControl, SimModel, SimState
from ..solvers.newton import NewtonSettings, StepStats
from .base import (
    IncrementalPotential,
    Integrator,
    bind_energies,
    minimize_pinned,
    split_for_backend,
)

__all__ = ["IntegratorBackwardEuler", "solve_static"]


@dataclasses.dataclass(frozen=True)
class IntegratorBackwardEuler(Integrator):
    """First-order implicit integrator; unconditionally stable, numerically damped."""

    def advance(self, model, state, control, dt, energies, step_forces, settings):
        """Backward-Euler step from the step's bound energies and forces."""
        x_pred = state.pos + dt * state.vel
        shell, energies = split_for_backend(settings.backend, model, energies)
        objective = IncrementalPotential(
            model, energies, step_forces, state.pos, x_pred, dt, shell=shell
        )
        x, stats = minimize_pinned(model, objective, x_pred, control, settings)
        vel = (x - state.pos) / dt
        return SimState(pos=x, vel=vel, time=state.time + dt), stats


def solve_static(
    model: SimModel,
    state: SimState,
    control: SimControl,
    *,
    settings: NewtonSettings | None = None,
    regularization: float = 1e-9,
) -> tuple[SimState, StepStats]:
    """Static equilibrium: minimise the potential energy with pins held at ``control``.

    Velocity-dependent forces play no part. ``regularization`` [N/m] is a small
    diagonal shift that keeps the Newton system SPD at zero-stiffness modes.
    """
    settings = settings or NewtonSettings(
        max_iters=50, tol_dx=1e-9, cg_rtol=1e-6, cg_max_iters=1000
    )
    energies = bind_energies(model, control, state.pos)
    shell, energies = split_for_backend(settings.backend, model, energies)
    objective = IncrementalPotential(
        model, energies, (), state.pos, state.pos, None, regularization=regularization, shell=shell
    )
    x, stats = minimize_pinned(model, objective, state.pos, control, settings)
    return dataclasses.replace(state, pos=x, vel=torch.zeros_like(x), acc=None), stats
