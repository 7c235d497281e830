"""Hydra entry point: simulate subspace classes in a scene and save the mesh sequence.

``python -m simulator.cloth.simulate scene=wind classes=[0,26,53]`` writes
``sequence.npz`` (format in :mod:`simulator.sequence`) into the run directory
and, with ``export=obj``, a frame series of the first instance.

Every field is checked before anything is simulated: a bad value ends the command with one
line ``error: <field> must be ...`` (:mod:`common.commands`), and nothing is written.
"""

from __future__ import annotations

import logging
from pathlib import Path

from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf

from common.checks import check_device, check_float, check_int, check_threads
from common.commands import hydra_command
from common.configs import check_node, config_errors
from common.errors import InputError
from common.files import staged_folder
from common.paths import check_output_dir, check_output_file
from simulator.cloth.effects import PhysicsEffects
from simulator.cloth.material import ClothMaterial, check_class_ids, class_summary
from simulator.cloth.rollout import check_recording_memory, simulate
from simulator.sequence import MeshSequence
from simulator.threads import use_process_threads

log = logging.getLogger(__name__)

EXPORT_FORMATS = ("obj", "ply")
"""Values of ``export`` besides null (:meth:`simulator.sequence.MeshSequence.export`)."""


def _checked(cfg: DictConfig) -> dict:
    """Every field of the command, validated and built; raises :class:`InputError`."""
    with config_errors():
        threads = check_threads(cfg.get("threads", 1), "threads")
        classes = check_class_ids(cfg.classes, "classes")
        seed = check_int(cfg.seed, "seed", 0)
        fps = check_float(cfg.fps, "fps", 0, low_open=True)
        record_time = check_float(cfg.record_time, "record_time", 0, low_open=True)
        export = cfg.export
        if export is not None and export not in EXPORT_FORMATS:
            raise InputError(
                f"export must be one of {', '.join(EXPORT_FORMATS)} or null, got {export!r}"
            )
        if not OmegaConf.is_dict(cfg.scenario):  # e.g. scenario=wind, the group's old name
            raise InputError(
                "scenario must be a scene's fields (scenario.<field>=...); pick the scene with "
                f"scene=wind or scene=arm_bend (configs/scene/), got {cfg.scenario!r}"
            )
        for name in ("sim", "scenario", "effects"):
            check_node(OmegaConf.to_container(cfg[name], resolve=True), name)
        check_device(cfg.sim.device, "sim.device")
        scenario = instantiate(cfg.scenario)
        settings = instantiate(cfg.sim)
        effects = PhysicsEffects.from_dict(
            {k: v for k, v in cfg.effects.items() if k != "_target_"}
        )
    speeds = getattr(scenario, "wind_speeds", None)
    wind_level = check_int(cfg.wind_level, "wind_level", 0, len(speeds) - 1 if speeds else None)
    check_recording_memory(record_time, fps, len(classes), scenario.mesh().vert_count)
    out_file = check_output_file(cfg.out_file, "out_file")
    if export is not None:
        check_output_dir(out_file.parent / f"frames_{export}", "export")
    return {
        "threads": threads,
        "classes": classes,
        "seed": seed,
        "fps": fps,
        "record_time": record_time,
        "export": export,
        "scenario": scenario,
        "settings": settings,
        "effects": effects,
        "wind_level": wind_level,
        "out_file": out_file,
    }


def run(cfg: DictConfig):
    """Simulate ``cfg.classes`` and return the saved :class:`MeshSequence`."""
    fields = _checked(cfg)
    use_process_threads(fields["threads"], name="threads")
    classes = list(fields["classes"])
    sequence = simulate(
        fields["scenario"],
        ClothMaterial.from_classes(classes),
        seeds=[fields["seed"] + i for i in range(len(classes))],
        wind_levels=[fields["wind_level"]] * len(classes),
        fps=fields["fps"],
        record_time=fields["record_time"],
        effects=fields["effects"],
        settings=fields["settings"],
        labels=classes,
        progress=True,
    )
    sequence.meta["classes"] = [class_summary(c) for c in classes]
    path = sequence.save(fields["out_file"])
    log.info("wrote %s (%d instances x %d frames)", path, len(classes), sequence.frame_count)
    if fields["export"]:
        fmt = fields["export"]
        paths = _export(sequence, path.parent / f"frames_{fmt}", fmt)
        log.info("exported %d %s frames to %s", len(paths), fmt, paths[0].parent)
    return sequence


def _export(sequence: MeshSequence, out_dir: Path, fmt: str) -> list[Path]:
    """Export into a stage that replaces ``out_dir`` whole, so no half series is left behind."""
    with staged_folder(out_dir, replace=True) as stage:
        written = sequence.export(stage, fmt=fmt)
    return [out_dir / p.name for p in written]


main = hydra_command(run, config_name="simulate", config_path="../../configs")
"""The command line: ``python -m simulator.cloth.simulate`` (``configs/simulate.yaml``)."""


if __name__ == "__main__":
    main()
