"""Hydra entry point of dataset generation (configs/generate.yaml).

``python -m datasets.generate motion=wind preset=full level=2 texture=random seed=0``
writes shards, unit indices and the manifest into ``out_dir`` (see
:mod:`datasets.manifest` for the layout); running it again resumes.

Every field is checked before the output folder is touched: a bad value ends the command
with one line ``error: <field> must be ...`` (:mod:`common.commands`).
"""

from __future__ import annotations

import logging

from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf

from common.checks import check_bool, check_choice, check_device, check_float, check_int
from common.commands import hydra_command
from common.configs import check_node, config_errors
from common.errors import InputError
from common.paths import check_name, check_output_dir
from render.backgrounds import BACKDROPS
from render.effects import VisualEffects
from render.textures import TextureMode
from simulator.cloth.effects import PhysicsEffects
from simulator.cloth.material import WANG54, MaterialError, MaterialSet
from simulator.cloth.scenes import RESOLUTION_LEVELS
from simulator.threads import use_process_threads

from .generation import generate_dataset
from .spec import MOTIONS, DatasetSpec, SizePreset

log = logging.getLogger(__name__)

_NODES = (
    "sim",
    "scenario",
    "preset",
    "effects",
    "render.camera",
    "render.lights",
    "render.effects",
)
"""Instantiated config nodes, type-checked against their targets before they are built."""


def _plain(node) -> dict:
    values = OmegaConf.to_container(node, resolve=True) if node is not None else {}
    values.pop("_target_", None)
    return values


def material_set_from_config(node) -> MaterialSet:
    """The :class:`MaterialSet` of a ``material_set`` config node (``None``: ``wang54``).

    Raises:
        InputError: naming ``material_set.<field>`` and what it must be.
    """
    if node is None:
        return WANG54
    values = OmegaConf.to_container(node, resolve=True) if OmegaConf.is_config(node) else node
    try:
        return MaterialSet.from_json(values, "material_set")
    except MaterialError as err:
        raise InputError(str(err)) from None


def spec_from_config(cfg: DictConfig, *, preset: SizePreset | None = None) -> DatasetSpec:
    """Build the validated :class:`DatasetSpec` of a generate config.

    Args:
        cfg: A config with the fields of ``configs/generate.yaml`` (``sims_per_unit`` may
            be left out: 0, all classes in one rollout; ``material_set`` too: ``wang54``;
            ``backdrop`` too: ``bank``).
        preset: Use this size preset instead of the config's ``preset`` node
            (:mod:`apps.demo` derives its own from ``fps`` and ``record_time``).

    Raises:
        InputError: naming the first bad field and its allowed values.
    """
    with config_errors():
        motion = check_choice(cfg.motion, "motion", sorted(MOTIONS))
        if not OmegaConf.is_dict(cfg.scenario):  # e.g. scenario=arm_bend: the motion picks it
            raise InputError(
                "scenario must be a scene's fields (scenario.<field>=...); the motion picks the "
                f"scene: motion=wind or motion=arm (configs/motion/), got {cfg.scenario!r}"
            )
        check_int(cfg.level, "level", min(RESOLUTION_LEVELS), max(RESOLUTION_LEVELS))
        texture = check_choice(cfg.texture, "texture", [m.value for m in TextureMode])
        backdrop = check_choice(cfg.get("backdrop", "bank"), "backdrop", list(BACKDROPS))
        material_set = material_set_from_config(cfg.get("material_set"))
        classes = cfg.classes
        kwargs = {"material_set": material_set}
        if classes is not None:
            kwargs["classes"] = material_set.check_class_ids(classes, "classes")
            if len(set(kwargs["classes"])) != len(kwargs["classes"]):
                raise InputError(f"classes must not repeat a class id, got {list(classes)}")
        for name in _NODES:
            if name == "preset" and preset is not None:
                continue
            check_node(OmegaConf.to_container(OmegaConf.select(cfg, name), resolve=True), name)
        check_device(cfg.sim.device, "sim.device")
        return DatasetSpec(
            motion=motion,
            scenario=instantiate(cfg.scenario),
            preset=instantiate(cfg.preset) if preset is None else preset,
            texture_mode=texture,
            backdrop=backdrop,
            seed=check_int(cfg.seed, "seed", 0),
            lead_in=check_float(cfg.lead_in, "lead_in", 0),
            sim=instantiate(cfg.sim),
            physics=PhysicsEffects.from_dict(_plain(cfg.effects)),
            camera=instantiate(cfg.render.camera),
            lights=instantiate(cfg.render.lights),
            visual=VisualEffects.from_dict(_plain(cfg.render.effects)),
            supersample=check_int(cfg.render.supersample, "render.supersample", 1),
            texture_size=check_int(cfg.texture_size, "texture_size", 8),
            store_coverage=check_bool(cfg.render.store_coverage, "render.store_coverage"),
            store_passes=check_bool(cfg.render.get("store_passes", False), "render.store_passes"),
            sims_per_unit=check_int(cfg.get("sims_per_unit", 0), "sims_per_unit", 0),
            **kwargs,
        )


def _run_fields(cfg: DictConfig) -> dict:
    """The run's own fields (not the dataset's), validated."""
    count = check_int(cfg.worker.count, "worker.count", 1)
    return {
        "n_jobs": check_int(cfg.n_jobs, "n_jobs", 1),
        "threads_per_job": check_int(cfg.threads_per_job, "threads_per_job", 1),
        "worker_index": check_int(
            cfg.worker.index, f"worker.index (with worker.count={count})", 0, count - 1
        ),
        "worker_count": count,
        "mesh_cache": _path_or_none(cfg.mesh_cache, "mesh_cache"),
        "overwrite": check_bool(cfg.overwrite, "overwrite"),
        "max_units": None if cfg.max_units is None else check_int(cfg.max_units, "max_units", 0),
    }


def _path_or_none(value, field: str) -> str | None:
    if value is not None and (not isinstance(value, str) or not value.strip()):
        raise InputError(f"{field} must be a folder path or null, got {value!r}")
    return value


def run(cfg: DictConfig):
    """Generate (or resume) the configured dataset; returns the manifest or ``None``."""
    spec = spec_from_config(cfg)
    fields = _run_fields(cfg)
    check_name(spec.preset.name, "preset.name")  # a part of the default out_dir
    out_dir = _path_or_none(cfg.out_dir, "out_dir")
    if out_dir is None:
        raise InputError("out_dir must be a folder path, got null")
    check_output_dir(out_dir, "out_dir")
    if fields["mesh_cache"] is not None:
        check_output_dir(fields["mesh_cache"], "mesh_cache")
    use_process_threads(fields["threads_per_job"], name="threads_per_job")
    return generate_dataset(spec, out_dir, **fields)


main = hydra_command(run, config_name="generate")
"""The command line: ``python -m datasets.generate`` (``configs/generate.yaml``)."""


if __name__ == "__main__":
    main()
