"""Integrator protocol and the incremental-potential objective shared by the solvers."""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import torch

from ..energies.base import ElementBlocks
from ..solvers.block_sparse import BlockSparse
from ..solvers.newton import NewtonSettings, StepStats, newton_minimize

if TYPE_CHECKING:
    from ..model import SimControl, SimModel, SimState

__all__ = [
    "IncrementalPotential",
    "Integrator",
    "SimulationDiverged",
    "begin_step",
    "bind_energies",
    "minimize_pinned",
    "split_for_backend",
    "with_pins",
]


class SimulationDiverged(RuntimeError):
    """A rollout produced NaN/inf or a velocity beyond the bound (names instance and step)."""


def bind_energies(model, control, pos: torch.Tensor) -> tuple:
    """The model's energies bound to one step (obstacles, candidate pairs at ``pos``)."""
    return tuple(e.bind(model, control, pos) for e in model.energies)


def begin_step(model, state, control, dt: float) -> tuple[tuple, tuple]:
    """Check ``dt`` [s]; the step's bound energies and forces linearised at ``state``."""
    if not dt > 0:
        raise ValueError(f"dt must be > 0 s, got {dt}")
    energies = bind_energies(model, control, state.pos)
    step_forces = tuple(f.linearize(model, state, control, energies) for f in model.forces)
    return energies, step_forces


def split_for_backend(backend: str, model, energies: tuple) -> tuple:
    """``(shell, energies)``: on ``kernels`` the compiled membrane + bending terms are split off.

    ``shell`` is ``None`` on ``torch`` or when the model has no shell to compile.
    """
    if backend != "kernels":
        return None, energies
    from ..kernels.bridge import split_shell

    return split_shell(model, energies)


def with_pins(model, pos: torch.Tensor, control) -> torch.Tensor:
    """``pos`` (B, V, 3) with the pinned vertices moved to ``control.pin_pos``."""
    if model.pin_indices.numel() == 0:
        return pos
    out = pos.clone()
    out[:, model.pin_indices] = control.pin_pos.to(pos)
    return out


def minimize_pinned(model, objective, start: torch.Tensor, control, settings):
    """Newton minimiser of ``objective`` from ``start`` (B, V, 3) [m], pins held at ``control``.

    Returns the positions [m], shape (B, V, 3), and the solver's ``StepStats``.
    """
    return newton_minimize(
        objective,
        with_pins(model, start, control),
        model.free_mask(),
        settings,
        aggregates=model.aggregates,
    )


@dataclasses.dataclass(frozen=True)
class Integrator:
    """An implicit integrator on the shared Newton core, with a pure ``step``."""

    settings: NewtonSettings = dataclasses.field(default_factory=NewtonSettings)
    """Newton and CG settings of a ``step`` given none."""

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
        energies, step_forces = begin_step(model, state, control, dt)
        return self.advance(
            model, state, control, dt, energies, step_forces, settings or self.settings
        )

    def advance(
        self,
        model: SimModel,
        state: SimState,
        control: SimControl,
        dt: float,
        energies: tuple,
        step_forces: tuple,
        settings: NewtonSettings,
    ) -> tuple[SimState, StepStats]:
        """The step itself, given the step's bound energies and linearised forces."""
        raise NotImplementedError


@dataclasses.dataclass(frozen=True)
class IncrementalPotential:
    """``1/(2h²)|x - x_pred|²_M + sum E(x) + h_v sum_f [1/2 u^T D u - f^T v]``.

    The velocity is ``v = (x - x_start) / h_v``; backward Euler has ``h_v = h = dt`` and
    ``x_start = x_n``, Newmark other (affine) choices (see :mod:`.newmark`). With
    ``dt = None`` it is the static potential ``sum E(x)`` (plus a tiny Levenberg shift for
    SPD-ness), used for equilibrium solves.
    """

    model: object
    energies: tuple
    step_forces: tuple
    x_start: torch.Tensor
    """Where the step's velocity is zero (backward Euler: the start of the step) [m],
    shape (B, V, 3)."""
    x_pred: torch.Tensor
    """Inertial prediction ``x_n + h v_n`` [m], shape (B, V, 3)."""
    dt: float | None
    regularization: float = 0.0
    """Levenberg shift [N/m] added to the Hessian diagonal (static solves)."""
    velocity_dt: float | None = None
    """``h_v`` [s] of ``v = (x - x_start) / h_v``; ``None`` means ``dt``."""
    shell: object | None = None
    """Compiled membrane + bending terms (:class:`simulator.kernels.bridge.ShellKernel`) on the
    ``kernels`` backend; ``energies`` then holds only the other terms."""

    def _mass(self) -> torch.Tensor:
        return self.model.vert_mass[..., None]

    def _velocity_dt(self) -> float:
        return self.dt if self.velocity_dt is None else self.velocity_dt

    def value(self, x):
        """Objective per instance, shape (B,)."""
        total = sum(e.energy(self.model, x) for e in self.energies)
        if self.shell is not None:
            total = total + self.shell.value(x)
        if self.dt is None:
            return total
        h = self.dt
        total = total + 0.5 / (h * h) * (self._mass() * (x - self.x_pred) ** 2).sum(dim=(1, 2))
        hv = self._velocity_dt()
        vel = (x - self.x_start) / hv
        for f in self.step_forces:
            total = total + hv * f.power_potential(vel)
        return total

    def gradient(self, x):
        """Gradient [N], shape (B, V, 3)."""
        grad = sum(e.gradient(self.model, x) for e in self.energies)
        if self.shell is not None:
            grad = grad + self.shell.gradient(x, self.model.pattern.cols.shape[1])
        if self.dt is None:
            return grad
        h = self.dt
        grad = grad + self._mass() / (h * h) * (x - self.x_pred)
        vel = (x - self.x_start) / self._velocity_dt()
        for f in self.step_forces:
            grad = grad - f.force(vel)
        return grad

    def vertex_quadratic(self, x0):
        """``(Q (B, V, 3, 3), z (B, V, 3), g (B, V, 3), const (B,))`` of all but the shell.

        When the other terms are inertia, linear energies (gravity, dead loads) and forces with
        per-vertex damping only, they add up to ``1/2 y^T Q y - g^T y + const`` with
        ``y = x - z`` and 3x3 blocks on the diagonal, and the whole Newton solve can run in one
        compiled call (:mod:`simulator.kernels.step`). The centre ``z`` is the inertial
        prediction, so the values stay small and the line search compares them without
        cancellation. ``None`` for static solves, without a compiled shell, and with any other
        term (contact, self-collision, element-coupled damping). ``x0`` is unused by
        the quadratic terms but evaluates the linear energies.
        """
        if self.dt is None or self.shell is None:
            return None
        if not all(e.linear for e in self.energies):
            return None
        if any(f.damping_blocks for f in self.step_forces):
            return None
        batch, verts = x0.shape[:2]
        h = self.dt
        centre = self.x_pred.expand(batch, verts, 3)
        eye = torch.eye(3, dtype=x0.dtype, device=x0.device)
        # The same sums, in the same order, as hessian()'s diagonal.
        quad = (self._mass() / (h * h))[..., None] * eye
        quad = quad.expand(batch, verts, 3, 3)
        force = torch.zeros_like(centre)
        const = centre.new_zeros(batch)
        for e in self.energies:
            grad = e.gradient(self.model, x0).expand(batch, verts, 3)
            force = force - grad
            const = const + e.energy(self.model, x0) + (grad * (centre - x0)).sum(dim=(1, 2))
        hv = self._velocity_dt()
        inv_h = 1.0 / hv
        vel = (centre - self.x_start) / hv
        for f in self.step_forces:
            if f.damping_vertex is not None:
                quad = quad + inv_h * f.damping_vertex
            force = force + f.force(vel)
            const = const + hv * f.power_potential(vel)
        return quad, centre, force, const

    def hessian(self, x):
        """``(matvec, diag_blocks (B, V, 3, 3), block_sparse | None)`` of the SPD approximation."""
        batch, verts = x.shape[:2]
        eye = torch.eye(3, dtype=x.dtype, device=x.device)
        if self.dt is None:
            diag = x.new_full((batch, verts, 1, 1), self.regularization) * eye
        else:
            diag = (self._mass() / (self.dt * self.dt))[..., None] * eye
        pattern = self.model.pattern
        if self.shell is not None:
            # The kernel's fresh ELL array becomes the matrix; the other terms add into it.
            sparse = BlockSparse(pattern, self.shell.hessian_values(x, pattern.cols.shape[1]))
        else:
            sparse = BlockSparse.zeros(pattern, batch, x) if pattern is not None else None
        loose: list[ElementBlocks] = []
        for energy in self.energies:
            b = energy.hessian_blocks(self.model, x)
            if b is None:
                continue
            if sparse is not None and b.topology is not None:
                n = b.topology.shape[0]
                sparse.add_elements(b.topology, b.blocks.view(batch, n, *b.blocks.shape[1:]))
            elif sparse is not None and b.flat_indices.shape[1] == 1:
                # Per-vertex blocks (capsule contact) belong on the diagonal.
                sparse.add_vertex_blocks(b.diagonal_blocks(batch * verts).view(batch, verts, 3, 3))
            else:
                loose.append(b)
        forces = self.step_forces if self.dt is not None else ()
        inv_h = 0.0 if self.dt is None else 1.0 / self._velocity_dt()
        for f in forces:
            if f.damping_vertex is not None:
                diag = diag + inv_h * f.damping_vertex
            for b in f.damping_blocks:
                scaled = dataclasses.replace(b, blocks=inv_h * b.blocks)
                if sparse is not None and b.topology is not None:
                    n = b.topology.shape[0]
                    sparse.add_elements(
                        b.topology, scaled.blocks.view(batch, n, *b.blocks.shape[1:])
                    )
                else:
                    loose.append(scaled)
        if sparse is not None:
            sparse.add_vertex_blocks(diag)
            full_diag = sparse.diagonal()
        else:
            full_diag = diag
        for b in loose:
            full_diag = full_diag + b.diagonal_blocks(batch * verts).view(batch, verts, 3, 3)

        # Vertices without any stiffness (static solve, pinned) keep an invertible block.
        full_diag = (
            full_diag + (full_diag.diagonal(dim1=-2, dim2=-1).sum(-1) <= 0)[..., None, None] * eye
        )
        if sparse is not None and not loose:
            return sparse.matvec, full_diag, sparse

        def matvec(v):
            out = sparse.matvec(v) if sparse is not None else (diag @ v[..., None])[..., 0]
            flat = v.reshape(-1, 3)
            for b in loose:
                out = out + b.matvec(flat).view_as(v)
            return out

        return matvec, full_diag, sparse
