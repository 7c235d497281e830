"""Batched preconditioned conjugate gradients with a per-instance convergence mask."""

from __future__ import annotations

from collections.abc import Callable

import torch

__all__ = ["conjugate_gradient"]


def _dot(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return (a * b).flatten(1).sum(-1)


def conjugate_gradient(
    matvec: Callable[[torch.Tensor], torch.Tensor],
    rhs: torch.Tensor,
    precond: Callable[[torch.Tensor], torch.Tensor],
    *,
    rtol: float = 1e-4,
    max_iters: int = 200,
    check_every: int = 4,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Solve ``A x = rhs`` for B independent SPD systems at once.

    Instances stop updating once ``|r| <= rtol |rhs|``; the loop ends when all have
    converged (checked every ``check_every`` iterations, the only host sync) or
    after ``max_iters``.

    Args:
        matvec: ``A @ v`` for v of shape (B, ...).
        rhs: right-hand sides, shape (B, ...).
        precond: ``M^-1 @ r`` (SPD), same shape.
        rtol: relative residual tolerance.
        max_iters: iteration cap.
        check_every: iterations between convergence checks.

    Returns:
        ``(x, iterations (B,) int64, relative residual (B,))``.
    """
    x = torch.zeros_like(rhs)
    r = rhs.clone()
    z = precond(r)
    p = z.clone()
    rz = _dot(r, z)
    rhs_norm = torch.sqrt(_dot(rhs, rhs))
    tiny = torch.finfo(rhs.dtype).tiny
    active = rhs_norm > tiny
    iters = torch.zeros(rhs.shape[0], dtype=torch.int64, device=rhs.device)
    res = torch.where(active, torch.ones_like(rhs_norm), torch.zeros_like(rhs_norm))
    shape = (-1,) + (1,) * (rhs.dim() - 1)
    for it in range(max_iters):
        ap = matvec(p)
        pap = _dot(p, ap)
        alpha = torch.where(active & (pap > tiny), rz / pap.clamp_min(tiny), torch.zeros_like(rz))
        x = x + alpha.view(shape) * p
        r = r - alpha.view(shape) * ap
        iters = iters + active.long()
        res = torch.where(active, torch.sqrt(_dot(r, r)) / rhs_norm.clamp_min(tiny), res)
        active = active & (res > rtol)
        if (it + 1) % check_every == 0 and not bool(active.any()):
            break
        z = precond(r)
        rz_new = _dot(r, z)
        beta = torch.where(active, rz_new / rz.clamp_min(tiny), torch.zeros_like(rz))
        p = z + beta.view(shape) * p
        rz = rz_new
    return x, iters, res
