"""Hydra entry point: simulate subspace classes in a scene and save the mesh sequence.

``python -m simulator.simulate scenario=wind classes=[0,26,53]`` writes
``sequence.npz`` (format in :mod:`simulator.sequence`) into the run directory
and, with ``export=obj``, a frame series of the first instance.
"""

from __future__ import annotations

import logging

import hydra
from hydra.utils import instantiate
from omegaconf import DictConfig

from simulator.effects import PhysicsEffects
from simulator.material import ClothMaterial, class_summary
from simulator.rollout import simulate
from simulator.threads import use_process_threads

log = logging.getLogger(__name__)


def run(cfg: DictConfig):
    """Simulate ``cfg.classes`` and return the saved :class:`MeshSequence`."""
    use_process_threads(cfg.get("threads", 1), name="threads")
    classes = [int(c) for c in cfg.classes]
    material = ClothMaterial.from_classes(classes)
    scenario = instantiate(cfg.scenario)
    settings = instantiate(cfg.sim)
    effects = PhysicsEffects.from_dict({k: v for k, v in cfg.effects.items() if k != "_target_"})
    seeds = [int(cfg.seed) + i for i in range(len(classes))]
    sequence = simulate(
        scenario,
        material,
        seeds=seeds,
        wind_levels=[int(cfg.wind_level)] * len(classes),
        fps=float(cfg.fps),
        record_time=float(cfg.record_time),
        effects=effects,
        settings=settings,
        labels=classes,
        progress=True,
    )
    sequence.meta["classes"] = [class_summary(c) for c in classes]
    path = sequence.save(cfg.out_file)
    log.info("wrote %s (%d instances x %d frames)", path, len(classes), sequence.frame_count)
    if cfg.export:
        paths = sequence.export(path.parent / f"frames_{cfg.export}", fmt=str(cfg.export))
        log.info("exported %d %s frames to %s", len(paths), cfg.export, paths[0].parent)
    return sequence


@hydra.main(version_base="1.3", config_path="../configs", config_name="simulate")
def main(cfg: DictConfig) -> None:
    """Hydra wrapper around :func:`run`."""
    run(cfg)


if __name__ == "__main__":
    main()
