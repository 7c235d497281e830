"""Batched implicit solver core for cloth (and, later, tetrahedral tissue) simulation.

Shape legend used in every docstring:

* ``B`` batch: one material x scenario instance (PSO particles / UKF sigma points later);
* ``V`` vertices, ``F`` triangles, ``E`` interior bending edges, ``P`` pinned vertices;
* ``T`` tetrahedra, ``R`` material regions (tissue);
* ``K`` recorded frames; ``C`` capsule obstacles.

Arrays are row-major ``(N, 3)``; positions in metres, SI units throughout. Only
torch and numpy are imported here (no hydra / lightning / pyrender / cv2).
"""

from .cloth import ClothModelKind, build_cloth_model
from .effects import PHYSICS_EFFECT_NAMES, PhysicsEffects
from .integrators import (
    IntegratorBackwardEuler,
    IntegratorNewmark,
    SimulationDiverged,
    solve_static,
)
from .material import (
    BASIS_MATERIAL,
    BEND_MULTIPLIERS,
    CLASS_COUNT,
    STRETCH_MULTIPLIERS,
    ClothMaterial,
    MaterialError,
    WangMaterial,
    class_summary,
    load_wang_material,
    multipliers_from_class,
)
from .mesh import MeshError, TriMesh
from .model import SimControl, SimModel, SimState
from .rollout import SimSettings, simulate
from .scenario import RESOLUTION_LEVELS, ScenarioArmBend, ScenarioWind
from .sequence import MeshSequence
from .solvers import NewtonSettings, StepStats
from .tetmesh import TetMesh

__all__ = [
    "BASIS_MATERIAL",
    "BEND_MULTIPLIERS",
    "CLASS_COUNT",
    "PHYSICS_EFFECT_NAMES",
    "RESOLUTION_LEVELS",
    "STRETCH_MULTIPLIERS",
    "ClothMaterial",
    "ClothModelKind",
    "IntegratorBackwardEuler",
    "IntegratorNewmark",
    "MaterialError",
    "MeshError",
    "MeshSequence",
    "NewtonSettings",
    "PhysicsEffects",
    "ScenarioArmBend",
    "ScenarioWind",
    "SimControl",
    "SimModel",
    "SimSettings",
    "SimState",
    "SimulationDiverged",
    "StepStats",
    "TetMesh",
    "TriMesh",
    "WangMaterial",
    "build_cloth_model",
    "class_summary",
    "load_wang_material",
    "multipliers_from_class",
    "simulate",
    "solve_static",
]
