"""Anisotropic, strain-stiffening membrane energy from Wang et al. (2011) measurements.

Per triangle, with the Green strain ``G = 1/2 (F^T F - I)`` in the (warp, weft)
material frame written as ``g = (G00, G11, G01)``::

    W(g) = 1/2 (k0 G00^2 + k2 G11^2 + 2 k1 G00 G11 + k3 G01^2)        [J/m²]
    k(g) = row0 + w(e) (row_dir(psi) - row0)

``e`` is the largest principal Green strain, ``w`` a C1 smoothstep of
``e / STRETCH_SAMPLE_STRAIN`` clamped to [0, 1] (the stiffening saturates at the
measured strain, as in ArcSim), ``psi`` the angle of the principal direction to
the warp folded into [0, 90] degrees, and ``row_dir`` the piecewise-linear
interpolation of the five directional rows. The principal direction is
undefined for equi-biaxial strain, where an angle-based blend would make forces
blow up; so ``row_dir`` fades to the mean of the directional rows as the strain
anisotropy ``r`` (half the principal-strain difference) drops below
``ANISOTROPY_FADE`` (a smoothstep in ``r``), and ``e`` uses ``r`` rounded by
``sqrt(r² + delta²) - delta``, which keeps ``W`` twice differentiable there.
Unlike ArcSim, forces are the exact gradient of this energy (including the
``dk/dg`` terms), so energy is conserved by construction and Newton's line
search is well defined.

Switches: ``strain_dependent=False`` uses row 0 (zero-strain stiffness)
everywhere; ``anisotropic=False`` replaces each row by its isotropic average
(``k0 = k2 = (k0 + k2) / 2``, ``k3 = 2 (k0 - k1)``, directions averaged).
"""

from __future__ import annotations

import dataclasses
import math

import torch

from ..geometry import deformation_gradient, flat_indices, scatter_vertices
from ..material import STRETCH_SAMPLE_STRAIN
from .base import ElementBlocks, Energy, psd_project_sym2

__all__ = ["EnergyMembraneWang", "isotropic_rows", "membrane_density"]

_ANGLE_EPS = 1e-9  # regularises the principal angle at isotropic strain
ANISOTROPY_FADE = 0.1 * STRETCH_SAMPLE_STRAIN
"""Strain anisotropy below which the directional rows fade to their mean."""
_CONE_ROUNDING = 0.01 * STRETCH_SAMPLE_STRAIN
"""Rounds the cone of the principal-strain formula at equi-biaxial strain (keeps W C2)."""


def isotropic_rows(stretching: torch.Tensor) -> torch.Tensor:
    """Isotropic average of stiffness rows (B, 6, 4): equal tension, matching shear."""
    k_tension = 0.5 * (stretching[..., 0] + stretching[..., 2])
    k_coupling = torch.minimum(stretching[..., 1], 0.9 * k_tension)
    iso = torch.stack([k_tension, k_coupling, k_tension, 2.0 * (k_tension - k_coupling)], dim=-1)
    directional = iso[..., 1:, :].mean(dim=-2, keepdim=True).expand_as(iso[..., 1:, :])
    return torch.cat([iso[..., :1, :], directional], dim=-2)


def stiffness_at_strain(
    g: torch.Tensor, rows: torch.Tensor, strain_dependent: bool
) -> torch.Tensor:
    """Blended stiffness vector k(g) [N/m], shape (B, F, 4), for strains g (B, F, 3)."""
    row0 = rows[:, None, 0, :]
    if not strain_dependent:
        return row0.expand(*g.shape[:2], 4)
    g0, g1, g2 = g.unbind(-1)
    half_diff = 0.5 * (g0 - g1)
    off = torch.sqrt(g2 * g2 + _ANGLE_EPS**2)
    rounded = torch.sqrt(half_diff * half_diff + g2 * g2 + _CONE_ROUNDING**2) - _CONE_ROUNDING
    e_max = 0.5 * (g0 + g1) + rounded
    t = (e_max / STRETCH_SAMPLE_STRAIN).clamp(0.0, 1.0)
    weight = t * t * (3.0 - 2.0 * t)
    psi = 0.5 * torch.atan2(off, half_diff)  # [0, pi/2]
    pos = psi / (math.pi / 8.0)
    idx = pos.detach().floor().clamp(0, 3).long()
    frac = pos - idx
    directional = rows[:, 1:, :]  # (B, 5, 4)
    gather = lambda j: torch.gather(  # noqa: E731
        directional, 1, j.reshape(j.shape[0], -1, 1).expand(-1, -1, 4)
    ).reshape(*j.shape, 4)
    k_dir = gather(idx) * (1 - frac)[..., None] + gather(idx + 1) * frac[..., None]
    k_mean = directional.mean(dim=1, keepdim=True)
    fade = (rounded / ANISOTROPY_FADE).clamp(0.0, 1.0)
    fade = (fade * fade * (3.0 - 2.0 * fade))[..., None]
    k_dir = k_mean + fade * (k_dir - k_mean)
    return row0 + weight[..., None] * (k_dir - row0)


def membrane_density(g: torch.Tensor, rows: torch.Tensor, strain_dependent: bool) -> torch.Tensor:
    """Energy per unit rest area W(g) [J/m²], shape (B, F)."""
    k = stiffness_at_strain(g, rows, strain_dependent)
    g0, g1, g2 = g.unbind(-1)
    k0, k1, k2, k3 = k.unbind(-1)
    return 0.5 * (k0 * g0 * g0 + k2 * g1 * g1 + 2.0 * k1 * g0 * g1 + k3 * g2 * g2)


def _green_strain(fmat: torch.Tensor) -> torch.Tensor:
    f0, f1 = fmat[..., 0], fmat[..., 1]
    return torch.stack(
        [0.5 * ((f0 * f0).sum(-1) - 1.0), 0.5 * ((f1 * f1).sum(-1) - 1.0), 0.5 * (f0 * f1).sum(-1)],
        dim=-1,
    )


def _shape_coeffs(rest_inv: torch.Tensor) -> torch.Tensor:
    """c[i, a] = dF[:, a] / dx_i for the three triangle vertices, shape (F, 3, 2)."""
    return torch.cat([-rest_inv.sum(dim=1, keepdim=True), rest_inv], dim=1)


@dataclasses.dataclass(frozen=True)
class EnergyMembraneWang(Energy):
    """Membrane energy of the measured-data cloth model."""

    stretching: torch.Tensor
    """Stiffness rows [N/m], shape (B, 6, 4) (already stabilised and multiplied)."""
    strain_dependent: bool = True
    anisotropic: bool = True

    def rows(self) -> torch.Tensor:
        """Stiffness rows after the isotropy switch, shape (B, 6, 4)."""
        return self.stretching if self.anisotropic else isotropic_rows(self.stretching)

    def energy(self, model, pos):
        """Sum over triangles of rest area times W [J], shape (B,)."""
        mesh = model.mesh
        g = _green_strain(deformation_gradient(pos, mesh.tri_indices, mesh.tri_rest_inv))
        w = membrane_density(g, self.rows(), self.strain_dependent)
        return (w * mesh.tri_rest_area).sum(-1)

    def _strain_and_stress(self, model, pos):
        mesh = model.mesh
        fmat = deformation_gradient(pos, mesh.tri_indices, mesh.tri_rest_inv)
        g = _green_strain(fmat)
        with torch.enable_grad():
            gv = g.detach().requires_grad_(True)
            w = membrane_density(gv, self.rows(), self.strain_dependent)
            (s,) = torch.autograd.grad(w.sum(), gv)
        return fmat, g, s

    def _strain_jacobian(self, model, fmat):
        """J[b, f, i, v, :] = d g_v / d x_i, shape (B, F, 3, 3, 3)."""
        c = _shape_coeffs(model.mesh.tri_rest_inv)  # (F, 3, 2)
        f0, f1 = fmat[..., 0], fmat[..., 1]  # (B, F, 3)
        c0 = c[None, :, :, 0, None]
        c1 = c[None, :, :, 1, None]
        j0 = c0 * f0[:, :, None]
        j1 = c1 * f1[:, :, None]
        j2 = 0.5 * (c1 * f0[:, :, None] + c0 * f1[:, :, None])
        return torch.stack([j0, j1, j2], dim=3)

    def gradient(self, model, pos):
        """Analytic dE/dx [N], shape (B, V, 3)."""
        fmat, _, s = self._strain_and_stress(model, pos)
        jac = self._strain_jacobian(model, fmat)
        per_vert = (
            torch.einsum("bfv,bfivx->bfix", s, jac) * model.mesh.tri_rest_area[None, :, None, None]
        )
        return scatter_vertices(per_vert, model.mesh.tri_indices, pos.shape[1])

    def hessian_blocks(self, model, pos):
        """Gauss-Newton material term with frozen k plus PSD-clamped geometric stiffness."""
        mesh = model.mesh
        fmat, g, s = self._strain_and_stress(model, pos)
        k = stiffness_at_strain(g, self.rows(), self.strain_dependent)
        k0, k1, k2, k3 = k.unbind(-1)
        zero = torch.zeros_like(k0)
        cmat = torch.stack(
            [
                torch.stack([k0, k1, zero], -1),
                torch.stack([k1, k2, zero], -1),
                torch.stack([zero, zero, k3], -1),
            ],
            dim=-2,
        )  # (B, F, 3, 3)
        jac = self._strain_jacobian(model, fmat)  # (B, F, i, v, x)
        area = mesh.tri_rest_area[None, :, None, None]
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
        c = _shape_coeffs(mesh.tri_rest_inv)
        geo = torch.einsum("fia,zfac,fjc->zfij", c, smat, c)  # (B, F, 3, 3) times identity
        blocks.diagonal(dim1=-2, dim2=-1).add_(geo[..., None])
        batch = pos.shape[0]
        return ElementBlocks(
            flat_indices(mesh.tri_indices, batch, pos.shape[1]),
            blocks.reshape(-1, 3, 3, 3, 3),
            mesh.tri_indices,
        )
