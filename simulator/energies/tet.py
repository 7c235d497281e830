"""Hyperelastic energies of linear tetrahedra (tissue FEM, thesis ch. 3).

Every term is ``E = sum_t V_t Psi(F_t; params_t)`` with the deformation gradient
``F = [x1-x0, x2-x0, x3-x0] Dm^-1`` and per-instance, per-tet material parameters of
shape (B, T): a PSO swarm or a set of UKF sigma points is just a batch of instances.
Each model gives the density ``Psi``, the first Piola-Kirchhoff stress ``P = dPsi/dF``
and the exact tangent ``A = dP/dF``; the solver gets the element Hessians
``V_t G^T A+ G`` (12 x 12, entry layout (N, 4, 4, 3, 3)) with ``A+`` the 9 x 9 tangent
projected onto the PSD cone (only where a Cholesky test fails, which is cheap).

Models:

* :class:`EnergyTetLinear`: small-strain ``mu |eps|² + lam/2 tr(eps)²``, ``eps = sym(F) - I``.
* :class:`EnergyTetCorotated`: McAdams et al. (2011) ``mu |F - R|² + lam/2 tr(S - I)²``,
  ``F = R S`` with ``R`` a rotation (also for inverted ``F``, Irving et al. 2004 sign fix).
* :class:`EnergyTetStVK`: St Venant-Kirchhoff ``mu |E|² + lam/2 tr(E)²``, ``E = (F^T F - I)/2``.
* :class:`EnergyTetNeoHookean`: the stable neo-Hookean of Smith et al. (2018), with no
  ``log J`` and therefore finite for inverted elements.
* :class:`EnergyTetMooneyRivlin`: *thesis* eq. 3.8, ``1/2 mu1 ((I1² - I2)/I3^(2/3) - 6)
  + mu2 (I1/I3^(1/3) - 3) + v1 (I3^(1/2) - 1)²``; the ``I3^(-p)`` factors are continued by
  their second-order Taylor expansion below ``J = J_EXTEND``, so inverted elements have a
  finite energy that pushes them back (invertible FEM in the spirit of Teran et al. 2005).

Stresses and tangents are analytic (the base class falls back to ``torch.func`` for a new
density; the tests compare every analytic form with autograd or finite differences).
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import torch
from torch.func import grad, jvp, vmap

from simulator.errors import MaterialError

from .base import ElementBlocks, Energy

__all__ = [
    "J_EXTEND",
    "EnergyTetCorotated",
    "EnergyTetLinear",
    "EnergyTetMooneyRivlin",
    "EnergyTetNeoHookean",
    "EnergyTetStVK",
    "lame_from_young_poisson",
    "psd_project",
    "region_values",
    "tet_deformation_gradient",
    "tet_shape_gradients",
]

J_EXTEND = 0.2
"""Volume ratio below which the Mooney-Rivlin ``J^-p`` factors are Taylor-continued."""


def lame_from_young_poisson(
    youngs_modulus: torch.Tensor | float, poisson_ratio: torch.Tensor | float
) -> tuple[torch.Tensor, torch.Tensor]:
    """Lamé parameters ``(mu, lam)`` [Pa] of isotropic linear elasticity.

    Args:
        youngs_modulus: E [Pa], > 0, any shape.
        poisson_ratio: nu, in (-1, 0.5), broadcastable with ``youngs_modulus``.

    Raises:
        MaterialError: naming ``youngs_modulus`` or ``poisson_ratio`` and the allowed range.
    """
    e = torch.as_tensor(youngs_modulus, dtype=torch.float64)
    nu = torch.as_tensor(poisson_ratio, dtype=torch.float64)
    if isinstance(youngs_modulus, torch.Tensor):
        e = youngs_modulus
    if isinstance(poisson_ratio, torch.Tensor):
        nu = poisson_ratio
    if not bool(torch.isfinite(e).all()) or not bool((e > 0).all()):
        raise MaterialError(
            f"youngs_modulus must be finite and > 0 Pa, got min {float(e.min()):.4g} Pa"
        )
    if not bool(((nu > -1.0) & (nu < 0.5)).all()):
        bad = nu[~((nu > -1.0) & (nu < 0.5))].reshape(-1)[0]
        raise MaterialError(f"poisson_ratio must lie in (-1, 0.5), got {float(bad):.4g}")
    mu = e / (2.0 * (1.0 + nu))
    lam = e * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))
    return mu, lam


def region_values(values: torch.Tensor, tet_region: torch.Tensor) -> torch.Tensor:
    """Map per-region values (B, R) (or (R,)) to per-tet values (B, T)."""
    values = torch.as_tensor(values)
    if values.dim() == 1:
        values = values[None]
    region_count = int(tet_region.max()) + 1
    if values.shape[-1] != region_count:
        raise MaterialError(
            f"region values must have {region_count} columns (one per region), "
            f"got shape {tuple(values.shape)}"
        )
    return values[:, tet_region.to(values.device)]


def tet_shape_gradients(tet_rest_inv: torch.Tensor) -> torch.Tensor:
    """``c[t, a, j] = dF[:, j] / dx_a`` of each tet's four vertices [1/m], shape (T, 4, 3)."""
    return torch.cat([-tet_rest_inv.sum(dim=1, keepdim=True), tet_rest_inv], dim=1)


def tet_deformation_gradient(
    pos: torch.Tensor, tet_indices: torch.Tensor, tet_rest_inv: torch.Tensor
) -> torch.Tensor:
    """Deformation gradient ``F = Ds Dm^-1`` of each tet, shape (B, T, 3, 3)."""
    x = pos[:, tet_indices]  # (B, T, 4, 3)
    ds = (x[:, :, 1:] - x[:, :, :1]).transpose(-1, -2)  # columns are edge vectors
    return ds @ tet_rest_inv


class _Elements(NamedTuple):
    tet_indices: torch.Tensor
    tet_rest_inv: torch.Tensor
    tet_rest_volume: torch.Tensor


def _gradient_operator(tet_rest_inv: torch.Tensor) -> torch.Tensor:
    """``G[t, 3k + p, 3a + i] = d F_kp / d x_ai = delta_ki c[t, a, p]``, shape (T, 9, 12)."""
    c = tet_shape_gradients(tet_rest_inv)  # (T, 4, 3)
    eye = _eye(c)
    gmat = torch.einsum("ki,tap->tkpai", eye, c)
    return gmat.reshape(c.shape[0], 9, 12)


def _cofactor(fmat: torch.Tensor) -> torch.Tensor:
    """``dJ/dF`` = cofactor matrix (columns f1 x f2, f2 x f0, f0 x f1), valid for any F."""
    f0, f1, f2 = fmat[..., 0], fmat[..., 1], fmat[..., 2]
    return torch.stack(
        [torch.linalg.cross(f1, f2), torch.linalg.cross(f2, f0), torch.linalg.cross(f0, f1)], -1
    )


def _levi_civita(like: torch.Tensor) -> torch.Tensor:
    eps = torch.zeros(3, 3, 3, dtype=like.dtype, device=like.device)
    for i, j, k in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
        eps[i, j, k], eps[i, k, j] = 1.0, -1.0
    return eps


def _det_hessian(fmat: torch.Tensor) -> torch.Tensor:
    """``d²J / dF_ij dF_kl = eps_ikm eps_jln F_mn``, shape (..., 3, 3, 3, 3)."""
    eps = _levi_civita(fmat)
    return torch.einsum("ikm,jln,...mn->...ijkl", eps, eps, fmat)


def _outer(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """``a_ij b_kl``, shape (..., 3, 3, 3, 3)."""
    return a[..., :, :, None, None] * b[..., None, None, :, :]


def _left(mat: torch.Tensor) -> torch.Tensor:
    """``M_ik delta_jl``: the tangent of ``dF -> M dF``."""
    return torch.einsum("...ik,jl->...ijkl", mat, _eye(mat))


def _right(mat: torch.Tensor) -> torch.Tensor:
    """``delta_ik M_lj``: the tangent of ``dF -> dF M``."""
    return torch.einsum("ik,...lj->...ijkl", _eye(mat), mat)


def _swap(fmat: torch.Tensor) -> torch.Tensor:
    """``F_il F_kj``: the tangent of ``dF -> F dF^T F``."""
    return torch.einsum("...il,...kj->...ijkl", fmat, fmat)


def _scalar(x: torch.Tensor) -> torch.Tensor:
    return x[..., None, None]


def _scalar4(x: torch.Tensor) -> torch.Tensor:
    return x[..., None, None, None, None]


def psd_project(mat: torch.Tensor) -> torch.Tensor:
    """Clamp negative eigenvalues of symmetric matrices (..., n, n) to zero.

    A batched Cholesky decides which matrices are already positive definite; only the
    others go through ``eigh`` (about 13x slower), which keeps Newton's assembly cheap
    near the rest state where almost every element tangent is SPD.
    """
    shape = mat.shape
    flat = 0.5 * (mat + mat.transpose(-1, -2)).reshape(-1, shape[-2], shape[-1])
    _, info = torch.linalg.cholesky_ex(flat)
    bad = torch.nonzero(info > 0).reshape(-1)
    if bad.numel() == 0:
        return flat.reshape(shape)
    evals, evecs = torch.linalg.eigh(flat[bad])
    fixed = (evecs * evals.clamp_min(0.0)[..., None, :]) @ evecs.transpose(-1, -2)
    out = flat.clone()
    out[bad] = fixed
    return out.reshape(shape)


def _eye(like: torch.Tensor) -> torch.Tensor:
    return torch.eye(3, dtype=like.dtype, device=like.device)


def _param(value: torch.Tensor, name: str) -> None:
    if value.dim() != 2:
        raise MaterialError(f"{name} must have shape (B, T), got {tuple(value.shape)}")


class _EnergyTet(Energy):
    """Shared assembly of tet energies from ``density``, ``stress`` and ``tangent``."""

    project_tangent: bool = True
    """Whether the tangent needs PSD projection (False for convex densities)."""

    def density(self, fmat: torch.Tensor) -> torch.Tensor:
        """Energy per rest volume [J/m³], shape (B, T)."""
        raise NotImplementedError

    def stress(self, fmat: torch.Tensor) -> torch.Tensor:
        """First Piola-Kirchhoff stress ``dPsi/dF`` [Pa], shape (B, T, 3, 3)."""
        return grad(lambda f: self.density(f).sum())(fmat)

    def tangent(self, fmat: torch.Tensor) -> torch.Tensor:
        """Exact ``A[..., i, j, k, l] = dP_ij / dF_kl`` [Pa], shape (B, T, 3, 3, 3, 3)."""

        def stress_fn(f):
            return grad(lambda g: self.density(g).sum())(f)

        basis = torch.eye(9, dtype=fmat.dtype, device=fmat.device).reshape(9, 1, 1, 3, 3)
        cols = vmap(lambda d: jvp(stress_fn, (fmat,), (d.expand_as(fmat),))[1])(basis)
        return cols.permute(1, 2, 3, 4, 0).reshape(*fmat.shape[:2], 3, 3, 3, 3)

    def _elements(self, model) -> _Elements:
        mesh = model.mesh
        subset = getattr(self, "tet_subset", None)
        if subset is None:
            return _Elements(mesh.tet_indices, mesh.tet_rest_inv, mesh.tet_rest_volume)
        return _Elements(
            mesh.tet_indices[subset], mesh.tet_rest_inv[subset], mesh.tet_rest_volume[subset]
        )

    def _fmat(self, model, pos):
        el = self._elements(model)
        return tet_deformation_gradient(pos, el.tet_indices, el.tet_rest_inv)

    def energy(self, model, pos):
        """Sum over tets of rest volume times Psi [J], shape (B,)."""
        return (self.density(self._fmat(model, pos)) * self._elements(model).tet_rest_volume).sum(
            -1
        )

    def _scatter(self, model, pmat, batch, verts):
        el = self._elements(model)
        c = tet_shape_gradients(el.tet_rest_inv)
        per_vert = torch.einsum("btij,taj->btai", pmat, c) * el.tet_rest_volume[:, None, None]
        out = pmat.new_zeros(batch * verts, 3)
        offset = torch.arange(batch, device=pmat.device)[:, None, None] * verts
        out.index_add_(0, (el.tet_indices[None] + offset).reshape(-1), per_vert.reshape(-1, 3))
        return out.view(batch, verts, 3)

    def gradient(self, model, pos):
        """dE/dx [N], shape (B, V, 3)."""
        pmat = self.stress(self._fmat(model, pos))
        return self._scatter(model, pmat, pos.shape[0], pos.shape[1])

    def hessian_product(self, model, pos, dpos):
        """Exact (unprojected) Hessian times ``dpos``, shape (B, V, 3)."""
        el = self._elements(model)
        amat = self.tangent(self._fmat(model, pos))
        dfmat = tet_deformation_gradient(dpos, el.tet_indices, el.tet_rest_inv)
        dp = torch.einsum("btijkl,btkl->btij", amat, dfmat)
        return self._scatter(model, dp, pos.shape[0], pos.shape[1])

    def hessian_blocks(self, model, pos):
        """Element blocks ``V_t G^T A+ G`` in entry layout (B*T, 4, 4, 3, 3)."""
        el = self._elements(model)
        batch, verts = pos.shape[:2]
        amat = self.tangent(self._fmat(model, pos))
        if self.project_tangent:
            amat = psd_project(amat.reshape(*amat.shape[:2], 9, 9)).reshape(amat.shape)
        gmat = _gradient_operator(el.tet_rest_inv)  # (T, 9, 12)
        a9 = amat.reshape(batch, -1, 9, 9) * el.tet_rest_volume[:, None, None]
        blocks = gmat.transpose(-1, -2) @ (a9 @ gmat)  # (B, T, 12, 12), rows (a, i)
        blocks = blocks.reshape(batch, -1, 4, 3, 4, 3).permute(0, 1, 2, 4, 3, 5)
        offset = torch.arange(batch, device=pos.device)[:, None, None] * verts
        flat = (el.tet_indices[None] + offset).reshape(-1, 4)
        return ElementBlocks(flat, blocks.reshape(-1, 4, 4, 3, 3), el.tet_indices)


@dataclasses.dataclass(frozen=True)
class _LameEnergy(_EnergyTet):
    mu: torch.Tensor
    """First Lamé parameter (shear modulus) per instance and tet [Pa], shape (B, T)."""
    lam: torch.Tensor
    """Second Lamé parameter per instance and tet [Pa], shape (B, T)."""
    tet_subset: torch.Tensor | None = None
    """Ids of the tets this material occupies, int64 (T',); ``None`` for the whole mesh.
    With a subset, ``mu`` and ``lam`` are (B, T')."""

    def __post_init__(self):
        _param(self.mu, "mu")
        _param(self.lam, "lam")
        if not bool((self.mu > 0).all()):
            raise MaterialError("mu must be > 0 Pa (shear modulus)")

    @classmethod
    def from_young_poisson(
        cls,
        youngs_modulus: torch.Tensor,
        poisson_ratio: torch.Tensor | float,
        tet_count: int | None = None,
        *,
        tet_subset: torch.Tensor | None = None,
    ):
        """Build from Young's modulus [Pa] and Poisson ratio, each (B, T), (B,) or scalar.

        ``(B,)`` values are broadcast to every tet (needs ``tet_count``).
        """
        mu, lam = lame_from_young_poisson(youngs_modulus, poisson_ratio)
        mu, lam = torch.broadcast_tensors(mu, lam)
        if mu.dim() < 2:
            if tet_count is None:
                raise MaterialError("tet_count is needed to broadcast per-instance moduli")
            mu = mu.reshape(-1, 1).expand(-1, tet_count)
            lam = lam.reshape(-1, 1).expand(-1, tet_count)
        return cls(mu.contiguous(), lam.contiguous(), tet_subset)


@dataclasses.dataclass(frozen=True)
class EnergyTetLinear(_LameEnergy):
    """Small-strain linear elasticity; quadratic in positions, constant SPD tangent."""

    project_tangent = False

    def density(self, fmat):
        """``mu |eps|² + lam/2 tr(eps)²`` [J/m³], shape (B, T)."""
        eps = 0.5 * (fmat + fmat.transpose(-1, -2)) - _eye(fmat)
        tr = eps.diagonal(dim1=-2, dim2=-1).sum(-1)
        return self.mu * (eps * eps).sum((-1, -2)) + 0.5 * self.lam * tr * tr

    def stress(self, fmat):
        """``2 mu eps + lam tr(eps) I`` [Pa], shape (B, T, 3, 3)."""
        eye = _eye(fmat)
        eps = 0.5 * (fmat + fmat.transpose(-1, -2)) - eye
        tr = eps.diagonal(dim1=-2, dim2=-1).sum(-1)
        return 2.0 * self.mu[..., None, None] * eps + (self.lam * tr)[..., None, None] * eye

    def tangent(self, fmat):
        """``mu (d_ik d_jl + d_il d_jk) + lam d_ij d_kl`` [Pa], shape (B, T, 3, 3, 3, 3)."""
        eye = _eye(fmat)
        sym = torch.einsum("ik,jl->ijkl", eye, eye) + torch.einsum("il,jk->ijkl", eye, eye)
        vol = torch.einsum("ij,kl->ijkl", eye, eye)
        mu = self.mu[..., None, None, None, None]
        lam = self.lam[..., None, None, None, None]
        return mu * sym + lam * vol


def _signed_polar(fmat: torch.Tensor):
    """``F = R S`` with ``R`` a rotation (det +1) even for inverted ``F``.

    Returns ``(R, S, V, sigma)`` with ``S = V diag(sigma) V^T`` and the smallest singular
    value carrying the sign of ``det F`` (Irving et al. 2004).
    """
    u, sigma, vh = torch.linalg.svd(fmat)
    v = vh.transpose(-1, -2)
    flip_u = torch.det(u) < 0
    flip_v = torch.det(v) < 0
    sign = torch.ones_like(sigma)
    sign[..., 2] = torch.where(flip_u ^ flip_v, -1.0, 1.0).to(sigma)
    col = torch.ones_like(sigma)
    col_u, col_v = col.clone(), col.clone()
    col_u[..., 2] = torch.where(flip_u, -1.0, 1.0).to(sigma)
    col_v[..., 2] = torch.where(flip_v, -1.0, 1.0).to(sigma)
    u = u * col_u[..., None, :]
    v = v * col_v[..., None, :]
    sigma = sigma * sign
    rot = u @ v.transpose(-1, -2)
    sym = (v * sigma[..., None, :]) @ v.transpose(-1, -2)
    return rot, sym, v, sigma


def _hat(w: torch.Tensor) -> torch.Tensor:
    """Skew matrix of axial vectors (..., 3) -> (..., 3, 3)."""
    zero = torch.zeros_like(w[..., 0])
    x, y, z = w.unbind(-1)
    return torch.stack(
        [
            torch.stack([zero, -z, y], -1),
            torch.stack([z, zero, -x], -1),
            torch.stack([-y, x, zero], -1),
        ],
        -2,
    )


@dataclasses.dataclass(frozen=True)
class EnergyTetCorotated(_LameEnergy):
    """Corotated elasticity (McAdams et al. 2011): exact stress and tangent via the polar R."""

    def density(self, fmat):
        """``mu |F - R|² + lam/2 tr(S - I)²`` [J/m³], shape (B, T)."""
        rot, sym, _, _ = _signed_polar(fmat)
        tr = sym.diagonal(dim1=-2, dim2=-1).sum(-1) - 3.0
        return self.mu * ((fmat - rot) ** 2).sum((-1, -2)) + 0.5 * self.lam * tr * tr

    def stress(self, fmat):
        """``2 mu (F - R) + lam tr(S - I) R`` [Pa], shape (B, T, 3, 3)."""
        rot, sym, _, _ = _signed_polar(fmat)
        tr = sym.diagonal(dim1=-2, dim2=-1).sum(-1) - 3.0
        return (
            2.0 * self.mu[..., None, None] * (fmat - rot) + (self.lam * tr)[..., None, None] * rot
        )

    def tangent(self, fmat):
        """Exact ``dP/dF`` with ``dR = R hat(w)``, ``w = (tr S I - S)^-1 vee(R^T dF - dF^T R)``."""
        rot, _, v, sigma = _signed_polar(fmat)
        tr = sigma.sum(-1) - 3.0
        # (tr S I - S)^-1 in the eigenbasis of S; pairs sigma_i + sigma_j ~ 0 are clamped.
        pair = torch.stack(
            [
                sigma[..., 1] + sigma[..., 2],
                sigma[..., 0] + sigma[..., 2],
                sigma[..., 0] + sigma[..., 1],
            ],
            -1,
        )
        pair = torch.where(pair.abs() < 1e-6, torch.full_like(pair, 1e-6), pair)
        inv = (v / pair[..., None, :]) @ v.transpose(-1, -2)
        basis = torch.eye(9, dtype=fmat.dtype, device=fmat.device).reshape(9, 3, 3)
        mu = self.mu[..., None, None, None]
        lam = self.lam[..., None, None, None]
        rtdf = torch.einsum("btki,dkj->btdij", rot, basis)  # R^T dF for each basis dF
        skew = rtdf - rtdf.transpose(-1, -2)
        vee = torch.stack([skew[..., 2, 1], skew[..., 0, 2], skew[..., 1, 0]], -1)
        omega = torch.einsum("btij,btdj->btdi", inv, vee)
        drot = rot[:, :, None] @ _hat(omega)
        tr_dS = rtdf.diagonal(dim1=-2, dim2=-1).sum(-1)  # tr(R^T dF) = tr(dS)
        dp = (
            2.0 * mu * basis
            + (lam * tr[..., None, None, None] - 2.0 * mu) * drot
            + lam * tr_dS[..., None, None] * rot[:, :, None]
        )  # (B, T, 9 directions, 3, 3)
        return dp.permute(0, 1, 3, 4, 2).reshape(*fmat.shape[:2], 3, 3, 3, 3)


@dataclasses.dataclass(frozen=True)
class EnergyTetStVK(_LameEnergy):
    """St Venant-Kirchhoff; finite everywhere but softens (and may collapse) in compression."""

    def density(self, fmat):
        """``mu |E|² + lam/2 tr(E)²`` [J/m³], shape (B, T)."""
        green = 0.5 * (fmat.transpose(-1, -2) @ fmat - _eye(fmat))
        tr = green.diagonal(dim1=-2, dim2=-1).sum(-1)
        return self.mu * (green * green).sum((-1, -2)) + 0.5 * self.lam * tr * tr

    def _pk2(self, fmat):
        green = 0.5 * (fmat.transpose(-1, -2) @ fmat - _eye(fmat))
        tr = green.diagonal(dim1=-2, dim2=-1).sum(-1)
        return 2.0 * _scalar(self.mu) * green + _scalar(self.lam * tr) * _eye(fmat)

    def stress(self, fmat):
        """``P = F S``, ``S = 2 mu E + lam tr(E) I`` [Pa], shape (B, T, 3, 3)."""
        return fmat @ self._pk2(fmat)

    def tangent(self, fmat):
        """``dF S + F (2 mu dE + lam tr(dE) I)`` as a 4-index tensor [Pa]."""
        ffT = fmat @ fmat.transpose(-1, -2)
        return (
            _right(self._pk2(fmat))
            + _scalar4(self.mu) * (_left(ffT) + _swap(fmat))
            + _scalar4(self.lam) * _outer(fmat, fmat)
        )


@dataclasses.dataclass(frozen=True)
class EnergyTetNeoHookean(_LameEnergy):
    """Stable neo-Hookean (Smith et al. 2018), matched to ``(mu, lam)`` at small strain.

    ``Psi = mu'/2 (I_C - 3) + lam'/2 (J - alpha)² - mu'/2 log(I_C + 1) - Psi(I)`` with
    ``mu' = 4/3 mu``, ``lam' = lam + 5/6 mu``, ``alpha = 1 + 3 mu' / (4 lam')``.
    """

    def density(self, fmat):
        """Energy density [J/m³], zero at rest, shape (B, T)."""
        mu = 4.0 / 3.0 * self.mu
        lam = self.lam + 5.0 / 6.0 * self.mu
        alpha = 1.0 + 0.75 * mu / lam
        ic = (fmat * fmat).sum((-1, -2))
        det = torch.linalg.det(fmat)
        rest = 0.5 * lam * (1.0 - alpha) ** 2 - 0.5 * mu * math.log(4.0)
        return (
            0.5 * mu * (ic - 3.0)
            + 0.5 * lam * (det - alpha) ** 2
            - 0.5 * mu * torch.log(ic + 1.0)
            - rest
        )

    def _coeffs(self, fmat):
        mu = 4.0 / 3.0 * self.mu
        lam = self.lam + 5.0 / 6.0 * self.mu
        alpha = 1.0 + 0.75 * mu / lam
        ic = (fmat * fmat).sum((-1, -2))
        return mu, lam, alpha, ic, torch.linalg.det(fmat), _cofactor(fmat)

    def stress(self, fmat):
        """``mu' F (1 - 1/(I_C + 1)) + lam' (J - alpha) cof F`` [Pa], shape (B, T, 3, 3)."""
        mu, lam, alpha, ic, det, cof = self._coeffs(fmat)
        return _scalar(mu * (1.0 - 1.0 / (ic + 1.0))) * fmat + _scalar(lam * (det - alpha)) * cof

    def tangent(self, fmat):
        """Exact ``dP/dF`` [Pa], shape (B, T, 3, 3, 3, 3)."""
        mu, lam, alpha, ic, det, cof = self._coeffs(fmat)
        eye4 = _right(_eye(fmat).expand_as(fmat))
        return (
            _scalar4(mu * (1.0 - 1.0 / (ic + 1.0))) * eye4
            + _scalar4(2.0 * mu / (ic + 1.0) ** 2) * _outer(fmat, fmat)
            + _scalar4(lam) * _outer(cof, cof)
            + _scalar4(lam * (det - alpha)) * _det_hessian(fmat)
        )


def _pow_extended(det: torch.Tensor, power: float, order: int = 0) -> torch.Tensor:
    """``J^-power`` (``order`` 0) or its first or second derivative (1, 2).

    Below J_EXTEND: the second-order Taylor expansion at J_EXTEND (C² in J, finite for J <= 0).
    """
    jc = J_EXTEND
    safe = torch.clamp(det, min=jc)
    d = det - jc
    h0 = jc ** (-power)
    h1 = -power * jc ** (-power - 1.0)
    h2 = power * (power + 1.0) * jc ** (-power - 2.0)
    if order == 0:
        main, ext = safe ** (-power), h0 + h1 * d + 0.5 * h2 * d * d
    elif order == 1:
        main, ext = -power * safe ** (-power - 1.0), h1 + h2 * d
    else:
        main, ext = power * (power + 1.0) * safe ** (-power - 2.0), h2 + 0.0 * d
    return torch.where(det >= jc, main, ext)


@dataclasses.dataclass(frozen=True)
class EnergyTetMooneyRivlin(_EnergyTet):
    """*thesis* eq. 3.8 Mooney-Rivlin with a large volumetric term for near-incompressibility.

    Small-strain equivalents (tested): shear modulus ``mu = 5 mu1 + 2 mu2``, bulk
    modulus ``kappa = 2 v1`` (see :meth:`small_strain_lame`).
    """

    mu1: torch.Tensor
    """First distortional parameter [Pa], shape (B, T)."""
    mu2: torch.Tensor
    """Second distortional parameter [Pa], shape (B, T)."""
    v1: torch.Tensor
    """Volumetric parameter [Pa], shape (B, T); large and fixed in the thesis."""
    tet_subset: torch.Tensor | None = None
    """Ids of the tets this material occupies, int64 (T',); ``None`` for the whole mesh."""

    def __post_init__(self):
        for name in ("mu1", "mu2", "v1"):
            _param(getattr(self, name), name)
        if not bool((5.0 * self.mu1 + 2.0 * self.mu2 > 0).all()):
            raise MaterialError("mu1, mu2: the shear modulus 5 mu1 + 2 mu2 must be > 0 Pa")
        if not bool((self.v1 > 0).all()):
            raise MaterialError("v1 must be > 0 Pa (volumetric stiffness)")

    def small_strain_lame(self) -> tuple[torch.Tensor, torch.Tensor]:
        """``(mu, lam)`` [Pa] of the linearisation at rest, each (B, T)."""
        mu = 5.0 * self.mu1 + 2.0 * self.mu2
        return mu, 2.0 * self.v1 - 2.0 / 3.0 * mu

    def density(self, fmat):
        """Energy density [J/m³], zero at rest, shape (B, T)."""
        cmat = fmat.transpose(-1, -2) @ fmat
        i1 = cmat.diagonal(dim1=-2, dim2=-1).sum(-1)
        i2 = 0.5 * (i1 * i1 - (cmat * cmat).sum((-1, -2)))
        det = torch.linalg.det(fmat)
        return (
            0.5 * self.mu1 * ((i1 * i1 - i2) * _pow_extended(det, 4.0 / 3.0) - 6.0)
            + self.mu2 * (i1 * _pow_extended(det, 2.0 / 3.0) - 3.0)
            + self.v1 * (det - 1.0) ** 2
        )

    def _terms(self, fmat):
        cmat = fmat.transpose(-1, -2) @ fmat
        i1 = cmat.diagonal(dim1=-2, dim2=-1).sum(-1)
        q = 0.5 * (i1 * i1 + (cmat * cmat).sum((-1, -2)))  # I1² - I2
        dq = 2.0 * _scalar(i1) * fmat + 2.0 * fmat @ cmat
        det = torch.linalg.det(fmat)
        g4 = [_pow_extended(det, 4.0 / 3.0, k) for k in range(3)]
        g2 = [_pow_extended(det, 2.0 / 3.0, k) for k in range(3)]
        return cmat, i1, q, dq, det, _cofactor(fmat), g4, g2

    def stress(self, fmat):
        """``dPsi/dF`` [Pa], shape (B, T, 3, 3)."""
        _, i1, q, dq, det, cof, g4, g2 = self._terms(fmat)
        m1, m2 = 0.5 * self.mu1, self.mu2
        return (
            _scalar(m1 * g4[0]) * dq
            + _scalar(m1 * q * g4[1] + m2 * i1 * g2[1] + 2.0 * self.v1 * (det - 1.0)) * cof
            + _scalar(2.0 * m2 * g2[0]) * fmat
        )

    def tangent(self, fmat):
        """Exact ``dP/dF`` [Pa], shape (B, T, 3, 3, 3, 3)."""
        cmat, i1, q, dq, det, cof, g4, g2 = self._terms(fmat)
        m1, m2 = 0.5 * self.mu1, self.mu2
        eye4 = _right(_eye(fmat).expand_as(fmat))
        ffT = fmat @ fmat.transpose(-1, -2)
        hess_q = (
            4.0 * _outer(fmat, fmat)
            + 2.0 * _scalar4(i1) * eye4
            + 2.0 * (_right(cmat) + _left(ffT) + _swap(fmat))
        )
        hess_j = _det_hessian(fmat)
        jj = _outer(cof, cof)
        return (
            _scalar4(m1 * g4[0]) * hess_q
            + _scalar4(m1 * g4[1]) * (_outer(dq, cof) + _outer(cof, dq))
            + _scalar4(m1 * q * g4[2] + m2 * i1 * g2[2] + 2.0 * self.v1) * jj
            + _scalar4(m1 * q * g4[1] + m2 * i1 * g2[1] + 2.0 * self.v1 * (det - 1.0)) * hess_j
            + _scalar4(2.0 * m2 * g2[0]) * eye4
            + _scalar4(2.0 * m2 * g2[1]) * (_outer(fmat, cof) + _outer(cof, fmat))
        )
