"""Linear and nonlinear batched solvers."""

from .cg import conjugate_gradient
from .newton import NewtonSettings, StepStats, newton_minimize

__all__ = ["NewtonSettings", "StepStats", "conjugate_gradient", "newton_minimize"]
