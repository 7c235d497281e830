"""Velocity-dependent and non-conservative forces, frozen per step as :class:`StepForce`."""

from .aerodynamics import AerodynamicDrag, AerodynamicLift, AirDamping
from .base import Force, StepForce
from .damping import StrainRateDamping
from .friction import FrictionCapsule

__all__ = [
    "AerodynamicDrag",
    "AerodynamicLift",
    "AirDamping",
    "Force",
    "FrictionCapsule",
    "StepForce",
    "StrainRateDamping",
]
