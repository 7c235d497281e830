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
from ..solvers.newton import NewtonSettings, StepStats, newton_minimize
from .base import IncrementalPotential, begin_step, bind_energies, split_for_backend, with_pins

__all__ = ["IntegratorBackwardEuler", "solve_static"]


@dataclasses.dataclass(frozen=True)
class IntegratorBackwardEuler:
    """First-order implicit integrator; unconditionally stable, numerically damped."""

    settings: NewtonSettings = dataclasses.field(default_factory=NewtonSettings)

    def step(
        self,
        model: SimModel,
        state: SimState,
        control: SimControl,
        dt: float,
        *,
        settings: NewtonSettings | None = None,
    ) -> tuple[SimState, StepStats]:
        """Advance every instance by ``dt`` [s]."""
        settings = settings or self.settings
        energies, step_forces = begin_step(model, state, control, dt)
        x_pred = state.pos + dt * state.vel
        shell, energies = split_for_backend(settings.backend, model, energies)
        objective = IncrementalPotential(
            model, energies, step_forces, state.pos, x_pred, dt, shell=shell
        )
        x0 = with_pins(model, x_pred, control)
        x, stats = newton_minimize(
            objective, x0, model.free_mask(), settings, aggregates=model.aggregates
        )
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
    x, stats = newton_minimize(
        objective,
        with_pins(model, state.pos, control),
        model.free_mask(),
        settings,
        aggregates=model.aggregates,
    )
    return dataclasses.replace(state, pos=x, vel=torch.zeros_like(x), acc=None), stats
