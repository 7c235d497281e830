"""Time integrators and the static equilibrium solve."""

from .backward_euler import IntegratorBackwardEuler, solve_static
from .base import IncrementalPotential, SimulationDiverged

__all__ = ["IncrementalPotential", "IntegratorBackwardEuler", "SimulationDiverged", "solve_static"]
