"""Internal (strain-rate) damping: stiffness-proportional Rayleigh damping.

``f = -beta K(x_n) v`` with ``K`` the solver's PSD stiffness blocks of the elastic
energies at the start of the step, so only deformation rates are damped (rigid
motion is not, since ``K`` annihilates it).
"""

from __future__ import annotations

import dataclasses

from .base import Force, StepForce

__all__ = ["StrainRateDamping"]


@dataclasses.dataclass(frozen=True)
class StrainRateDamping(Force):
    """Rayleigh damping of the elastic terms."""

    beta: float = 2.0e-3
    """Stiffness-proportional damping time [s]."""
    elastic_types: tuple = ()
    """Energy classes counted as elastic; empty means membrane, bending and springs."""

    def linearize(self, model, state, control, energies):
        """``D = beta K`` from the elastic energies' blocks."""
        from ..energies import EnergyBendingDihedral, EnergyMassSpring, EnergyMembraneWang

        kinds = self.elastic_types or (EnergyMembraneWang, EnergyBendingDihedral, EnergyMassSpring)
        parts = [e.hessian_blocks(model, state.pos) for e in energies if isinstance(e, kinds)]
        scaled = tuple(
            dataclasses.replace(p, blocks=self.beta * p.blocks) for p in parts if p is not None
        )
        return StepForce(damping_blocks=scaled)
