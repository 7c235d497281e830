"""Batched implicit solver core; cloth, tissue, calibration and monocular wings sit above it.

The core (this package's top-level modules and ``energies/``, ``forces/``, ``integrators/``,
``solvers/``, ``kernels/``) knows meshes, models, energies and solvers, never a fabric or an
organ. The wings import the core and never the other way round (an import-linter contract in
CI): :mod:`simulator.cloth` (fabrics, subspace, scenes, rollouts), :mod:`simulator.tissue`
(organ meshes and scenes), :mod:`simulator.calibrate` (PSO, UKF), :mod:`simulator.monocular`
(the paper's reconstruction).

Shape legend used in every docstring:

* ``B`` batch: one material x scenario instance (PSO particles / UKF sigma points later);
* ``V`` vertices, ``F`` triangles, ``E`` interior bending edges, ``P`` pinned vertices;
* ``T`` tetrahedra, ``R`` material regions (tissue);
* ``K`` recorded frames; ``C`` capsule obstacles.

Arrays are row-major ``(N, 3)``; positions in metres, SI units throughout. Only
torch and numpy are imported here (no hydra / lightning / pyrender / cv2).
"""

from .errors import InputError, MaterialError
from .integrators import (
    IntegratorBackwardEuler,
    IntegratorNewmark,
    SimulationDiverged,
    solve_static,
)
from .mesh import MeshError, TriMesh
from .model import SimControl, SimModel, SimState
from .sequence import MeshSequence
from .solvers import NewtonSettings, StepStats
from .tetmesh import TetMesh

__all__ = [
    "InputError",
    "IntegratorBackwardEuler",
    "IntegratorNewmark",
    "MaterialError",
    "MeshError",
    "MeshSequence",
    "NewtonSettings",
    "SimControl",
    "SimModel",
    "SimState",
    "SimulationDiverged",
    "StepStats",
    "TetMesh",
    "TriMesh",
    "solve_static",
]
