"""Hydra entry point of dataset generation (configs/generate.yaml).

``python -m datasets.generate motion=wind preset=full level=2 texture=random seed=0``
writes shards, unit indices and the manifest into ``out_dir`` (see
:mod:`datasets.manifest` for the layout); running it again resumes.
"""

from __future__ import annotations

import logging

import hydra
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf

from render.effects import VisualEffects
from simulator.effects import PhysicsEffects
from simulator.threads import use_process_threads

from .generation import generate_dataset
from .spec import MOTIONS, DatasetSpec

log = logging.getLogger(__name__)


def _plain(node) -> dict:
    values = OmegaConf.to_container(node, resolve=True) if node is not None else {}
    values.pop("_target_", None)
    return values


def spec_from_config(cfg: DictConfig) -> DatasetSpec:
    """Build the validated :class:`DatasetSpec` of a generate config."""
    motion = str(cfg.motion)
    if motion not in MOTIONS:
        raise ValueError(f"motion must be one of {sorted(MOTIONS)}, got {motion!r}")
    classes = cfg.classes
    kwargs = {} if classes is None else {"classes": tuple(int(c) for c in classes)}
    return DatasetSpec(
        motion=motion,
        scenario=instantiate(cfg.scenario),
        preset=instantiate(cfg.preset),
        texture_mode=str(cfg.texture),
        seed=int(cfg.seed),
        lead_in=float(cfg.lead_in),
        sim=instantiate(cfg.sim),
        physics=PhysicsEffects.from_dict(_plain(cfg.effects)),
        camera=instantiate(cfg.render.camera),
        lights=instantiate(cfg.render.lights),
        visual=VisualEffects.from_dict(_plain(cfg.render.effects)),
        supersample=int(cfg.render.supersample),
        texture_size=int(cfg.texture_size),
        store_coverage=bool(cfg.render.store_coverage),
        store_passes=bool(cfg.render.get("store_passes", False)),
        sims_per_unit=int(cfg.sims_per_unit),
        **kwargs,
    )


def run(cfg: DictConfig):
    """Generate (or resume) the configured dataset; returns the manifest or ``None``."""
    spec = spec_from_config(cfg)
    use_process_threads(int(cfg.threads_per_job), name="threads_per_job")
    return generate_dataset(
        spec,
        cfg.out_dir,
        n_jobs=int(cfg.n_jobs),
        threads_per_job=int(cfg.threads_per_job),
        worker_index=int(cfg.worker.index),
        worker_count=int(cfg.worker.count),
        mesh_cache=cfg.mesh_cache,
        overwrite=bool(cfg.overwrite),
        max_units=None if cfg.max_units is None else int(cfg.max_units),
    )


@hydra.main(version_base="1.3", config_path="../configs", config_name="generate")
def main(cfg: DictConfig) -> None:
    """Hydra wrapper around :func:`run`."""
    run(cfg)


if __name__ == "__main__":
    main()
