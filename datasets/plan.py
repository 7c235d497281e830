"""Which simulations a dataset runs, which split each belongs to, and how they batch.

Every simulation is one (class, simulation index) pair with its own seed, wind strength,
texture and background. Splits are drawn per class over whole simulations, so no clip of a
validation or test simulation is ever in training. Simulations are grouped into work units:
one batched rollout each, rendered into one shard per split. Everything here is a pure
function of the :class:`~datasets.spec.DatasetSpec`, so any worker (or cluster job) can
rebuild the plan and pick its units.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .spec import DatasetSpec

__all__ = ["SimulationPlan", "WorkUnit", "plan_units", "simulation_seed"]

_SPLIT_STREAM = 7
_SEED_STREAM = 11


@dataclasses.dataclass(frozen=True)
class SimulationPlan:
    """One simulation: a class, its index among the class's simulations, seed and split."""

    class_id: int
    sim_index: int
    seed: int
    """Seeds the scene (initial noise, wind yaw / arm offset), texture, background, effects."""
    wind_level: int
    """0, 1, 2 = W1, W2, W3 (cycled over simulation indices; unused by the arm scene)."""
    split: str

    @property
    def sim_id(self) -> str:
        """Stable name of the simulation, unique in a dataset."""
        return f"c{self.class_id:02d}-s{self.sim_index:02d}"


@dataclasses.dataclass(frozen=True)
class WorkUnit:
    """Simulations run as one batch and written as one group of shards."""

    index: int
    sims: tuple[SimulationPlan, ...]

    @property
    def name(self) -> str:
        """File stem of the unit's shards and index."""
        return f"unit-{self.index:04d}"


def simulation_seed(dataset_seed: int, class_id: int, sim_index: int) -> int:
    """Seed of one simulation, independent of the other simulations and of the splits."""
    seq = np.random.SeedSequence([int(dataset_seed), _SEED_STREAM, int(class_id), int(sim_index)])
    return int(seq.generate_state(1, dtype=np.uint32)[0])


def _splits_of_class(spec: DatasetSpec, class_id: int) -> list[str]:
    preset = spec.preset
    rng = np.random.default_rng([spec.seed, _SPLIT_STREAM, class_id])
    order = rng.permutation(preset.sims_per_class)
    splits = ["train"] * preset.sims_per_class
    for rank, sim_index in enumerate(order):
        if rank < preset.test_sims_per_class:
            splits[sim_index] = "test"
        elif rank < preset.test_sims_per_class + preset.val_sims_per_class:
            splits[sim_index] = "val"
    return splits


def plan_units(spec: DatasetSpec) -> list[WorkUnit]:
    """All work units of the dataset, in a fixed order.

    Unit order is simulation index major, class minor: each unit holds one simulation of
    up to ``spec.unit_size`` classes, so every unit mixes the whole stiffness range (batches
    with similar per-instance solver cost) and a partial run covers all classes.
    """
    wind_count = len(getattr(spec.scenario, "wind_speeds", (0.0,)))
    splits = {c: _splits_of_class(spec, c) for c in spec.classes}
    sims = [
        SimulationPlan(
            class_id=c,
            sim_index=j,
            seed=simulation_seed(spec.seed, c, j),
            wind_level=j % wind_count,
            split=splits[c][j],
        )
        for j in range(spec.preset.sims_per_class)
        for c in spec.classes
    ]
    size = spec.unit_size
    return [
        WorkUnit(index=i, sims=tuple(sims[start : start + size]))
        for i, start in enumerate(range(0, len(sims), size))
    ]
