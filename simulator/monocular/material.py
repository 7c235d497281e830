"""Isotropic elastic sheet parameters (Young's modulus, Poisson ratio, thickness) with checks.

The paper models a 10 mm silicone slab with tetrahedra; we model it as a thin sheet: a
plane-stress St Venant-Kirchhoff membrane of thickness ``h`` plus Kirchhoff bending with the
plate rigidity ``D = E h³ / (12 (1 - nu²))``. Values are validated here so that every energy
built from them can assume a well-posed law.
"""

from __future__ import annotations

import dataclasses
import math

import torch

__all__ = ["SheetMaterial", "plane_stress_matrix"]


@dataclasses.dataclass(frozen=True)
class SheetMaterial:
    """Homogeneous isotropic sheet material (scalars shared by the batch)."""

    youngs_modulus: float
    """Young's modulus E [Pa], > 0."""
    poisson_ratio: float
    """Poisson ratio nu, in (-1, 0.5)."""
    thickness: float
    """Sheet thickness h [m], > 0."""

    def __post_init__(self):
        if not (math.isfinite(self.youngs_modulus) and self.youngs_modulus > 0):
            raise ValueError(f"youngs_modulus must be > 0 Pa, got {self.youngs_modulus}")
        if not (math.isfinite(self.poisson_ratio) and -1.0 < self.poisson_ratio < 0.5):
            raise ValueError(f"poisson_ratio must lie in (-1, 0.5), got {self.poisson_ratio}")
        if not (math.isfinite(self.thickness) and self.thickness > 0):
            raise ValueError(f"thickness must be > 0 m, got {self.thickness}")

    @property
    def stretch_modulus(self) -> float:
        """Plane-stress membrane modulus ``E h / (1 - nu²)`` [N/m]."""
        return self.youngs_modulus * self.thickness / (1.0 - self.poisson_ratio**2)

    @property
    def bending_rigidity(self) -> float:
        """Plate rigidity ``E h³ / (12 (1 - nu²))`` [N·m]."""
        return self.youngs_modulus * self.thickness**3 / (12.0 * (1.0 - self.poisson_ratio**2))

    def stiffness_rows(self) -> tuple[float, float, float, float]:
        """``(k0, k1, k2, k3)`` [N/m] of the core's membrane law ``W = 1/2(k0 G00² + ...)``.

        Plane stress: ``k0 = k2 = E h / (1 - nu²)``, ``k1 = nu k0``, ``k3 = 4 mu h`` (the core
        writes the shear term with ``G01``, not the engineering strain ``2 G01``).
        """
        k0 = self.stretch_modulus
        mu = self.youngs_modulus / (2.0 * (1.0 + self.poisson_ratio))
        return k0, self.poisson_ratio * k0, k0, 4.0 * mu * self.thickness


def plane_stress_matrix(material: SheetMaterial, *, dtype=torch.float64) -> torch.Tensor:
    """Voigt plane-stress matrix times thickness [N/m] for ``[exx, eyy, 2 exy]``, shape (3, 3)."""
    k = material.stretch_modulus
    nu = material.poisson_ratio
    return torch.tensor(
        [[k, nu * k, 0.0], [nu * k, k, 0.0], [0.0, 0.0, 0.5 * (1.0 - nu) * k]], dtype=dtype
    )
