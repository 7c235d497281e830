"""Garment recovery from a single image (*thesis* chapter 6): a wing on the solver core.

A garment is a parametric sewing pattern (:mod:`.patterns`: skirt, pants, t-shirt with their
sizing parameters G) cut from a fabric with material parameters C (bend and stretch multipliers
of a measured Wang et al. fabric). It is placed around a posable mannequin made of capsules
and spheres (:mod:`.body`, the 15 joints of *thesis* Table 6.3), registered to the body's pose
by linear-blend skinning with interpenetrations removed (:mod:`.skinning`), sewn by a seam
energy and draped to static equilibrium on the shared Newton solver (:mod:`.energies`,
:mod:`.drape`). :mod:`.curvature` measures the wrinkle curvature of Eq. 6.7, :mod:`.image` the
silhouettes and wrinkle densities of images, and :mod:`.recovery` fits G, C and the pose by
particle swarms (Alg. 3 and 4). :mod:`.scenes` renders the synthetic evaluation scenes of
Fig. 6.11, :mod:`.tryon` dresses another body and animates it in wind, and
``python -m simulator.garment.recover`` is the command.

Imports the core, :mod:`simulator.cloth` (fabrics) and :mod:`simulator.calibrate` (the swarm);
nothing else in the simulator imports it. Rendering (:mod:`render`) and OpenCV are imported
lazily by the functions that draw or read images.
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
