"""Assemble a cloth :class:`SimModel` from a mesh, materials and effect switches."""

from __future__ import annotations

import enum

import torch

from simulator.cloth.effects import PhysicsEffects
from simulator.cloth.material import ClothMaterial
from simulator.energies import (
    EnergyBendingDihedral,
    EnergyContactCapsule,
    EnergyGravity,
    EnergyMassSpring,
    EnergyMembraneWang,
    EnergySelfCollision,
)
from simulator.forces import (
    AerodynamicDrag,
    AerodynamicLift,
    AirDamping,
    FrictionCapsule,
    StrainRateDamping,
)
from simulator.mesh import TriMesh
from simulator.model import SimModel

__all__ = ["GRAVITY", "ClothModelKind", "build_cloth_model"]

GRAVITY = (0.0, 0.0, -9.81)
"""Gravitational acceleration [m/s²] (z up)."""


class ClothModelKind(enum.StrEnum):
    """The two cloth force models."""

    DISCRETE_SHELL = "discrete_shell"
    MASS_SPRING = "mass_spring"


def build_cloth_model(
    mesh: TriMesh,
    material: ClothMaterial,
    pin_indices: torch.Tensor,
    *,
    kind: ClothModelKind | str = ClothModelKind.DISCRETE_SHELL,
    effects: PhysicsEffects | None = None,
    wind_drag: bool = True,
    capsule_contact: bool = False,
    friction: float = 0.5,
) -> SimModel:
    """Build the model of B cloth instances sharing ``mesh``.

    Args:
        mesh: shared topology and rest shape.
        material: per-instance parameters (B of them).
        pin_indices: Dirichlet vertices, int64 (P,).
        kind: ``discrete_shell`` (Wang membrane + dihedral bending) or ``mass_spring``.
        effects: physical effect switches (defaults: all off, measured stiffness model).
        wind_drag: include aerodynamic normal drag (needed whenever air moves or cloth flies).
        capsule_contact: include penalty contact and friction with capsule obstacles.
        friction: Coulomb coefficient for capsule contact.
    """
    effects = effects or PhysicsEffects()
    try:
        kind = ClothModelKind(kind)
    except ValueError as err:
        allowed = [k.value for k in ClothModelKind]
        raise ValueError(f"cloth model kind must be one of {allowed}, got {kind!r}") from err
    dtype, device = mesh.vert_pos.dtype, mesh.vert_pos.device
    material = material.to(device=device, dtype=dtype)
    if kind is ClothModelKind.DISCRETE_SHELL:
        elastic = (
            EnergyMembraneWang.from_material(
                material.stretching,
                strain_dependent=effects.strain_dependent_stiffness,
                anisotropic=effects.anisotropic_stiffness,
            ),
            EnergyBendingDihedral.from_material(
                mesh,
                material.bending,
                curvature_dependent=effects.strain_dependent_stiffness,
                anisotropic=effects.anisotropic_stiffness,
            ),
        )
    else:
        elastic = (EnergyMassSpring.from_material(mesh, material.stretching, material.bending),)
    energies = [*elastic, EnergyGravity(torch.tensor(GRAVITY, dtype=dtype, device=device))]
    forces = []
    if capsule_contact:
        energies.append(EnergyContactCapsule())
        forces.append(FrictionCapsule(mu=friction))
    if effects.self_collision:
        energies.append(EnergySelfCollision(radius=effects.self_collision_radius))
    if wind_drag:
        isotropy = effects.drag_isotropy if effects.isotropic_drag else 0.0
        forces.append(AerodynamicDrag(isotropy=isotropy))
    if effects.aero_lift:
        forces.append(AerodynamicLift(lift_coefficient=effects.lift_coefficient))
    if effects.air_damping:
        forces.append(AirDamping(coefficient=effects.air_damping_coefficient))
    if effects.internal_damping:
        forces.append(StrainRateDamping(beta=effects.internal_damping_beta))
    vert_mass = material.density[:, None] * mesh.vert_area[None, :]
    model = SimModel(
        mesh=mesh,
        energies=tuple(energies),
        forces=tuple(forces),
        vert_mass=vert_mass,
        pin_indices=pin_indices.to(device),
    )
    return model.with_pattern()
