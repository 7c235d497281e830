"""Velocity-dependent and non-conservative forces, linearised once per step.

A force is turned, at the start of each step, into a :class:`StepForce`
``f(v) = f_const - D (v - v_ref)`` with ``D`` symmetric positive semi-definite.
Backward Euler then treats the damping part implicitly through the
incremental potential ``h [1/2 (v - v_ref)^T D (v - v_ref) - f_const^T v]``
with ``v = (x - x_n) / h``, which keeps stiff drag and friction stable at
large steps, and the constant part explicitly.
"""

from __future__ import annotations

import dataclasses

import torch

from ..energies.base import ElementBlocks

__all__ = ["Force", "StepForce"]


@dataclasses.dataclass(frozen=True)
class StepForce:
    """One force frozen over one step."""

    damping_vertex: torch.Tensor | None = None
    """Per-vertex damping blocks [N·s/m], shape (B, V, 3, 3)."""
    damping_blocks: tuple[ElementBlocks, ...] = ()
    """Coupled damping as element blocks [N·s/m] (e.g. Rayleigh damping)."""
    v_ref: torch.Tensor | None = None
    """Velocity the damping pulls towards [m/s], shape (B, V, 3); zero if ``None``."""
    f_const: torch.Tensor | None = None
    """Explicit force [N], shape (B, V, 3)."""

    def damping_matvec(self, vec: torch.Tensor) -> torch.Tensor:
        """``D @ vec`` for a field of shape (B, V, 3)."""
        out = torch.zeros_like(vec)
        if self.damping_vertex is not None:
            out = out + (self.damping_vertex @ vec[..., None])[..., 0]
        for blocks in self.damping_blocks:
            out = out + blocks.matvec(vec.reshape(-1, 3)).view_as(vec)
        return out

    def damping_diagonal(self, batch: int, verts: int, like: torch.Tensor) -> torch.Tensor:
        """Per-vertex diagonal 3x3 blocks of ``D``, shape (B, V, 3, 3)."""
        out = like.new_zeros(batch, verts, 3, 3)
        if self.damping_vertex is not None:
            out = out + self.damping_vertex
        for blocks in self.damping_blocks:
            out = out + blocks.diagonal_blocks(batch * verts).view(batch, verts, 3, 3)
        return out

    def relative(self, vel: torch.Tensor) -> torch.Tensor:
        """``v - v_ref``."""
        return vel if self.v_ref is None else vel - self.v_ref

    def power_potential(self, vel: torch.Tensor) -> torch.Tensor:
        """``1/2 u^T D u - f_const^T v`` per instance [W], shape (B,)."""
        u = self.relative(vel)
        value = 0.5 * (u * self.damping_matvec(u)).sum(dim=(1, 2))
        if self.f_const is not None:
            value = value - (self.f_const * vel).sum(dim=(1, 2))
        return value

    def force(self, vel: torch.Tensor) -> torch.Tensor:
        """``f(v)`` [N], shape (B, V, 3)."""
        f = -self.damping_matvec(self.relative(vel))
        return f if self.f_const is None else f + self.f_const


class Force:
    """Base class: ``linearize`` returns the :class:`StepForce` for the coming step."""

    def linearize(self, model, state, control, energies) -> StepForce:
        """Freeze the force at the start-of-step ``state`` (``energies`` bound to this step)."""
        raise NotImplementedError

    def to(self, device=None, dtype=None):
        """Forces hold only Python scalars; nothing to move."""
        return self
