"""Time integrators and the static equilibrium solve."""

from .backward_euler import IntegratorBackwardEuler, solve_static
from .base import IncrementalPotential, SimulationDiverged
from .newmark import IntegratorNewmark

__all__ = [
    "IncrementalPotential",
    "IntegratorBackwardEuler",
    "IntegratorNewmark",
    "SimulationDiverged",
    "solve_static",
]
