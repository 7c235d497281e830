"""Named physical effects: each a switch, composable, with its own parameters.

The sim-to-real study turns these on and off one at a time, so every effect
is independent of the others and documented in one line here.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from common.configs import switches_from_dict
from common.effect_fields import strength

__all__ = ["PHYSICS_EFFECT_NAMES", "PhysicsEffects", "strength"]

_DENSITY_STREAM = 4
"""Random stream of the density factors (1: wind yaw, 2: arm offset, 3: flatness noise)."""


@dataclasses.dataclass(frozen=True)
class PhysicsEffects:
    """Switches (and parameters) of the unmodelled-by-default physical effects."""

    aero_lift: bool = False
    """Thin-plate lift perpendicular to the relative air flow (C_l = ``lift_coefficient``)."""
    air_damping: bool = False
    """Isotropic linear drag relative to the air, ``air_damping_coefficient`` kg/(m²·s)."""
    isotropic_drag: bool = False
    """A share ``drag_isotropy`` of the wind drag blind to the cloth's orientation."""
    gusty_wind: bool = False
    """Wind varying in space and time (random travelling waves, ``gust_amplitude`` of the mean)."""
    self_collision: bool = False
    """Repulsion between non-neighbouring cloth vertices closer than ``self_collision_radius``."""
    internal_damping: bool = False
    """Strain-rate (stiffness-proportional Rayleigh) damping, time ``internal_damping_beta`` s."""
    strain_dependent_stiffness: bool = True
    """Stiffness follows the measured strain/curvature samples; off = zero-strain values only."""
    anisotropic_stiffness: bool = True
    """Direction-dependent stiffness as measured; off = isotropic average."""
    density_variation: bool = False
    """Each cloth weighs its class's density times a log-uniform factor of log-width
    ``density_spread``, one draw per simulation from its seed (:meth:`density_factors`)."""

    lift_coefficient: float = strength(0.5, "aero_lift", 0.1, 1.2)
    """Thin flat plates reach C_l of about 1 before stall."""
    air_damping_coefficient: float = strength(0.05, "air_damping", 0.01, 0.3)
    drag_isotropy: float = strength(1.0, "isotropic_drag", 0.25, 1.0)
    """From mostly normal pressure drag to a point-body fluid model's drag (all of it)."""
    gust_amplitude: float = strength(0.4, "gusty_wind", 0.1, 0.8)
    """Fan and outdoor turbulence intensities span roughly 10-80 % of the mean speed."""
    gust_modes: int = 4
    self_collision_radius: float = strength(0.012, "self_collision", 0.004, 0.02)
    """From about the cloth's thickness to a coarse mesh's edge length [m]."""
    internal_damping_beta: float = strength(2.0e-3, "internal_damping", 2.0e-4, 1.0e-2)
    density_spread: float = strength(0.45, "density_variation", 0.1, 1.1)
    """ln(heaviest / lightest): 0.45 is x 0.8-1.25; the ten measured fabrics span about 1.05."""

    def __post_init__(self):
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            if field.type == "bool" and not isinstance(value, bool):
                raise ValueError(f"effects.{field.name} must be true or false, got {value!r}")
        for name in (
            "lift_coefficient",
            "air_damping_coefficient",
            "drag_isotropy",
            "gust_amplitude",
            "self_collision_radius",
            "internal_damping_beta",
            "density_spread",
        ):
            if not getattr(self, name) >= 0:
                raise ValueError(f"effects.{name} must be >= 0, got {getattr(self, name)}")
        if not self.drag_isotropy <= 1:
            raise ValueError(f"effects.drag_isotropy must be <= 1, got {self.drag_isotropy}")
        if self.gust_modes < 1:
            raise ValueError(f"effects.gust_modes must be >= 1, got {self.gust_modes}")

    def enabled(self) -> dict[str, bool]:
        """The switch values by name."""
        return {name: getattr(self, name) for name in PHYSICS_EFFECT_NAMES}

    def density_factors(self, seeds: Sequence[int]) -> np.ndarray:
        """Areal-density factor of each simulation: exp(spread * u), u uniform in [-1/2, 1/2].

        Ones while ``density_variation`` is off. Fabrics of one stiffness class differ in
        weight (the measured ones by a factor of almost 3), and a heavier cloth of the same
        stiffness sags and flutters like a softer one; the factor comes from the seed alone
        (a stream of its own), so the same simulation is the same cloth in every domain.
        """
        if not self.density_variation:
            return np.ones(len(seeds))
        u = [np.random.default_rng([int(s), _DENSITY_STREAM]).uniform(-0.5, 0.5) for s in seeds]
        return np.exp(self.density_spread * np.asarray(u, dtype=np.float64))

    @staticmethod
    def from_dict(values: dict | None) -> PhysicsEffects:
        """Build from a (config) mapping; unknown keys raise, naming them and the allowed keys."""
        return switches_from_dict(PhysicsEffects, values, "effects")


PHYSICS_EFFECT_NAMES: tuple[str, ...] = tuple(
    f.name for f in dataclasses.fields(PhysicsEffects) if f.type == "bool"
)
