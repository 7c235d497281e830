"""Compiled kernel of a whole Newton solve of the cloth's incremental potential.

When every term besides the membrane and bending is a per-vertex quadratic over the step
(inertia, gravity, the linearised air forces and their damping), the potential is
``shell(x) + 1/2 y^T Q y - g^T y + const`` with ``y = x - z`` (``z`` the inertial prediction)
and 3x3 blocks ``Q_i`` on the diagonal. Then the whole Newton loop (fused element pass, coarse
factor, two-level PCG, backtracking line search) runs as one call, each instance in its own
thread and with its own iteration counts, with the arithmetic of
:func:`simulator.solvers.newton.newton_minimize`; no torch operation and no host sync inside
a step.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .pcg import coarse_factor_one, coarse_matrix_one, pcg_one
from .shell import _shell_instance

__all__ = ["newton_whole"]


@njit(cache=True, inline="always")
def _quadratic(x, quad, centre, force, grad, values, diag_slots, want):
    """``1/2 y^T Q y - g^T y`` (``y = x - z``) of one instance; ``want`` adds its derivatives."""
    total = 0.0
    for i in range(x.shape[0]):
        q = quad[i]
        y0, y1, y2 = x[i, 0] - centre[i, 0], x[i, 1] - centre[i, 1], x[i, 2] - centre[i, 2]
        q0 = q[0, 0] * y0 + q[0, 1] * y1 + q[0, 2] * y2
        q1 = q[1, 0] * y0 + q[1, 1] * y1 + q[1, 2] * y2
        q2 = q[2, 0] * y0 + q[2, 1] * y1 + q[2, 2] * y2
        total += 0.5 * (q0 * y0 + q1 * y1 + q2 * y2) - (
            force[i, 0] * y0 + force[i, 1] * y1 + force[i, 2] * y2
        )
        if want:
            grad[i, 0] += q0 - force[i, 0]
            grad[i, 1] += q1 - force[i, 1]
            grad[i, 2] += q2 - force[i, 2]
            slot = diag_slots[i]
            for d in range(3):
                for e in range(3):
                    values[slot, d, e] += q[d, e]
    return total


@njit(cache=True, parallel=True, error_model="numpy")
def newton_whole(x0, quad, centre, force, const, free, geometry, params, solve, newton):
    """Minimise ``shell(x) + 1/2 y^T Q y - g^T y + const`` (``y = x - z``) per instance.

    Args:
        x0: start (B, V, 3) [m], pinned vertices at their values.
        quad: per-vertex blocks Q (B, V, 3, 3) [N/m].
        centre: z (B, V, 3) [m].
        force: g, the other terms' force at ``z`` (B, V, 3) [N].
        const: their value at ``z`` (B,) [J] (only the line search's round-off slack sees it).
        free: 1 for free, 0 for pinned (B, V).
        geometry: the shell's shared arrays, as :func:`.shell.shell_assemble` takes them.
        params: each instance's material, as :func:`.shell.shell_assemble` takes them.
        solve: ``(cols (V, K), diag_slots (V,), agg (V,), first (3A,), A)``: the ELL
            neighbours, each row's diagonal slot, the aggregates, the coarse envelope
            (:func:`.pcg.coarse_envelope`) and the aggregate count.
        newton: ``(max_iters, tol_dx, cg_rtol, cg_max_iters, line_search, max_halvings)`` of
            :class:`simulator.solvers.NewtonSettings`.

    Returns:
        ``(x (B, V, 3), Newton iterations (B,), CG iterations (B,), last max update (B,))``.
    """
    row0, fibres, samples, cumulative = params
    cols, diag_slots, agg, first, n_agg = solve
    max_iters, tol_dx, cg_rtol, cg_max_iters, line_search, max_halvings = newton
    batch, verts, width = x0.shape[0], x0.shape[1], cols.shape[1]
    x = x0.copy()
    newton_iters = np.zeros(batch, dtype=np.int64)
    cg_iters = np.zeros(batch, dtype=np.int64)
    max_update = np.full(batch, np.inf)
    eps = np.finfo(np.float64).eps
    for b in prange(batch):
        xb, fb = x[b], free[b]
        grad = np.empty((verts, 3))
        flat = np.empty((verts * width, 3, 3))
        values = flat.reshape((verts, width, 3, 3))
        diag = np.empty((verts, 3, 3))
        coarse = np.empty((3 * n_agg, 3 * n_agg))
        factor = np.empty((3 * n_agg, 3 * n_agg))
        rhs = np.empty((verts, 3))
        dx = np.empty((verts, 3))
        trial = np.empty((verts, 3))
        no_grad = np.empty((1, 3))
        no_values = np.empty((1, 3, 3))
        value = 0.0
        have_value = False
        for _ in range(max_iters):
            grad[:] = 0.0
            flat[:] = 0.0
            energy = _shell_instance(
                xb, geometry, row0[b], fibres[b], samples[b], cumulative[b], True, grad, flat
            )
            energy += _quadratic(xb, quad[b], centre[b], force[b], grad, flat, diag_slots, True)
            if line_search and not have_value:
                value = energy + const[b]
                have_value = True
            for i in range(verts):
                for d in range(3):
                    grad[i, d] *= fb[i]
                    rhs[i, d] = -grad[i, d]
                trace = 0.0
                for d in range(3):
                    for e in range(3):
                        diag[i, d, e] = flat[diag_slots[i], d, e]
                    trace += diag[i, d, d]
                if trace <= 0.0:  # a vertex without stiffness keeps an invertible block
                    for d in range(3):
                        diag[i, d, d] += 1.0
            coarse[:] = 0.0
            coarse_matrix_one(values, cols, agg, fb, coarse)
            coarse_factor_one(coarse, first, agg, fb, factor)
            its, _ = pcg_one(
                values, cols, diag, agg, factor, first, fb, rhs, dx, cg_rtol, cg_max_iters
            )
            alpha = 1.0
            if line_search:
                slope = 0.0
                for i in range(verts):
                    for d in range(3):
                        slope += grad[i, d] * dx[i, d]
                trial_value = value
                for _h in range(max_halvings):
                    for i in range(verts):
                        for d in range(3):
                            trial[i, d] = xb[i, d] + alpha * dx[i, d]
                    trial_value = _shell_instance(
                        trial,
                        geometry,
                        row0[b],
                        fibres[b],
                        samples[b],
                        cumulative[b],
                        False,
                        no_grad,
                        no_values,
                    )
                    trial_value += _quadratic(
                        trial, quad[b], centre[b], force[b], no_grad, no_values, diag_slots, False
                    )
                    trial_value += const[b]  # summed as ``value`` above
                    if trial_value <= value + 1e-4 * alpha * slope + 16 * eps * abs(value):
                        break
                    alpha = 0.5 * alpha
                value = trial_value
            update = 0.0
            for i in range(verts):
                s0, s1, s2 = alpha * dx[i, 0], alpha * dx[i, 1], alpha * dx[i, 2]
                xb[i, 0] += s0
                xb[i, 1] += s1
                xb[i, 2] += s2
                update = max(update, math.sqrt(s0 * s0 + s1 * s1 + s2 * s2))
            newton_iters[b] += 1
            cg_iters[b] += its
            max_update[b] = update
            if not update > tol_dx:
                break
    return x, newton_iters, cg_iters, max_update
