"""Garments on a posable body (*thesis* chapter 6): a wing on the solver core.

A garment is a parametric sewing pattern (:mod:`.patterns`: skirt, pants, t-shirt with their
sizing parameters G) cut from a fabric with material parameters C (bend and stretch multipliers
of a measured Wang et al. fabric). It is placed around a posable mannequin made of capsules
and spheres (:mod:`.body`, the 15 joints of *thesis* Table 6.3), registered to the body's pose
by linear-blend skinning with interpenetrations removed (:mod:`.skinning`), sewn by a seam
energy and draped to static equilibrium on the shared Newton solver (:mod:`.energies`,
:mod:`.drape`); :mod:`.curvature` measures the wrinkle curvature of Eq. 6.7. Recovering a
garment from an image, the evaluation scenes and try-on are applications on top of this wing
(:mod:`apps.garment`).

Imports the core and :mod:`simulator.cloth` (fabrics);
nothing else in the simulator imports it, and it draws nothing.
"""

from .patterns import (
    GARMENT_TYPES,
    GarmentType,
    ParamSpec,
    Pattern,
    PatternError,
    build_pattern,
    param_specs,
)

__all__ = [
    "GARMENT_TYPES",
    "GarmentType",
    "ParamSpec",
    "Pattern",
    "PatternError",
    "build_pattern",
    "param_specs",
]
