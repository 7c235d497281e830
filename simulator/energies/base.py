"""Energy protocol and the element-block Hessian used by the Newton/CG solver.

Every energy term gives, for the whole batch at once, its value ``(B,)``, its
gradient ``(B, V, 3)`` and an exact Hessian-vector product (autograd double
backward unless a subclass writes it analytically). For the solver it also
gives :class:`ElementBlocks`: small dense per-element Hessian blocks, projected
to be positive semi-definite so that conjugate gradients sees an SPD system.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import torch

from ..mesh import tensor_fields_to

if TYPE_CHECKING:
    from ..model import SimControl, SimModel

__all__ = ["ElementBlocks", "Energy", "autograd_hessian_product"]


@dataclasses.dataclass(frozen=True)
class ElementBlocks:
    """A sum of small dense blocks scattered into the (B*V*3)-dimensional system.

    Indices are flat vertex ids into ``pos.reshape(B * V, 3)``, so the same type
    holds shared-topology elements and per-instance pairs (contacts).
    """

    flat_indices: torch.Tensor
    """Flat vertex ids of each element, int64, shape (N, k)."""
    blocks: torch.Tensor
    """Symmetric element matrices in entry layout: block (a, b) of element n is
    ``blocks[n, a, b]`` (3 x 3), shape (N, k, k, 3, 3)."""
    topology: torch.Tensor | None = None
    """Shared element topology (N / B, k) when every instance has the same elements
    (blocks then run instance-major); lets the solver assemble a block-sparse matrix."""

    def matvec(self, vec_flat: torch.Tensor) -> torch.Tensor:
        """Product with a flat vector field of shape (B*V, 3); returns the same shape."""
        n, k = self.flat_indices.shape
        gathered = vec_flat[self.flat_indices].reshape(n, 3 * k, 1)
        dense = self.blocks.permute(0, 1, 3, 2, 4).reshape(n, 3 * k, 3 * k)
        prod = torch.bmm(dense, gathered).reshape(n * k, 3)
        out = torch.zeros_like(vec_flat)
        out.index_add_(0, self.flat_indices.reshape(-1), prod)
        return out

    def diagonal_blocks(self, flat_vert_count: int) -> torch.Tensor:
        """Per-vertex 3x3 diagonal blocks summed over elements, shape (B*V, 3, 3)."""
        n, k = self.flat_indices.shape
        diag = torch.diagonal(self.blocks, dim1=1, dim2=2).permute(0, 3, 1, 2).reshape(n * k, 3, 3)
        out = self.blocks.new_zeros(flat_vert_count, 3, 3)
        out.index_add_(0, self.flat_indices.reshape(-1), diag)
        return out


def autograd_hessian_product(
    energy_fn, model: SimModel, pos: torch.Tensor, dpos: torch.Tensor
) -> torch.Tensor:
    """Exact Hessian-vector product of ``energy_fn(model, pos).sum()`` by double backward."""
    with torch.enable_grad():
        x = pos.detach().requires_grad_(True)
        (grad,) = torch.autograd.grad(energy_fn(model, x).sum(), x, create_graph=True)
        (hvp,) = torch.autograd.grad((grad * dpos).sum(), x)
    return hvp


class Energy:
    """Base class of the conservative energy terms (potential energy [J])."""

    linear = False
    """Whether the energy is linear in the positions (constant gradient, no Hessian): such
    terms fold into the per-vertex quadratic of a step (:mod:`simulator.kernels.step`)."""

    def energy(self, model: SimModel, pos: torch.Tensor) -> torch.Tensor:
        """Energy of each instance [J], shape (B,). Must be differentiable in ``pos``."""
        raise NotImplementedError

    def gradient(self, model: SimModel, pos: torch.Tensor) -> torch.Tensor:
        """dE/dx [N], shape (B, V, 3); the default differentiates :meth:`energy`."""
        with torch.enable_grad():
            x = pos.detach().requires_grad_(True)
            (grad,) = torch.autograd.grad(self.energy(model, x).sum(), x)
        return grad

    def hessian_product(
        self, model: SimModel, pos: torch.Tensor, dpos: torch.Tensor
    ) -> torch.Tensor:
        """Exact d²E/dx² · dpos [N/m · m], shape (B, V, 3)."""
        return autograd_hessian_product(self.energy, model, pos, dpos)

    def hessian_blocks(self, model: SimModel, pos: torch.Tensor) -> ElementBlocks | None:
        """PSD approximation of the Hessian for Newton; ``None`` for linear energies."""
        return None

    def bind(self, model: SimModel, control: SimControl, pos: torch.Tensor) -> Energy:
        """The term for one step: obstacles from ``control``, candidate pairs from ``pos``."""
        return self

    def to(self, device=None, dtype=None):
        """Copy with every tensor field moved to ``device`` / ``dtype`` (floats only)."""
        return tensor_fields_to(self, device, dtype)


def psd_project_sym2(mat: torch.Tensor) -> torch.Tensor:
    """Clamp the eigenvalues of symmetric 2x2 matrices (..., 2, 2) at zero (closed form)."""
    a, b, d = mat[..., 0, 0], mat[..., 0, 1], mat[..., 1, 1]
    info = torch.finfo(mat.dtype)
    mean = 0.5 * (a + d)
    rad = torch.sqrt(0.25 * (a - d) ** 2 + b * b)
    lam1 = mean + rad
    lam2 = mean - rad
    # Eigenvector of lam1 is (b, lam1 - a) or (lam1 - d, b); pick the better-conditioned one.
    v1x = torch.where((a - d) >= 0, lam1 - d, b)
    v1y = torch.where((a - d) >= 0, b, lam1 - a)
    norm = torch.sqrt(v1x * v1x + v1y * v1y)
    # Isotropic (or zero) matrices: any frame is an eigenframe. Without this branch float32
    # gives 0/0 here for an unstressed flat cloth (a constant like 1e-300 rounds to 0).
    scale = a.abs() + d.abs() + b.abs()
    degenerate = norm <= 4 * info.eps * scale + info.tiny
    safe = torch.where(degenerate, torch.ones_like(norm), norm)
    cx = torch.where(degenerate, torch.ones_like(norm), v1x / safe)
    sy = torch.where(degenerate, torch.zeros_like(norm), v1y / safe)
    p1 = lam1.clamp_min(0.0)
    p2 = lam2.clamp_min(0.0)
    out = torch.empty_like(mat)
    out[..., 0, 0] = p1 * cx * cx + p2 * sy * sy
    out[..., 1, 1] = p1 * sy * sy + p2 * cx * cx
    out[..., 0, 1] = (p1 - p2) * cx * sy
    out[..., 1, 0] = out[..., 0, 1]
    return out
