"""Conservative energy terms: each gives value, gradient, Hessian products and PSD blocks."""

from .base import ElementBlocks, Energy
from .bending import EnergyBendingDihedral
from .contact import EnergyContactCapsule
from .gravity import EnergyGravity
from .membrane import EnergyMembraneWang
from .self_collision import EnergySelfCollision
from .springs import EnergyMassSpring

__all__ = [
    "ElementBlocks",
    "Energy",
    "EnergyBendingDihedral",
    "EnergyContactCapsule",
    "EnergyGravity",
    "EnergyMassSpring",
    "EnergyMembraneWang",
    "EnergySelfCollision",
]
