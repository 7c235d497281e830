"""Cloth wing: fabrics, the 54-class subspace, scenes, effect switches and rollouts.

Built on the solver core (:mod:`simulator`): :mod:`.material` (measured fabrics, material
sets such as the 54-class subspace), :mod:`.model` (a cloth :class:`~simulator.model.SimModel`
from a mesh, materials and switches), :mod:`.scenes` (wind and arm), :mod:`.wind`,
:mod:`.effects` (the physical switches), :mod:`.rollout` (batched simulation to a mesh
sequence), :mod:`.sensitivity` and the Hydra entry :mod:`.simulate`.
"""

from .effects import PHYSICS_EFFECT_NAMES, PhysicsEffects
from .material import (
    BASIS_MATERIAL,
    BEND_MULTIPLIERS,
    CLASS_COUNT,
    STRETCH_MULTIPLIERS,
    WANG54,
    ClothMaterial,
    MaterialSet,
    WangMaterial,
    class_summary,
    load_wang_material,
    multipliers_from_class,
)
from .model import ClothModelKind, build_cloth_model
from .rollout import SimSettings, simulate
from .scenes import RESOLUTION_LEVELS, ScenarioArmBend, ScenarioWind

__all__ = [
    "BASIS_MATERIAL",
    "BEND_MULTIPLIERS",
    "CLASS_COUNT",
    "PHYSICS_EFFECT_NAMES",
    "RESOLUTION_LEVELS",
    "STRETCH_MULTIPLIERS",
    "WANG54",
    "ClothMaterial",
    "ClothModelKind",
    "MaterialSet",
    "PhysicsEffects",
    "ScenarioArmBend",
    "ScenarioWind",
    "SimSettings",
    "WangMaterial",
    "build_cloth_model",
    "class_summary",
    "load_wang_material",
    "multipliers_from_class",
    "simulate",
]
