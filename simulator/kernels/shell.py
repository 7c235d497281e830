"""Compiled kernels of the discrete-shell cloth energies (membrane + dihedral bending).

One pass per instance computes, for every triangle and hinge, the energy, its gradient and
the solver's PSD Hessian blocks, and adds the blocks straight into the block-sparse (ELL)
values at precomputed slots: nothing per element is materialised. A second, energy-only pass
serves the line search. The formulas are those of :mod:`simulator.energies.membrane` and
:mod:`simulator.energies.bending` (the torch reference, which the tests compare to 1e-12),
written per element; instances run in parallel (``prange``), elements in order, in float64.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

__all__ = ["shell_assemble", "shell_energy"]

_EPS64 = np.finfo(np.float64).eps
_TINY64 = np.finfo(np.float64).tiny


@njit(cache=True, inline="always")
def _phi(eps, e_s, order):
    """Fibre potential Phi (order 0), Phi' (1) or Phi'' (2); see ``membrane._phi``."""
    t = min(max(eps / e_s, 0.0), 1.0)
    over = max(eps - e_s, 0.0)
    if order == 0:
        return e_s * e_s * (t**4 / 4.0 - t**5 / 10.0) + 0.5 * e_s * over + 0.5 * over * over
    if order == 1:
        return e_s * (t**3 - t**4 / 2.0) + over
    return t * t * (3.0 - 2.0 * t)


@njit(cache=True, inline="always")
def _phi_all(eps, e_s):
    """Phi, Phi' and Phi'' of one fibre strain together (``_phi`` of orders 0, 1, 2)."""
    t = min(max(eps / e_s, 0.0), 1.0)
    over = max(eps - e_s, 0.0)
    t2 = t * t
    t3 = t2 * t
    t4 = t3 * t
    phi = e_s * e_s * (t4 / 4.0 - t4 * t / 10.0) + 0.5 * e_s * over + 0.5 * over * over
    return phi, e_s * (t3 - t4 / 2.0) + over, t2 * (3.0 - 2.0 * t)


@njit(cache=True, inline="always", error_model="numpy")
def _membrane(x, tri, rest_inv, area, row0, fibres, fvec, e_s, want, grad, hess, work):
    """Energy of one triangle [J]; with ``want`` also its gradient (3, 3) and blocks (3, 3, 3, 3).

    ``fvec`` (8, 3) holds the fibre vectors a_i with eps_i = a_i . g; ``work`` is a
    :func:`_membrane_work` scratch tuple (no allocation per element).
    """
    c, f, s, cmat, jac, smat, cj = work
    for a in range(2):
        c[1, a] = rest_inv[0, a]
        c[2, a] = rest_inv[1, a]
        c[0, a] = -(rest_inv[0, a] + rest_inv[1, a])
    f[:] = 0.0
    for i in range(3):
        for a in range(2):
            for d in range(3):
                f[a, d] += c[i, a] * x[tri[i], d]
    g0 = 0.5 * (f[0, 0] ** 2 + f[0, 1] ** 2 + f[0, 2] ** 2 - 1.0)
    g1 = 0.5 * (f[1, 0] ** 2 + f[1, 1] ** 2 + f[1, 2] ** 2 - 1.0)
    g2 = 0.5 * (f[0, 0] * f[1, 0] + f[0, 1] * f[1, 1] + f[0, 2] * f[1, 2])
    k0, k1, k2, k3 = row0[0], row0[1], row0[2], row0[3]
    w = 0.5 * (k0 * g0 * g0 + k2 * g1 * g1 + 2.0 * k1 * g0 * g1 + k3 * g2 * g2)
    s[0] = k0 * g0 + k1 * g1
    s[1] = k1 * g0 + k2 * g1
    s[2] = k3 * g2
    cmat[:] = 0.0
    if want:
        cmat[0, 0], cmat[0, 1], cmat[1, 0], cmat[1, 1], cmat[2, 2] = k0, k1, k1, k2, k3
    for n in range(fvec.shape[0]):
        eps = fvec[n, 0] * g0 + fvec[n, 1] * g1 + fvec[n, 2] * g2
        if not eps > 0.0 or fibres[n] == 0.0:
            continue  # a fibre in compression (or absent) adds exactly nothing
        if not want:
            w += fibres[n] * _phi(eps, e_s, 0)
        else:
            phi, phi1, phi2 = _phi_all(eps, e_s)
            w += fibres[n] * phi
            p1 = fibres[n] * phi1
            p2 = fibres[n] * phi2
            for v in range(3):
                s[v] += p1 * fvec[n, v]
                for u in range(3):
                    cmat[v, u] += p2 * fvec[n, v] * fvec[n, u]
    if not want:
        return area * w
    # J[i, v, :] = d g_v / d x_i
    for i in range(3):
        for d in range(3):
            jac[i, 0, d] = c[i, 0] * f[0, d]
            jac[i, 1, d] = c[i, 1] * f[1, d]
            jac[i, 2, d] = 0.5 * (c[i, 1] * f[0, d] + c[i, 0] * f[1, d])
    for i in range(3):
        for d in range(3):
            grad[i, d] = area * (s[0] * jac[i, 0, d] + s[1] * jac[i, 1, d] + s[2] * jac[i, 2, d])
    # Geometric stiffness: PSD projection of [[S0, S2/2], [S2/2, S1]] (psd_project_sym2).
    a_, b_, d_ = s[0], 0.5 * s[2], s[1]
    mean = 0.5 * (a_ + d_)
    rad = math.sqrt(0.25 * (a_ - d_) ** 2 + b_ * b_)
    lam1, lam2 = mean + rad, mean - rad
    if a_ - d_ >= 0:
        v1x, v1y = lam1 - d_, b_
    else:
        v1x, v1y = b_, lam1 - a_
    norm = math.sqrt(v1x * v1x + v1y * v1y)
    scale = abs(a_) + abs(d_) + abs(b_)
    if norm <= 4.0 * _EPS64 * scale + _TINY64:
        cx, sy = 1.0, 0.0
    else:
        cx, sy = v1x / norm, v1y / norm
    p1, p2 = max(lam1, 0.0), max(lam2, 0.0)
    smat[0, 0] = (p1 * cx * cx + p2 * sy * sy) * area
    smat[1, 1] = (p1 * sy * sy + p2 * cx * cx) * area
    smat[0, 1] = smat[1, 0] = (p1 - p2) * cx * sy * area
    # cj[j, v, :] = area * sum_w C[v, w] J[j, w, :]
    for j in range(3):
        for v in range(3):
            for d in range(3):
                cj[j, v, d] = area * (
                    cmat[v, 0] * jac[j, 0, d]
                    + cmat[v, 1] * jac[j, 1, d]
                    + cmat[v, 2] * jac[j, 2, d]
                )
    for i in range(3):
        for j in range(i, 3):  # the blocks below the diagonal are the transposes
            geo = 0.0
            for a in range(2):
                for b in range(2):
                    geo += c[i, a] * smat[a, b] * c[j, b]
            for d in range(3):
                for e in range(3):
                    hess[i, j, d, e] = (
                        jac[i, 0, d] * cj[j, 0, e]
                        + jac[i, 1, d] * cj[j, 1, e]
                        + jac[i, 2, d] * cj[j, 2, e]
                    )
                hess[i, j, d, d] += geo
            if j != i:
                for d in range(3):
                    for e in range(3):
                        hess[j, i, e, d] = hess[i, j, d, e]
    return area * w


@njit(cache=True, error_model="numpy")
def _membrane_work():
    """Scratch arrays of :func:`_membrane`: c, f, s, cmat, jac, smat, cj."""
    return (
        np.empty((3, 2)),
        np.empty((2, 3)),
        np.empty(3),
        np.empty((3, 3)),
        np.empty((3, 3, 3)),
        np.empty((2, 2)),
        np.empty((3, 3, 3)),
    )


@njit(cache=True, inline="always")
def _cross(a0, a1, a2, b0, b1, b2):
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@njit(cache=True, inline="always")
def _along(x, p, q, h0, h1, h2):
    """``(x_p - x_q) . h``."""
    return (x[p, 0] - x[q, 0]) * h0 + (x[p, 1] - x[q, 1]) * h1 + (x[p, 2] - x[q, 2]) * h2


@njit(cache=True, inline="always")
def _secant(samples, cumulative, knots, kappa):
    """psi(kappa), k(kappa), k'(kappa) of piecewise-linear secant samples.

    As ``bending._secant_integral``; ``cumulative`` holds psi at the knots
    (``bending.secant_knot_integrals``).
    """
    last = knots.shape[0] - 1
    spacing = knots[1] - knots[0]
    seg = min(max(math.floor(kappa / spacing), 0), last - 1)
    k_j = samples[seg]
    m_seg = (samples[seg + 1] - samples[seg]) / spacing
    lo = knots[seg]
    u = min(kappa, knots[last])
    psi = (
        cumulative[seg]
        + (k_j * u * u / 2 + m_seg * (u**3 / 3 - lo * u * u / 2))
        - (k_j * lo * lo / 2 + m_seg * (lo**3 / 3 - lo * lo * lo / 2))
    )
    if kappa < knots[last]:
        return psi, k_j + m_seg * (kappa - lo), m_seg
    return psi + samples[last] * (kappa * kappa - knots[last] ** 2) / 2, samples[last], 0.0


@njit(cache=True, inline="always", error_model="numpy")
def _bending(x, hinge, rest_angle, scale, area, samples, cumulative, knots, bend_scale, want, grad):
    """Energy of one hinge [J].

    With ``want`` it also writes dE/dx into ``grad[0:4]`` and d theta/dx scaled by
    ``sqrt(max(E'', 0))`` (the Gauss-Newton factor) into ``grad[4:8]``.
    """
    o0, o1, v1, v2 = hinge[0], hinge[1], hinge[2], hinge[3]
    a0, a1, a2 = x[v1, 0] - x[o0, 0], x[v1, 1] - x[o0, 1], x[v1, 2] - x[o0, 2]
    b0, b1, b2 = x[v2, 0] - x[o0, 0], x[v2, 1] - x[o0, 1], x[v2, 2] - x[o0, 2]
    n10, n11, n12 = _cross(a0, a1, a2, b0, b1, b2)
    a0, a1, a2 = x[v2, 0] - x[o1, 0], x[v2, 1] - x[o1, 1], x[v2, 2] - x[o1, 2]
    b0, b1, b2 = x[v1, 0] - x[o1, 0], x[v1, 1] - x[o1, 1], x[v1, 2] - x[o1, 2]
    n20, n21, n22 = _cross(a0, a1, a2, b0, b1, b2)
    e0, e1, e2 = x[v2, 0] - x[v1, 0], x[v2, 1] - x[v1, 1], x[v2, 2] - x[v1, 2]
    e_len = math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
    h0, h1, h2 = e0 / e_len, e1 / e_len, e2 / e_len
    n1_sq = n10 * n10 + n11 * n11 + n12 * n12
    n2_sq = n20 * n20 + n21 * n21 + n22 * n22
    norm = math.sqrt(n1_sq) * math.sqrt(n2_sq)
    c0, c1, c2 = _cross(n10, n11, n12, n20, n21, n22)
    sin = (c0 * h0 + c1 * h1 + c2 * h2) / norm
    cos = (n10 * n20 + n11 * n21 + n12 * n22) / norm
    delta = math.atan2(sin, cos) - rest_angle
    kappa = abs(delta) * scale
    psi, k_val, k_slope = _secant(samples, cumulative, knots, kappa)
    if not want:
        return bend_scale * area * psi
    d_e = bend_scale * area * scale * scale * k_val * delta
    dd_e = bend_scale * area * scale * scale * (k_val + k_slope * kappa)
    root = math.sqrt(max(dd_e, 0.0))
    # d theta / dx (Bridson et al. 2003), as dihedral_angle_gradient.
    along_o0_v2 = _along(x, o0, v2, h0, h1, h2)
    along_o1_v2 = _along(x, o1, v2, h0, h1, h2)
    along_o0_v1 = _along(x, o0, v1, h0, h1, h2)
    along_o1_v1 = _along(x, o1, v1, h0, h1, h2)
    for d in range(3):
        if d == 0:
            m1, m2 = n10 / n1_sq, n20 / n2_sq
        elif d == 1:
            m1, m2 = n11 / n1_sq, n21 / n2_sq
        else:
            m1, m2 = n12 / n1_sq, n22 / n2_sq
        t0 = -e_len * m1
        t1 = -e_len * m2
        t2 = -along_o0_v2 * m1 - along_o1_v2 * m2
        t3 = along_o0_v1 * m1 + along_o1_v1 * m2
        grad[0, d], grad[4, d] = d_e * t0, root * t0
        grad[1, d], grad[5, d] = d_e * t1, root * t1
        grad[2, d], grad[6, d] = d_e * t2, root * t2
        grad[3, d], grad[7, d] = d_e * t3, root * t3
    return bend_scale * area * psi


@njit(cache=True, error_model="numpy")
def _shell_instance(x, geometry, row0, fibres, samples, cumulative, want, grad, values):
    """Energy of one instance [J]; with ``want`` also adds its gradient and Hessian blocks.

    ``x`` (V, 3), ``row0`` (4,), ``fibres`` (8,), ``samples`` and ``cumulative`` (E, 5),
    ``grad`` (V, 3) and ``values`` (V * K, 3, 3) are this instance's; ``geometry`` as
    :func:`shell_assemble`.
    """
    (
        tri,
        rest_inv,
        tri_area,
        tri_slots,
        fvec,
        e_s,
        hinges,
        rest_angle,
        edge_scale,
        edge_area,
        knots,
        bend_scale,
        hinge_slots,
    ) = geometry
    g3 = np.empty((3, 3))
    h3 = np.empty((3, 3, 3, 3))
    g4 = np.empty((8, 3))
    work = _membrane_work()
    total = 0.0
    for f in range(tri.shape[0]):
        total += _membrane(
            x, tri[f], rest_inv[f], tri_area[f], row0, fibres, fvec, e_s, want, g3, h3, work
        )
        if not want:
            continue
        for i in range(3):
            for d in range(3):
                grad[tri[f, i], d] += g3[i, d]
            for j in range(3):
                slot = tri_slots[f, i, j]
                for d in range(3):
                    for e in range(3):
                        values[slot, d, e] += h3[i, j, d, e]
    for n in range(hinges.shape[0]):
        total += _bending(
            x,
            hinges[n],
            rest_angle[n],
            edge_scale[n],
            edge_area[n],
            samples[n],
            cumulative[n],
            knots,
            bend_scale,
            want,
            g4,
        )
        if not want:
            continue
        for i in range(4):
            for d in range(3):
                grad[hinges[n, i], d] += g4[i, d]
            if g4[4 + i, 0] == 0.0 and g4[4 + i, 1] == 0.0 and g4[4 + i, 2] == 0.0:
                continue  # a zero row (E'' <= 0 here) adds nothing, nor does its mirror
            for j in range(i, 4):  # g_i g_j^T and its transpose g_j g_i^T together
                slot = hinge_slots[n, i, j]
                mirror = hinge_slots[n, j, i]
                for d in range(3):
                    for e in range(3):
                        prod = g4[4 + i, d] * g4[4 + j, e]
                        values[slot, d, e] += prod
                        if j != i:
                            values[mirror, e, d] += prod
    return total


@njit(cache=True, parallel=True, error_model="numpy")
def shell_assemble(pos, geometry, params, energy, grad, values):
    """Add energy (B,), gradient (B, V, 3) and PSD Hessian blocks into ELL ``values``.

    Args:
        pos: positions [m], (B, V, 3).
        geometry: what every instance shares, in this order:
            tri: triangles (F, 3);
            rest_inv: inverse rest edge matrices (F, 2, 2) [1/m];
            tri_area: rest areas (F,) [m²];
            tri_slots: flat ELL slot ``row * K + k`` of block (a, b) of each triangle,
            (F, 3, 3);
            fvec: fibre vectors (8, 3);
            e_s: fibre saturation strain;
            hinges: hinges ``[o0, o1, v1, v2]`` (E, 4);
            rest_angle: rest dihedral angles (E,) [rad];
            edge_scale: ``l / A`` (E,) [1/m];
            edge_area: ``A`` (E,) [m²];
            knots: the bending samples' curvatures (5,) [1/m];
            bend_scale: the bending discrete-to-continuum factor;
            hinge_slots: ELL slots of the hinge blocks, (E, 4, 4).
        params: each instance's material, in this order:
            row0: zero-strain membrane rows (B, 4) [N/m];
            fibres: fibre strengths (B, 8) [N/m];
            samples: secant bending samples (B, E, 5) [N·m];
            cumulative: psi at their curvatures (B, E, 5) [N/m]
            (``bending.secant_knot_integrals``).
        energy: output (B,), added to.
        grad: output (B, V, 3), added to.
        values: output (B, V * K, 3, 3), added to.
    """
    row0, fibres, samples, cumulative = params
    for b in prange(pos.shape[0]):
        energy[b] += _shell_instance(
            pos[b],
            geometry,
            row0[b],
            fibres[b],
            samples[b],
            cumulative[b],
            True,
            grad[b],
            values[b],
        )


@njit(cache=True, parallel=True, error_model="numpy")
def shell_energy(pos, geometry, params):
    """Membrane + bending energy [J] per instance, (B,); arguments as :func:`shell_assemble`."""
    row0, fibres, samples, cumulative = params
    batch = pos.shape[0]
    out = np.zeros(batch)
    for b in prange(batch):
        unused_grad = np.empty((1, 3))
        unused_values = np.empty((1, 3, 3))
        out[b] = _shell_instance(
            pos[b],
            geometry,
            row0[b],
            fibres[b],
            samples[b],
            cumulative[b],
            False,
            unused_grad,
            unused_values,
        )
    return out
