"""Anisotropic, strain-stiffening membrane energy fitted to Wang et al. (2011) data.

Per triangle, with the Green strain ``G = 1/2 (F^T F - I)`` in the (warp, weft)
material frame, ``g = (G00, G11, G01)``::

    W(g) = 1/2 (k0 G00^2 + k2 G11^2 + 2 k1 G00 G11 + k3 G01^2)    (row 0: zero strain)
         + sum_i beta_i Phi(eps_i),  eps_i = n_i^T G n_i             [J/m²]

Row 0 of the measurements is the small-strain orthotropic St Venant-Kirchhoff
law. Stiffening is carried by "fibre" terms along eight directions ``n_i`` at
0, ±22.5, ±45, ±67.5 and 90 degrees to the warp: ``Phi`` is convex, zero in
compression, with ``Phi''`` rising smoothly (smoothstep) from 0 at zero strain to
1 at the measured strain ``STRETCH_SAMPLE_STRAIN`` and constant beyond (the
stiffening saturates there, as ArcSim's clamp does). The fibre strengths
``beta >= 0`` are fitted (non-negative least squares, symmetric about the warp)
so that, under uniaxial strain of the measured size along each measured
direction, the tangent stiffness along that direction equals the one of the
measured row (``k0 c^4 + k2 s^4 + (2 k1 + k3) c^2 s^2``). Where a row is softer than
row 0 the fit leaves it at row 0.

Why not ArcSim's scheme (blend the four coefficients by the principal strain's
size and angle)? Read as an energy it is not convex: for camel-ponte-roma the
density Hessian has a negative eigenvalue at ~65 % of sampled strains, and the
simulated cloth never comes to rest. ArcSim sidesteps this by ignoring the
stiffness's own derivatives (non-conservative forces). The fibre form is
hyperelastic and convex in ``G``: forces are exact gradients, the density
Hessian is positive semi-definite, and Newton's line search is well defined.
Coupling and shear changes between rows enter only through their effect on
the directional tangent stiffness.

Switches: ``strain_dependent=False`` drops the fibres (row 0 everywhere);
``anisotropic=False`` makes row 0 isotropic (``k0 = k2 = (k0 + k2)/2``,
``k3 = 2 (k0 - k1)``) and gives all eight fibres their mean strength.
"""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np
import torch

from ..geometry import deformation_gradient, flat_indices, scatter_vertices
from .base import ElementBlocks, Energy, psd_project_sym2

__all__ = [
    "FIBRE_ANGLES_DEG",
    "STRETCH_SAMPLE_STRAIN",
    "EnergyMembraneWang",
    "fit_fibres",
    "isotropic_rows",
    "membrane_density",
]

STRETCH_SAMPLE_STRAIN = 0.5 * ((7.0 / 6.0) ** 2 - 1.0)
"""Green strain of the measured stretching rows 1-5 (principal stretch 1 + 1/6)."""

FIBRE_ANGLES_DEG = (0.0, 22.5, -22.5, 45.0, -45.0, 67.5, -67.5, 90.0)
"""Fibre directions to the warp [deg]; pairs +-a share one fitted strength."""
_MEASURED_ANGLES = np.radians([0.0, 22.5, 45.0, 67.5, 90.0])
_FIBRE_GROUP = (0, 1, 1, 2, 2, 3, 3, 4)


def _directional_stiffness(rows: np.ndarray, angle: np.ndarray) -> np.ndarray:
    c2, s2 = np.cos(angle) ** 2, np.sin(angle) ** 2
    k0, k1, k2, k3 = np.moveaxis(rows, -1, 0)
    return k0 * c2 * c2 + k2 * s2 * s2 + (2 * k1 + k3) * c2 * s2


def _ramp(t):
    """Phi'' / 1 as a function of t = eps / e_s: smoothstep, 0 below 0, 1 above 1."""
    t = np.clip(t, 0.0, 1.0)
    return t * t * (3 - 2 * t)


def _nnls_exact(design: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Non-negative least squares of a small full-rank system, by trying every support.

    The optimum is the unconstrained least-squares solution on its own support, so the
    feasible support solution of least residual is it. Five unknowns make 32 supports. Not
    scipy's ``nnls``: its re-implementations (1.12 and later) can return a point that is not
    the minimiser (scipy issues 21140, 25389), which changed the fitted cloth between
    installs (camel-ponte-roma's 67.5-degree stiffness came out 1.75x the measured one).
    """
    best, best_residual = np.zeros(design.shape[1]), float(np.sum(target**2))
    for size in range(1, design.shape[1] + 1):
        for support in itertools.combinations(range(design.shape[1]), size):
            cols = list(support)
            x, *_ = np.linalg.lstsq(design[:, cols], target, rcond=None)
            if np.any(x < 0.0):
                continue
            residual = float(np.sum((design[:, cols] @ x - target) ** 2))
            if residual < best_residual:
                best = np.zeros(design.shape[1])
                best[cols] = x
                best_residual = residual
    return best


def fit_fibres(stretching: np.ndarray) -> np.ndarray:
    """Fibre strengths [N/m] of one material's (6, 4) rows, one per FIBRE_ANGLES_DEG entry."""
    base = _directional_stiffness(stretching[0], _MEASURED_ANGLES)
    target = _directional_stiffness(stretching[1:], _MEASURED_ANGLES) - base
    fibre = np.radians(FIBRE_ANGLES_DEG)
    design = np.zeros((5, 5))
    for j, theta in enumerate(_MEASURED_ANGLES):
        cos2 = np.cos(fibre - theta) ** 2
        contrib = cos2 * cos2 * _ramp(cos2)  # fibre strain is e_s cos², tangent picks cos⁴
        for i, group in enumerate(_FIBRE_GROUP):
            design[j, group] += contrib[i]
    strength = _nnls_exact(design, np.maximum(target, 0.0))
    return strength[list(_FIBRE_GROUP)]


def isotropic_rows(stretching: torch.Tensor) -> torch.Tensor:
    """Isotropic version of stiffness rows (..., 4): equal tension, matching shear."""
    k_tension = 0.5 * (stretching[..., 0] + stretching[..., 2])
    k_coupling = torch.minimum(stretching[..., 1], 0.9 * k_tension)
    return torch.stack([k_tension, k_coupling, k_tension, 2.0 * (k_tension - k_coupling)], -1)


def _fibre_vectors(dtype, device) -> torch.Tensor:
    """a_i with eps_i = a_i . g, shape (8, 3)."""
    theta = torch.tensor([math.radians(a) for a in FIBRE_ANGLES_DEG], dtype=dtype, device=device)
    c, s = torch.cos(theta), torch.sin(theta)
    return torch.stack([c * c, s * s, 2 * c * s], dim=-1)


def _phi(eps: torch.Tensor, order: int) -> torch.Tensor:
    """Phi (order 0), Phi' (1) or Phi'' (2) of the fibre strain, zero in compression."""
    e_s = STRETCH_SAMPLE_STRAIN
    t = (eps / e_s).clamp(0.0, 1.0)
    over = (eps - e_s).clamp_min(0.0)
    if order == 0:
        return e_s * e_s * (t**4 / 4 - t**5 / 10) + (e_s / 2) * over + 0.5 * over * over
    if order == 1:
        return e_s * (t**3 - t**4 / 2) + over
    return t * t * (3 - 2 * t)


def membrane_density(g: torch.Tensor, row0: torch.Tensor, fibres: torch.Tensor) -> torch.Tensor:
    """Energy per unit rest area W(g) [J/m²], shape (B, F), for row0 (B, 4), fibres (B, 8)."""
    g0, g1, g2 = g.unbind(-1)
    k0, k1, k2, k3 = (row0[:, i, None] for i in range(4))
    base = 0.5 * (k0 * g0 * g0 + k2 * g1 * g1 + 2.0 * k1 * g0 * g1 + k3 * g2 * g2)
    eps = g @ _fibre_vectors(g.dtype, g.device).T  # (B, F, 8)
    return base + (fibres[:, None, :] * _phi(eps, 0)).sum(-1)


def _green_strain(fmat: torch.Tensor) -> torch.Tensor:
    f0, f1 = fmat[..., 0], fmat[..., 1]
    return torch.stack(
        [0.5 * ((f0 * f0).sum(-1) - 1.0), 0.5 * ((f1 * f1).sum(-1) - 1.0), 0.5 * (f0 * f1).sum(-1)],
        dim=-1,
    )


def _shape_coeffs(rest_inv: torch.Tensor) -> torch.Tensor:
    """c[..., i, a] = dF[:, a] / dx_i for the three triangle vertices.

    Shape (F, 3, 2) from a shared rest_inv (F, 2, 2) [1/m], (B, F, 3, 2) from a per-instance
    one (B, F, 2, 2).
    """
    return torch.cat([-rest_inv.sum(dim=-2, keepdim=True), rest_inv], dim=-2)


def _geometric_stiffness(c: torch.Tensor, smat: torch.Tensor) -> torch.Tensor:
    """``c S c^T`` per triangle, shape (B, F, 3, 3), from c (F or B, F, 3, 2), S (B, F, 2, 2)."""
    spec = "fia,zfac,fjc->zfij" if c.dim() == 3 else "zfia,zfac,zfjc->zfij"
    return torch.einsum(spec, c, smat, c)


@dataclasses.dataclass(frozen=True)
class EnergyMembraneWang(Energy):
    """Membrane energy of the measured-data cloth model (see module docstring)."""

    row0: torch.Tensor
    """Zero-strain stiffness ``(k0, k1, k2, k3)`` [N/m], shape (B, 4)."""
    fibres: torch.Tensor
    """Fibre strengths [N/m] along FIBRE_ANGLES_DEG, shape (B, 8)."""

    @staticmethod
    def from_material(
        stretching: torch.Tensor, *, strain_dependent: bool = True, anisotropic: bool = True
    ) -> EnergyMembraneWang:
        """Build from stabilised stiffness rows (B, 6, 4) [N/m]."""
        rows = stretching.detach().cpu().double().numpy()
        fibres = np.stack([fit_fibres(r) for r in rows])
        fibres = torch.as_tensor(fibres, dtype=stretching.dtype, device=stretching.device)
        row0 = stretching[:, 0, :]
        if not anisotropic:
            row0 = isotropic_rows(row0)
            fibres = fibres.mean(dim=1, keepdim=True).expand_as(fibres)
        if not strain_dependent:
            fibres = torch.zeros_like(fibres)
        return EnergyMembraneWang(row0.contiguous(), fibres.contiguous())

    def rest_data(self, model) -> tuple[torch.Tensor, torch.Tensor]:
        """Inverse rest edge matrices [1/m] and rest areas [m²] of the triangles.

        The shared mesh's, shapes (F, 2, 2) and (F,); a subclass with per-instance rest
        shapes returns (B, F, 2, 2) and (B, F), and every other method follows.
        """
        return model.mesh.tri_rest_inv, model.mesh.tri_rest_area

    def _strain(self, model, pos):
        fmat = deformation_gradient(pos, model.mesh.tri_indices, self.rest_data(model)[0])
        return fmat, _green_strain(fmat)

    def energy(self, model, pos):
        """Sum over triangles of rest area times W [J], shape (B,)."""
        _, g = self._strain(model, pos)
        return (membrane_density(g, self.row0, self.fibres) * self.rest_data(model)[1]).sum(-1)

    def _stress(self, g):
        """S = dW/dg, shape (B, F, 3), and the fibre strains (B, F, 8)."""
        k0, k1, k2, k3 = (self.row0[:, i, None] for i in range(4))
        g0, g1, g2 = g.unbind(-1)
        base = torch.stack([k0 * g0 + k1 * g1, k1 * g0 + k2 * g1, k3 * g2], dim=-1)
        vectors = _fibre_vectors(g.dtype, g.device)
        eps = g @ vectors.T
        return base + (self.fibres[:, None, :] * _phi(eps, 1)) @ vectors, eps

    def _strain_jacobian(self, model, fmat):
        """J[b, f, i, v, :] = d g_v / d x_i, shape (B, F, 3, 3, 3)."""
        c = _shape_coeffs(self.rest_data(model)[0])  # (F, 3, 2) or (B, F, 3, 2)
        f0, f1 = fmat[..., 0], fmat[..., 1]  # (B, F, 3)
        c0, c1 = c[..., 0, None], c[..., 1, None]
        j0 = c0 * f0[:, :, None]
        j1 = c1 * f1[:, :, None]
        j2 = 0.5 * (c1 * f0[:, :, None] + c0 * f1[:, :, None])
        return torch.stack([j0, j1, j2], dim=3)

    def gradient(self, model, pos):
        """Analytic dE/dx [N], shape (B, V, 3)."""
        fmat, g = self._strain(model, pos)
        s, _ = self._stress(g)
        jac = self._strain_jacobian(model, fmat)
        area = self.rest_data(model)[1][..., None, None]
        per_vert = torch.einsum("bfv,bfivx->bfix", s, jac) * area
        return scatter_vertices(per_vert, model.mesh.tri_indices, pos.shape[1])

    def hessian_blocks(self, model, pos):
        """Exact material term (convex density) plus PSD-clamped geometric stiffness."""
        mesh = model.mesh
        fmat, g = self._strain(model, pos)
        s, eps = self._stress(g)
        k0, k1, k2, k3 = (self.row0[:, i, None] for i in range(4))
        zero = torch.zeros_like(g[..., 0])
        cmat = torch.stack(
            [
                torch.stack([k0 + zero, k1 + zero, zero], -1),
                torch.stack([k1 + zero, k2 + zero, zero], -1),
                torch.stack([zero, zero, k3 + zero], -1),
            ],
            dim=-2,
        )  # (B, F, 3, 3)
        vectors = _fibre_vectors(g.dtype, g.device)
        weights = self.fibres[:, None, :] * _phi(eps, 2)  # (B, F, 8)
        cmat = cmat + torch.einsum("bfi,iv,iw->bfvw", weights, vectors, vectors)
        jac = self._strain_jacobian(model, fmat)  # (B, F, i, v, x)
        rest_inv, rest_area = self.rest_data(model)
        area = rest_area[..., None, None]
        cj = torch.einsum("zfvw,zfjwy->zfjvy", cmat * area, jac)
        blocks = torch.einsum("zfivx,zfjvy->zfijxy", jac, cj)
        smat = torch.stack(
            [
                torch.stack([s[..., 0], 0.5 * s[..., 2]], -1),
                torch.stack([0.5 * s[..., 2], s[..., 1]], -1),
            ],
            dim=-2,
        )
        smat = psd_project_sym2(smat) * area
        geo = _geometric_stiffness(_shape_coeffs(rest_inv), smat)  # times identity
        blocks.diagonal(dim1=-2, dim2=-1).add_(geo[..., None])
        batch = pos.shape[0]
        return ElementBlocks(
            flat_indices(mesh.tri_indices, batch, pos.shape[1]),
            blocks.reshape(-1, 3, 3, 3, 3),
            mesh.tri_indices,
        )
