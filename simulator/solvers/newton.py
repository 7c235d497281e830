"""Batched Newton minimisation with PCG inner solves and a backtracking line search.

Used by both the backward-Euler step (incremental potential) and the static
equilibrium solve. Each instance converges on its own: finished rows stop
moving while the others continue; the loops only sync with the host to decide
whether everybody is done.
"""

from __future__ import annotations

import dataclasses
from typing import Protocol

import torch

from .cg import conjugate_gradient
from .coarse import TwoLevelPreconditioner

__all__ = ["NewtonSettings", "Objective", "StepStats", "newton_minimize"]


@dataclasses.dataclass(frozen=True)
class NewtonSettings:
    """Tolerances and caps of the Newton / CG solve."""

    max_iters: int = 4
    """Newton iterations per solve (per step for dynamics)."""
    tol_dx: float = 1e-6
    """Converged when the largest vertex update is below this [m]."""
    cg_rtol: float = 1e-3
    """Relative residual of each linear solve."""
    cg_max_iters: int = 100
    line_search: bool = True
    max_halvings: int = 8
    check_every: int = 4
    """CG iterations between convergence checks (host syncs)."""
    preconditioner: str = "two_level"
    """``two_level`` (block Jacobi + aggregation coarse solve, when the model has
    aggregates) or ``jacobi`` (3x3 block Jacobi)."""

    def __post_init__(self):
        for name in ("max_iters", "cg_max_iters", "check_every"):
            if getattr(self, name) < 1:
                raise ValueError(f"NewtonSettings.{name} must be >= 1, got {getattr(self, name)}")
        if self.preconditioner not in ("two_level", "jacobi"):
            raise ValueError(
                f"NewtonSettings.preconditioner must be 'two_level' or 'jacobi', "
                f"got {self.preconditioner!r}"
            )
        for name in ("tol_dx", "cg_rtol"):
            if not getattr(self, name) > 0:
                raise ValueError(f"NewtonSettings.{name} must be > 0, got {getattr(self, name)}")


@dataclasses.dataclass(frozen=True)
class StepStats:
    """Per-instance solver statistics of one solve."""

    newton_iters: torch.Tensor
    """Newton iterations used, int64, shape (B,)."""
    cg_iters: torch.Tensor
    """CG iterations summed over Newton iterations, int64, shape (B,)."""
    max_update: torch.Tensor
    """Largest vertex update of the last Newton iteration [m], shape (B,)."""
    converged: torch.Tensor
    """Whether ``max_update <= tol_dx``, bool, shape (B,)."""


class Objective(Protocol):
    """What :func:`newton_minimize` needs from a batched objective."""

    def value(self, x: torch.Tensor) -> torch.Tensor:
        """Objective per instance, shape (B,)."""

    def gradient(self, x: torch.Tensor) -> torch.Tensor:
        """Gradient, shape (B, V, 3)."""

    def hessian(self, x: torch.Tensor):
        """``(matvec, diag_blocks (B, V, 3, 3), BlockSparse | None)`` of an SPD approximation."""


def newton_minimize(
    objective: Objective,
    x0: torch.Tensor,
    free: torch.Tensor,
    settings: NewtonSettings,
    *,
    aggregates: torch.Tensor | None = None,
) -> tuple[torch.Tensor, StepStats]:
    """Minimise ``objective`` over the free vertices, starting from ``x0`` (B, V, 3).

    Args:
        objective: batched objective.
        x0: start, with constrained vertices already at their values.
        free: 1 for free, 0 for constrained vertices, shape (V, 1) or (B, V, 1).
        settings: tolerances.
        aggregates: coarse aggregate per vertex (V,), enabling the two-level preconditioner.
    """
    batch = x0.shape[0]
    device = x0.device
    x = x0
    active = torch.ones(batch, dtype=torch.bool, device=device)
    newton_iters = torch.zeros(batch, dtype=torch.int64, device=device)
    cg_total = torch.zeros_like(newton_iters)
    max_update = torch.full((batch,), float("inf"), dtype=x0.dtype, device=device)
    eps = torch.finfo(x0.dtype).eps
    value = objective.value(x) if settings.line_search else None
    for _ in range(settings.max_iters):
        grad = objective.gradient(x) * free
        matvec, diag, sparse = objective.hessian(x)

        def masked_matvec(v, matvec=matvec):
            return matvec(v * free) * free

        if settings.preconditioner == "two_level" and aggregates is not None and sparse is not None:
            precond = TwoLevelPreconditioner.build(sparse, diag, aggregates, free)
        else:
            diag_inv = torch.linalg.inv(diag)

            def precond(r, diag_inv=diag_inv):
                return (diag_inv @ r[..., None])[..., 0] * free

        dx, cg_iters, _ = conjugate_gradient(
            masked_matvec,
            -grad,
            precond,
            rtol=settings.cg_rtol,
            max_iters=settings.cg_max_iters,
            check_every=settings.check_every,
        )
        dx = dx * active.view(-1, 1, 1)
        alpha = torch.ones(batch, dtype=x0.dtype, device=device)
        if settings.line_search:
            slope = (grad * dx).flatten(1).sum(-1)
            pending = active.clone()
            trial_value = value
            for _ in range(settings.max_halvings):
                trial_value = objective.value(x + alpha.view(-1, 1, 1) * dx)
                slack = 16 * eps * value.abs()
                ok = trial_value <= value + 1e-4 * alpha * slope + slack
                pending = pending & ~ok
                if not bool(pending.any()):
                    break
                alpha = torch.where(pending, 0.5 * alpha, alpha)
            value = torch.where(active, trial_value, value)
        step = alpha.view(-1, 1, 1) * dx
        x = x + step
        newton_iters = newton_iters + active.long()
        cg_total = cg_total + cg_iters * active.long()
        update = torch.linalg.vector_norm(step, dim=-1).amax(dim=-1)
        max_update = torch.where(active, update, max_update)
        active = active & (max_update > settings.tol_dx)
        if not bool(active.any()):
            break
    stats = StepStats(newton_iters, cg_total, max_update, max_update <= settings.tol_dx)
    return x, stats
