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

__all__ = [
    "NewtonSettings",
    "Objective",
    "StepStats",
    "direct_solve",
    "lu_solve",
    "newton_minimize",
    "sparse_lu_factors",
]


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
    linear_solver: str = "pcg"
    """``pcg`` (batched PCG, the default) or ``direct``: a sparse LU (SuperLU) per instance
    of the assembled block-sparse Hessian. Direct pays off for small, stiff 3D solids
    (near-incompressible tissue) where PCG needs hundreds of iterations per Newton step;
    it needs a model with a block-sparse pattern and reports 1 "CG iteration" per solve."""
    backend: str = "torch"
    """``torch`` (batched tensors; CPU and CUDA) or ``kernels``: compiled CPU kernels
    (:mod:`simulator.kernels`) for the cloth shell energies and the two-level PCG, each
    instance iterating on its own. Resolve ``auto`` with
    :func:`simulator.kernels.resolve_backend` first."""
    whole_step: bool = True
    """On ``kernels`` with the two-level PCG: run the whole Newton loop in one compiled call
    when every term besides the shell is a per-vertex quadratic (the wind scene without
    contact; :meth:`IncrementalPotential.vertex_quadratic`). Same arithmetic; ``False`` keeps
    the loop here (the reference of the tests)."""

    def __post_init__(self):
        for name in ("max_iters", "cg_max_iters", "check_every"):
            if getattr(self, name) < 1:
                raise ValueError(f"NewtonSettings.{name} must be >= 1, got {getattr(self, name)}")
        if self.preconditioner not in ("two_level", "jacobi"):
            raise ValueError(
                f"NewtonSettings.preconditioner must be 'two_level' or 'jacobi', "
                f"got {self.preconditioner!r}"
            )
        if self.backend not in ("torch", "kernels"):
            raise ValueError(
                f"NewtonSettings.backend must be 'torch' or 'kernels', got {self.backend!r}"
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
    whole = _whole_step_parts(objective, x0, settings, aggregates)
    if whole is not None:
        from ..kernels.bridge import minimize_whole

        x, (newton_iters, cg_total, max_update) = minimize_whole(
            objective.shell, whole, x0, free, settings, aggregates, objective.model.pattern
        )
        return x, StepStats(newton_iters, cg_total, max_update, max_update <= settings.tol_dx)
    batch = x0.shape[0]
    device = x0.device
    x = x0
    active = torch.ones(batch, dtype=torch.bool, device=device)
    newton_iters = torch.zeros(batch, dtype=torch.int64, device=device)
    cg_total = torch.zeros_like(newton_iters)
    max_update = torch.full((batch,), float("inf"), dtype=x0.dtype, device=device)
    eps = torch.finfo(x0.dtype).eps
    value = None
    for _ in range(settings.max_iters):
        grad = objective.gradient(x) * free
        matvec, diag, sparse = objective.hessian(x)
        if settings.line_search and value is None:
            # After the gradient: a fused objective has the value at x already.
            value = objective.value(x)

        def masked_matvec(v, matvec=matvec):
            return matvec(v * free) * free

        if settings.linear_solver == "direct":
            dx = direct_solve(sparse, matvec, -grad, free, active)
            cg_iters = active.long()
        elif (
            settings.backend == "kernels"
            and settings.preconditioner == "two_level"
            and aggregates is not None
            and _whole_in_pattern(matvec, sparse)
        ):
            from ..kernels.bridge import solve_two_level

            dx, cg_iters = solve_two_level(
                sparse,
                diag,
                aggregates,
                free,
                -grad,
                active,
                settings.cg_rtol,
                settings.cg_max_iters,
            )
        else:
            if (
                settings.preconditioner == "two_level"
                and aggregates is not None
                and sparse is not None
            ):
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


def _whole_step_parts(objective, x0, settings: NewtonSettings, aggregates) -> tuple | None:
    """The per-vertex quadratic of ``objective`` when the whole solve can run compiled."""
    if not (
        settings.backend == "kernels"
        and settings.whole_step
        and settings.linear_solver == "pcg"
        and settings.preconditioner == "two_level"
        and aggregates is not None
        and x0.device.type == "cpu"
    ):
        return None
    split = getattr(objective, "vertex_quadratic", None)
    return None if split is None else split(x0)


def _whole_in_pattern(matvec, sparse) -> bool:
    """Whether the Hessian lives wholly in the block-sparse matrix.

    Objectives return ``sparse.matvec`` itself as the product then; with terms outside the
    pattern (self-collision pairs) they return a wrapper, and the torch PCG solves.
    """
    return sparse is not None and matvec == sparse.matvec


def _coo_pattern(sparse) -> tuple:
    """Scalar (row, col) of every entry of the block-sparse values, cached on the pattern."""
    pattern = sparse.pattern
    cached = pattern._slot_cache.get("coo")
    if cached is not None:
        return cached
    cols = pattern.cols.cpu()
    verts, width = cols.shape
    i = torch.arange(3)
    rows = (3 * torch.arange(verts)[:, None, None, None] + i[None, None, :, None]).expand(
        verts, width, 3, 3
    )
    cc = (3 * cols[:, :, None, None] + i[None, None, None, :]).expand(verts, width, 3, 3)
    out = (rows.reshape(-1).numpy(), cc.reshape(-1).numpy())
    pattern._slot_cache["coo"] = out
    return out


def direct_solve(sparse, matvec, rhs: torch.Tensor, free: torch.Tensor, active: torch.Tensor):
    """Solve ``A dx = rhs`` per instance by sparse LU on the free degrees of freedom.

    Args:
        sparse: the assembled :class:`BlockSparse` Hessian (values (B, V, K, 3, 3)).
        matvec: the full Hessian product, used to check that ``sparse`` holds all of it.
        rhs: right-hand sides (B, V, 3), zero at constrained vertices.
        free: 1 for free, 0 for constrained vertices, (V, 1) or (B, V, 1).
        active: rows still iterating, bool (B,); the others get a zero update.
    """
    if sparse is None:
        raise ValueError("linear_solver='direct' needs a model with a block-sparse pattern")
    probe = torch.randn(rhs.shape, generator=torch.Generator().manual_seed(0)).to(rhs)
    full, part = matvec(probe), sparse.matvec(probe)
    if not torch.allclose(full, part, rtol=1e-8, atol=1e-12 * float(full.abs().max())):
        raise ValueError(
            "linear_solver='direct': the Hessian has terms outside the block-sparse pattern "
            "(e.g. contact pairs); use 'pcg'"
        )
    factors = sparse_lu_factors(sparse, free, active)
    return lu_solve(factors, rhs)


SPLU_OPTIONS: dict = {"SymmetricMode": True}
"""SuperLU options of the direct solver. Newton's Hessians are symmetric; symmetric mode (a
hint: pivoting still guards a nonsymmetric matrix) keeps the fill-reducing order on both sides
and cuts the factorisation, most of a fine mesh's drape (``python -m benchmarks.drape_bench``
against ``{}``, SuperLU's default)."""


def sparse_lu_factors(sparse, free: torch.Tensor, active: torch.Tensor | None = None) -> list:
    """SuperLU factors of each instance's free-dof block of a :class:`BlockSparse` matrix.

    Returns a list of ``(factor, dofs)`` per batch row (``None`` for inactive rows).
    """
    import numpy as np
    import scipy.sparse as sp
    from scipy.sparse.linalg import splu

    batch, verts = sparse.values.shape[:2]
    rows, cols = _coo_pattern(sparse)
    values = sparse.values.detach().cpu().double().numpy().reshape(batch, -1)
    free_b = free.expand(batch, verts, 1) if free.dim() == 2 else free
    free_np = free_b[..., 0].cpu().numpy() > 0
    act = np.ones(batch, dtype=bool) if active is None else active.cpu().numpy()
    out = []
    for b in range(batch):
        if not act[b]:
            out.append(None)
            continue
        dofs = np.nonzero(np.repeat(free_np[b], 3))[0]
        mat = sp.csc_matrix((values[b], (rows, cols)), shape=(3 * verts, 3 * verts))
        mat = mat[dofs][:, dofs].tocsc()
        out.append((splu(mat, permc_spec="MMD_AT_PLUS_A", options=SPLU_OPTIONS), dofs))
    return out


def lu_solve(factors: list, rhs: torch.Tensor) -> torch.Tensor:
    """Apply :func:`sparse_lu_factors` to right-hand sides (B, V, 3); zero elsewhere."""
    import numpy as np

    b_np = rhs.detach().cpu().double().numpy().reshape(rhs.shape[0], -1)
    out = np.zeros_like(b_np)
    for b, fac in enumerate(factors):
        if fac is not None:
            lu, dofs = fac
            out[b, dofs] = lu.solve(b_np[b, dofs])
    return torch.as_tensor(out, dtype=rhs.dtype, device=rhs.device).view_as(rhs)
