"""Our cloth's material in MuJoCo's 2D flex terms: one mapping for every MuJoCo scene.

The flex membrane is a Saint Venant-Kirchhoff shell whose stretching energy per unit area is
``t`` times the plane-stress density, so ``E t`` is the stretch stiffness; its hinge bending
rigidity is ``D = E t^3 / (12 (1 - nu^2))``, which fixes ``t``. Used by the independent-engine
footage (:mod:`sim2real.study.independent`) and the solver-speed peer benchmark
(``benchmarks/mujoco_cloth.py``).
"""

from __future__ import annotations

import math

__all__ = ["AIR_DENSITY_KG_M3", "AIR_VISCOSITY_PA_S", "elastic_params"]

AIR_DENSITY_KG_M3 = 1.2
AIR_VISCOSITY_PA_S = 1.8e-5
STRETCH_ONLY_THICKNESS_M = 1e-3
"""Thickness [m] of a flex without bending stiffness (``elastic2d="stretch"``)."""


def elastic_params(
    stretch_stiffness_n_per_m: float, poisson: float, bend_stiffness_nm: float
) -> tuple[float, float, str]:
    """Return ``(young_pa, thickness_m, elastic2d)`` matching the membrane and bending stiffness."""
    if stretch_stiffness_n_per_m <= 0.0:
        raise ValueError("stretch_stiffness_n_per_m must be positive")
    if not 0.0 <= poisson < 0.5:
        raise ValueError("poisson must lie in [0, 0.5)")
    if bend_stiffness_nm < 0.0:
        raise ValueError("bend_stiffness_nm must be non-negative")
    if bend_stiffness_nm > 0.0:
        # E t = k_s and E t^3 / (12 (1 - nu^2)) = D  =>  t^2 = 12 (1 - nu^2) D / k_s.
        thickness = math.sqrt(
            12.0 * (1.0 - poisson**2) * bend_stiffness_nm / stretch_stiffness_n_per_m
        )
        mode = "both"
    else:
        # MuJoCo 4.0.0 compiles "stretch" with a spurious warning ("not rigid and has no ... passive
        # forces", also appended to MUJOCO_LOG.TXT in the cwd) although the membrane force works.
        thickness = STRETCH_ONLY_THICKNESS_M
        mode = "stretch"
    return stretch_stiffness_n_per_m / thickness, thickness, mode
