"""Per-frame static solve of the reconstruction problem (the paper eq. 20), two linear solvers.

``min_x sum E(x)`` (elastic + bending + image fitting) with the boundary vertices held at
their known positions (eq. 19). Each frame is warm-started from the previous frame's
solution, so 1-3 Newton iterations suffice. The Newton system is assembled from the
energies' PSD element blocks into the core's fixed-pattern block-sparse matrix; it is then
solved either by the core's batched PCG (:func:`simulator.solvers.newton.newton_minimize`) or,
for the small single-view problem, by a sparse direct LU of the free-DOF matrix whose
structure (CSR indices and the scatter map from element blocks) is built once per mesh.
Direct is the default: measured ~4x faster per frame at 1,600 elements on one core
(``python -m benchmarks.thesis.paper_table1`` writes both).
"""

from __future__ import annotations

import dataclasses
import enum

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import torch

from ..solvers.block_sparse import BlockPattern, BlockSparse
from ..solvers.newton import NewtonSettings, StepStats, newton_minimize

__all__ = ["LinearSolverKind", "SparseDirectSystem", "StaticPotential", "solve_frame"]


class LinearSolverKind(enum.StrEnum):
    """How the Newton systems are solved."""

    DIRECT = "direct"
    PCG = "pcg"


@dataclasses.dataclass(frozen=True)
class StaticPotential:
    """Sum of energies with a small Levenberg shift, as a Newton objective (core protocol)."""

    model: object
    """A :class:`simulator.model.SimModel` (mesh, pattern; masses unused)."""
    energies: tuple
    regularization: float = 1e-6
    """Diagonal shift [N/m] keeping the system SPD at zero-stiffness modes."""

    def value(self, x):
        """Potential [J], shape (B,)."""
        return sum(e.energy(self.model, x) for e in self.energies)

    def gradient(self, x):
        """Gradient [N], shape (B, V, 3)."""
        return sum(e.gradient(self.model, x) for e in self.energies)

    def assemble(self, x) -> BlockSparse:
        """PSD Hessian approximation as un-finalised block-sparse matrices (B of them)."""
        batch = x.shape[0]
        sparse = BlockSparse.zeros(self.model.pattern, batch, x)
        for energy in self.energies:
            b = energy.hessian_blocks(self.model, x)
            if b is None:
                continue
            if b.topology is None:
                raise ValueError(f"{type(energy).__name__}: blocks need a shared topology")
            n = b.topology.shape[0]
            sparse.add_elements(b.topology, b.blocks.view(batch, n, *b.blocks.shape[1:]))
        eye = torch.eye(3, dtype=x.dtype, device=x.device)
        sparse.add_vertex_blocks(x.new_full((batch, x.shape[1], 1, 1), self.regularization) * eye)
        return sparse

    def hessian(self, x):
        """``(matvec, diag_blocks, sparse)`` as :func:`newton_minimize` expects."""
        sparse = self.assemble(x)
        diag = sparse.diagonal()
        sparse = sparse.finalize()
        return sparse.matvec, diag, sparse


class SparseDirectSystem:
    """Free-DOF scalar CSR structure of a block pattern, the map that fills it, and its solver.

    Solves use a sparse LU (SuperLU, minimum-degree ordering) of the free-DOF matrix. With
    ``reuse_factor`` the last factorisation is kept and used as the preconditioner of
    conjugate gradients on the *current* matrix; it is refreshed only when PCG misses
    ``rtol`` within ``max_pcg_iters`` iterations. Between nearby frames the Hessian changes
    little, so most solves cost a few triangular solves instead of a factorisation.
    """

    def __init__(
        self,
        pattern: BlockPattern,
        free: torch.Tensor,
        *,
        reuse_factor: bool = True,
        rtol: float = 1e-5,
        max_pcg_iters: int = 15,
    ):
        """Precompute CSR indices for the vertices with ``free`` (V,) true."""
        cols = pattern.cols.cpu().numpy()
        verts, width = cols.shape
        free_np = free.cpu().numpy().astype(bool)
        dof = np.full(verts, -1)
        dof[free_np] = np.arange(int(free_np.sum()))
        # Padding slots repeat the row itself after its real diagonal slot: drop them.
        rows_v = np.repeat(np.arange(verts), width).reshape(verts, width)
        first = np.argmax(cols == rows_v, axis=1)
        real = ~((cols == rows_v) & (np.arange(width)[None] != first[:, None]))
        keep_slot = real & free_np[rows_v] & free_np[cols]
        r_v, s_v = np.nonzero(keep_slot)
        c_v = cols[r_v, s_v]
        comp = np.arange(3)
        rr = (3 * dof[r_v])[:, None, None] + comp[None, :, None]
        cc = (3 * dof[c_v])[:, None, None] + comp[None, None, :]
        rr, cc = np.broadcast_arrays(rr, cc)
        flat = (
            (r_v * width + s_v)[:, None, None] * 9 + comp[None, :, None] * 3 + comp[None, None, :]
        )
        n = 3 * int(free_np.sum())
        order = np.lexsort((cc.ravel(), rr.ravel()))
        self.source = torch.as_tensor(flat.ravel()[order])
        """Flat entry of ``values[b].reshape(-1)`` feeding each CSR slot, int64 (nnz,)."""
        self.indices = cc.ravel()[order].astype(np.int32)
        self.indptr = np.searchsorted(rr.ravel()[order], np.arange(n + 1)).astype(np.int32)
        self.size = n
        self.free_vertices = torch.as_tensor(np.nonzero(free_np)[0])
        self.reuse_factor = reuse_factor
        self.rtol = rtol
        self.max_pcg_iters = max_pcg_iters
        self.factorizations = 0
        """Number of LU factorisations so far (for benchmarks)."""
        self._lu = None

    def reset(self) -> None:
        """Forget the kept factorisation (start of a new sequence)."""
        self._lu = None

    def matrix(self, values: torch.Tensor) -> sp.csr_matrix:
        """CSR matrix of one instance's block values (V, K, 3, 3)."""
        data = values.reshape(-1)[self.source].numpy()
        return sp.csr_matrix((data, self.indices, self.indptr), shape=(self.size, self.size))

    def _factor(self, mat: sp.csr_matrix):
        self.factorizations += 1
        # The matrix is symmetric, so its CSR arrays read as CSC are the same matrix.
        csc = sp.csc_matrix((mat.data, mat.indices, mat.indptr), shape=mat.shape)
        self._lu = spla.splu(
            csc, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True}
        )

    def _pcg(self, mat: sp.csr_matrix, b: np.ndarray) -> np.ndarray | None:
        """CG preconditioned by the kept LU; None if it misses rtol in max_pcg_iters."""
        x = np.zeros_like(b)
        r = b.copy()
        b_norm = np.linalg.norm(b)
        if b_norm == 0.0:
            return x
        z = self._lu.solve(r)
        p = z.copy()
        rz = r @ z
        for _ in range(self.max_pcg_iters):
            ap = mat @ p
            alpha = rz / (p @ ap)
            x += alpha * p
            r -= alpha * ap
            if np.linalg.norm(r) <= self.rtol * b_norm:
                return x
            z = self._lu.solve(r)
            rz_new = r @ z
            p = z + (rz_new / rz) * p
            rz = rz_new
        return None

    def solve(self, values: torch.Tensor, rhs: torch.Tensor) -> torch.Tensor:
        """Solve ``A dx = rhs`` over the free vertices; rhs and result (V, 3)."""
        mat = self.matrix(values)
        b = rhs[self.free_vertices].reshape(-1).numpy()
        sol = None
        if self.reuse_factor and self._lu is not None:
            sol = self._pcg(mat, b)
        if sol is None:
            self._factor(mat)
            sol = self._lu.solve(b)
        out = torch.zeros_like(rhs)
        out[self.free_vertices] = torch.as_tensor(sol).view(-1, 3).to(rhs)
        return out


def _newton_direct(objective, x0, free, system: SparseDirectSystem, settings: NewtonSettings):
    """Newton with a sparse direct solve and a backtracking (Armijo) line search per instance."""
    x = x0.clone()
    batch = x.shape[0]
    iters = torch.zeros(batch, dtype=torch.int64)
    update = torch.full((batch,), float("inf"), dtype=x.dtype)
    value = objective.value(x)
    for _ in range(settings.max_iters):
        grad = objective.gradient(x) * free
        values = objective.assemble(x).values
        dx = torch.stack([system.solve(values[b], -grad[b]) for b in range(batch)])
        slope = (grad * dx).flatten(1).sum(-1)
        alpha = torch.ones(batch, dtype=x.dtype)
        trial = value
        for _ in range(settings.max_halvings if settings.line_search else 1):
            trial = objective.value(x + alpha.view(-1, 1, 1) * dx)
            bad = trial > value + 1e-4 * alpha * slope + 16 * torch.finfo(x.dtype).eps * value.abs()
            if not settings.line_search or not bool(bad.any()):
                break
            alpha = torch.where(bad, 0.5 * alpha, alpha)
        step = alpha.view(-1, 1, 1) * dx
        x = x + step
        value = trial
        iters += 1
        update = torch.linalg.vector_norm(step, dim=-1).amax(-1)
        if bool((update <= settings.tol_dx).all()):
            break
    zeros = torch.zeros(batch, dtype=torch.int64)
    return x, StepStats(iters, zeros, update, update <= settings.tol_dx)


def solve_frame(
    objective: StaticPotential,
    x0: torch.Tensor,
    free: torch.Tensor,
    settings: NewtonSettings,
    *,
    solver: LinearSolverKind = LinearSolverKind.DIRECT,
    system: SparseDirectSystem | None = None,
) -> tuple[torch.Tensor, StepStats]:
    """Minimise ``objective`` from ``x0`` (B, V, 3) with vertices where ``free`` (V, 1) is 0 fixed.

    ``system`` (built once per mesh and boundary set) is required for the direct solver.
    """
    solver = LinearSolverKind(solver)
    if solver is LinearSolverKind.PCG:
        return newton_minimize(
            objective, x0, free, settings, aggregates=getattr(objective.model, "aggregates", None)
        )
    if system is None:
        raise ValueError("system: the direct solver needs a SparseDirectSystem")
    return _newton_direct(objective, x0, free, system, settings)
