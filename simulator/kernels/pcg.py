"""Compiled kernels of the linear solve: coarse Galerkin matrix and per-instance two-level PCG.

The same algorithm as :func:`simulator.solvers.cg.conjugate_gradient` with the additive
:class:`simulator.solvers.coarse.TwoLevelPreconditioner` (block-Jacobi smoother plus an
aggregation coarse solve), but each instance runs its own loop in one thread and stops on its
own test: no instance waits for the slowest, and there is no host sync.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

__all__ = [
    "coarse_envelope",
    "coarse_factor",
    "coarse_factor_one",
    "coarse_matrix",
    "coarse_matrix_one",
    "pcg_one",
    "pcg_two_level",
]


@njit(cache=True, error_model="numpy")
def coarse_envelope(cols, agg, n_agg):
    """First possibly nonzero column of each coarse row (3A,): the matrix's envelope.

    Aggregates are numbered along the grid, so each coarse row couples only to nearby
    aggregates; the Cholesky factor stays inside this envelope, and factorisation and
    substitutions skip the zeros outside it (measured: a quarter of the dense lower triangle
    on the 32x32 cloth, about 18x fewer factorisation flops).
    """
    first = 3 * (np.arange(3 * n_agg) // 3)  # an aggregate's own 3x3 block
    for i in range(cols.shape[0]):
        ai = agg[i]
        for k in range(cols.shape[1]):
            aj = agg[cols[i, k]]
            if aj < ai:
                for d in range(3):
                    first[3 * ai + d] = min(first[3 * ai + d], 3 * aj)
    return first


@njit(cache=True, error_model="numpy")
def coarse_matrix_one(values, cols, agg, free, out):
    """Add one instance's ``P^T A P`` over free vertices into ``out`` (3A, 3A)."""
    verts, width = values.shape[0], values.shape[1]
    for i in range(verts):
        if free[i] == 0.0:
            continue
        ai = 3 * agg[i]
        for k in range(width):
            j = cols[i, k]
            if free[j] == 0.0:
                continue
            aj = 3 * agg[j]
            for d in range(3):
                for e in range(3):
                    out[ai + d, aj + e] += values[i, k, d, e]


@njit(cache=True, parallel=True, error_model="numpy")
def coarse_matrix(values, cols, agg, free, n_agg):
    """``Ac = P^T A P`` over free vertices, dofs ordered (aggregate, axis), (B, 3A, 3A).

    Args:
        values: ELL blocks (B, V, K, 3, 3) [N/m].
        cols: neighbour of each slot, (V, K).
        agg: aggregate of each vertex, (V,).
        free: 1 for free, 0 for pinned, (B, V).
        n_agg: A.
    """
    batch = values.shape[0]
    out = np.zeros((batch, 3 * n_agg, 3 * n_agg))
    for b in prange(batch):
        coarse_matrix_one(values[b], cols, agg, free[b], out[b])
    return out


@njit(cache=True, error_model="numpy")
def _cholesky(mat, first, out) -> bool:
    """Lower Cholesky factor of the lower triangle of ``mat`` into ``out``; False if not SPD.

    ``first`` is the envelope (:func:`coarse_envelope`): entries left of it are zero in
    ``mat`` and stay zero in the factor. Written out rather than LAPACK's, so that no BLAS
    thread pool runs inside numba's threads.
    """
    n = mat.shape[0]
    out[:] = 0.0
    for j in range(n):
        acc = mat[j, j]
        for k in range(first[j], j):
            acc -= out[j, k] * out[j, k]
        if not acc > 0.0:
            return False
        d = np.sqrt(acc)
        out[j, j] = d
        for i in range(j + 1, n):
            if first[i] > j:
                continue
            acc = mat[i, j]
            for k in range(max(first[i], first[j]), j):
                acc -= out[i, k] * out[j, k]
            out[i, j] = acc / d
    return True


@njit(cache=True, error_model="numpy")
def coarse_factor_one(coarse, first, agg, free, out):
    """Lower Cholesky factor of one coarse matrix (3A, 3A) into ``out``, made safely SPD first.

    As :func:`simulator.solvers.coarse._spd_inverse`: aggregates without a free vertex get an
    identity-scaled block, every diagonal a relative shift of 16 ulps, and a matrix whose
    factorisation still fails a 1e-6 relative shift. ``coarse`` is overwritten.
    """
    n = coarse.shape[0]
    eps = np.finfo(np.float64).eps
    count = np.zeros(n // 3)
    for i in range(agg.shape[0]):
        count[agg[i]] += free[i]
    scale = 1e-30
    for p in range(n):
        scale = max(scale, abs(coarse[p, p]))
    for p in range(n):
        coarse[p, p] += ((1.0 if count[p // 3] <= 0 else 0.0) + 16 * eps) * scale
    if not _cholesky(coarse, first, out):
        for p in range(n):
            coarse[p, p] += 1e-6 * scale
        _cholesky(coarse, first, out)


@njit(cache=True, parallel=True, error_model="numpy")
def coarse_factor(coarse, first, agg, free):
    """Lower Cholesky factors of the coarse matrices (B, 3A, 3A) (:func:`coarse_factor_one`)."""
    out = np.empty_like(coarse)
    for b in prange(coarse.shape[0]):
        coarse_factor_one(coarse[b].copy(), first, agg, free[b], out[b])
    return out


@njit(cache=True, inline="always")
def _coarse_solve(factor, first, rc, ec):
    """``ec = (L L^T)^-1 rc`` by forward and back substitution inside the envelope."""
    n = rc.shape[0]
    for p in range(n):
        acc = rc[p]
        for q in range(first[p], p):
            acc -= factor[p, q] * ec[q]
        ec[p] = acc / factor[p, p]
    for p in range(n - 1, -1, -1):
        ec[p] /= factor[p, p]
        for q in range(first[p], p):
            ec[q] -= factor[p, q] * ec[p]


@njit(cache=True, inline="always")
def _invert3(m, out):
    """Inverse of a 3x3 matrix by cofactors."""
    c00 = m[1, 1] * m[2, 2] - m[1, 2] * m[2, 1]
    c01 = m[1, 2] * m[2, 0] - m[1, 0] * m[2, 2]
    c02 = m[1, 0] * m[2, 1] - m[1, 1] * m[2, 0]
    inv_det = 1.0 / (m[0, 0] * c00 + m[0, 1] * c01 + m[0, 2] * c02)
    out[0, 0] = c00 * inv_det
    out[1, 0] = c01 * inv_det
    out[2, 0] = c02 * inv_det
    out[0, 1] = (m[0, 2] * m[2, 1] - m[0, 1] * m[2, 2]) * inv_det
    out[1, 1] = (m[0, 0] * m[2, 2] - m[0, 2] * m[2, 0]) * inv_det
    out[2, 1] = (m[0, 1] * m[2, 0] - m[0, 0] * m[2, 1]) * inv_det
    out[0, 2] = (m[0, 1] * m[1, 2] - m[0, 2] * m[1, 1]) * inv_det
    out[1, 2] = (m[0, 2] * m[1, 0] - m[0, 0] * m[1, 2]) * inv_det
    out[2, 2] = (m[0, 0] * m[1, 1] - m[0, 1] * m[1, 0]) * inv_det


@njit(cache=True, inline="always")
def _precondition(r, z, rc, ec, diag_inv, agg, factor, first, free):
    """``z = D^-1 r + P Ac^-1 P^T r`` on free vertices (additive two-level)."""
    verts = r.shape[0]
    rc[:] = 0.0
    for i in range(verts):
        if free[i] == 0.0:
            z[i, 0] = z[i, 1] = z[i, 2] = 0.0
            continue
        a = 3 * agg[i]
        for d in range(3):
            rc[a + d] += r[i, d]
            z[i, d] = (
                diag_inv[i, d, 0] * r[i, 0]
                + diag_inv[i, d, 1] * r[i, 1]
                + diag_inv[i, d, 2] * r[i, 2]
            )
    _coarse_solve(factor, first, rc, ec)
    for i in range(verts):
        if free[i] != 0.0:
            a = 3 * agg[i]
            for d in range(3):
                z[i, d] += ec[a + d]


@njit(cache=True, inline="always")
def _matvec(values, cols, free, p, out):
    """``out = A (p * free) * free`` for one instance's ELL matrix."""
    verts, width = values.shape[0], values.shape[1]
    for i in range(verts):
        s0 = s1 = s2 = 0.0
        if free[i] != 0.0:
            for k in range(width):
                j = cols[i, k]
                w = free[j]
                p0, p1, p2 = p[j, 0] * w, p[j, 1] * w, p[j, 2] * w
                blk = values[i, k]
                s0 += blk[0, 0] * p0 + blk[0, 1] * p1 + blk[0, 2] * p2
                s1 += blk[1, 0] * p0 + blk[1, 1] * p1 + blk[1, 2] * p2
                s2 += blk[2, 0] * p0 + blk[2, 1] * p1 + blk[2, 2] * p2
        out[i, 0], out[i, 1], out[i, 2] = s0, s1, s2


@njit(cache=True, error_model="numpy")
def pcg_one(values, cols, diag, agg, factor, first, free, rhs, x, rtol, max_iters):
    """Solve one instance's ``A x = rhs`` with additive two-level PCG, from ``x = 0``.

    Arguments as :func:`pcg_two_level`, for one instance; ``x`` (V, 3) is overwritten.
    Returns ``(iterations, relative residual)``.
    """
    verts = rhs.shape[0]
    tiny = np.finfo(np.float64).tiny
    n_coarse = factor.shape[0]
    x[:] = 0.0
    diag_inv = np.empty((verts, 3, 3))
    for i in range(verts):
        _invert3(diag[i], diag_inv[i])
    r = rhs.copy()
    z = np.empty((verts, 3))
    ap = np.empty((verts, 3))
    rc = np.empty(n_coarse)
    ec = np.empty(n_coarse)
    rhs_norm = math.sqrt(np.sum(r * r))
    if not rhs_norm > tiny:
        return 0, 0.0
    _precondition(r, z, rc, ec, diag_inv, agg, factor, first, free)
    p = z.copy()
    rz = np.sum(r * z)
    res = 1.0
    iters = 0
    for _ in range(max_iters):
        _matvec(values, cols, free, p, ap)
        pap = np.sum(p * ap)
        alpha = rz / pap if pap > tiny else 0.0
        rr = 0.0
        for i in range(verts):
            for d in range(3):
                x[i, d] += alpha * p[i, d]
                r[i, d] -= alpha * ap[i, d]
                rr += r[i, d] * r[i, d]
        iters += 1
        res = math.sqrt(rr) / rhs_norm
        if res <= rtol:
            break
        _precondition(r, z, rc, ec, diag_inv, agg, factor, first, free)
        rz_new = np.sum(r * z)
        beta = rz_new / rz if rz > tiny else 0.0
        for i in range(verts):
            for d in range(3):
                p[i, d] = z[i, d] + beta * p[i, d]
        rz = rz_new
    return iters, res


@njit(cache=True, parallel=True, error_model="numpy")
def pcg_two_level(values, cols, diag, agg, factor, first, free, rhs, active, rtol, max_iters):
    """Solve ``A x = rhs`` per instance with additive two-level PCG (:func:`pcg_one`).

    Args:
        values: ELL blocks (B, V, K, 3, 3).
        cols: neighbour of each slot (V, K).
        diag: diagonal blocks (B, V, 3, 3) (the smoother inverts them).
        agg: aggregate of each vertex (V,).
        factor: coarse Cholesky factors (B, 3A, 3A) from :func:`coarse_factor`.
        first: their envelope (3A,) from :func:`coarse_envelope`.
        free: 1 for free, 0 for pinned (B, V).
        rhs: right-hand sides (B, V, 3), zero at pinned vertices.
        active: instances to solve (B,) bool; the others get zero.
        rtol: relative residual tolerance.
        max_iters: iteration cap.

    Returns:
        ``(x (B, V, 3), iterations (B,) int64, relative residual (B,))``.
    """
    batch = rhs.shape[0]
    x = np.zeros_like(rhs)
    iters = np.zeros(batch, dtype=np.int64)
    res = np.zeros(batch)
    for b in prange(batch):
        if active[b]:
            iters[b], res[b] = pcg_one(
                values[b],
                cols,
                diag[b],
                agg,
                factor[b],
                first,
                free[b],
                rhs[b],
                x[b],
                rtol,
                max_iters,
            )
    return x, iters, res
