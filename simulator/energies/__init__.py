"""Conservative energy terms: each gives value, gradient, Hessian products and PSD blocks."""

from .base import ElementBlocks, Energy
from .bending import EnergyBendingDihedral
from .contact import EnergyContactCapsule
from .gravity import EnergyGravity
from .loads import EnergyNodalForce, surface_traction_forces
from .membrane import EnergyMembraneWang
from .self_collision import EnergySelfCollision
from .springs import EnergyMassSpring
from .tet import (
    EnergyTetCorotated,
    EnergyTetLinear,
    EnergyTetMooneyRivlin,
    EnergyTetNeoHookean,
    EnergyTetStVK,
    lame_from_young_poisson,
    region_values,
)

__all__ = [
    "ElementBlocks",
    "Energy",
    "EnergyBendingDihedral",
    "EnergyContactCapsule",
    "EnergyGravity",
    "EnergyMassSpring",
    "EnergyMembraneWang",
    "EnergyNodalForce",
    "EnergySelfCollision",
    "EnergyTetCorotated",
    "EnergyTetLinear",
    "EnergyTetMooneyRivlin",
    "EnergyTetNeoHookean",
    "EnergyTetStVK",
    "lame_from_young_poisson",
    "region_values",
    "surface_traction_forces",
]
