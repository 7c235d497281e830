"""Hydra entry point of the tissue tools (configs/tissue.yaml, group ``tissue_job``).

``python -m benchmarks.thesis.tissue_jobs tissue_job=ukf tissue_job.body=heart`` runs one job
(``tables``, ``sensitivity``, ``ukf`` or ``monocular``) into the run folder. A job config
is a ``_partial_`` of the tool's ``run(out, ...)``, the same function its argparse command
calls, so both entries give the same files.

The job's fields are checked (type from the tool's ``run`` signature, range from
``_RANGES``) before anything is written: a bad value ends the command with one line
``error: tissue_job.<field> must be ...`` (:mod:`common.commands`).
"""

from __future__ import annotations

import logging

from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf

from common.checks import check_choice, check_float, check_int
from common.commands import hydra_command
from common.configs import check_node
from common.errors import InputError
from common.files import atomic_write_bytes
from common.paths import check_output_dir

log = logging.getLogger(__name__)

_INT_AT_LEAST = {
    "seed": 0,
    "repeats": 1,
    "elements": 2,
    "tet_target": 1,
    "max_iters": 1,
    "threads": 1,
    "trials": 1,
    "frames": 2,
    "passes": 1,
    "truth_mesh_refine": 1,
}
"""Integer fields of the tissue jobs (scalars or each entry of a list) and their minimum."""
_POSITIVE = ("ratios", "tumour_kpa", "moduli_kpa")
"""Number fields (lists) whose entries must be > 0."""
_CHOICES = {
    "material": ("linear", "mooney_rivlin"),
    "body": ("beam", "heart"),
    "integrator": ("backward_euler", "newmark"),
}
"""Text fields and their allowed values (``null`` too where the tool's type allows it)."""


def _check_job(job: dict) -> None:
    """Type (against the tool's ``run``) and range checks of the job's fields."""
    check_node(job, "tissue_job")
    for key, value in job.items():
        field = f"tissue_job.{key}"
        values = value if isinstance(value, list) else [value]
        if key in _INT_AT_LEAST:
            for v in values:
                check_int(v, field, _INT_AT_LEAST[key])
        elif key in _POSITIVE and value is not None:
            for v in values:
                check_float(v, field, 0, low_open=True)
        elif key in _CHOICES and value is not None:  # null: the type check allowed it
            check_choice(value, field, _CHOICES[key])
        elif key == "noise_mm":
            check_float(value, field, 0)
        elif key == "only":
            if not isinstance(value, list) or not value:
                raise InputError(
                    f"{field} must be a non-empty list of t31, t32, sens; got {value!r}"
                )
            for v in value:
                check_choice(v, field, ("t31", "t32", "sens"))


def run(cfg: DictConfig):
    """Run ``cfg.tissue_job`` into ``cfg.out_dir`` (with its resolved config); its result."""
    check_int(cfg.seed, "seed", 0)
    _check_job(OmegaConf.to_container(cfg.tissue_job, resolve=True))
    out = check_output_dir(cfg.out_dir, "out_dir")
    out.mkdir(parents=True, exist_ok=True)
    job = OmegaConf.to_yaml(cfg.tissue_job, resolve=True)
    atomic_write_bytes(out / "tissue_job.yaml", job.encode())
    log.info("tissue job %s -> %s", cfg.tissue_job._target_, out)
    return instantiate(cfg.tissue_job, _convert_="all")(out)


main = hydra_command(run, config_name="tissue", config_path="../../configs")
"""The command line: ``python -m benchmarks.thesis.tissue_jobs`` (``configs/tissue.yaml``)."""


if __name__ == "__main__":
    main()
