"""Hydra entry point of the sim-to-real diagnosis (configs/diagnose.yaml).

``python -m sim2real.diagnose real_dir=path/to/real run=logs/train/<run> [budget=quick|full]``
writes ``outputs/sim2real/<name>/report.html`` (and ``report.md``, ``report.json``, PNG
figures) and prints the verdict. See :mod:`sim2real.diagnosis` for the method.
"""

from __future__ import annotations

import logging
from pathlib import Path

from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf

from common.checks import check_bool, check_choice, check_device, check_float, check_int
from common.commands import hydra_command
from common.errors import InputError
from common.paths import check_name, check_output_dir

from .pipeline import DiagnosisRequest, run_diagnosis
from .report import verdict
from .result import Diagnosis

log = logging.getLogger(__name__)


def run(cfg: DictConfig) -> Diagnosis:
    """Run the configured diagnosis."""
    name = cfg.name or f"{Path(str(cfg.real_dir)).name}-{Path(str(cfg.run)).name}"
    name = check_name(name, "name")  # the report folder's name: never a path
    out_dir = check_output_dir(cfg.out_dir or f"outputs/sim2real/{name}", "out_dir")
    for field in ("cache_dir", "mesh_cache"):
        check_output_dir(cfg[field], field)
    candidates = cfg.candidates
    if not isinstance(candidates, str):
        candidates = [str(c) for c in candidates]
    check_choice(str(cfg.device), "device", ("auto", "cpu", "cuda"))
    request = DiagnosisRequest(
        real_dir=cfg.real_dir,
        run=cfg.run,
        cache_dir=cfg.cache_dir,
        mesh_cache=cfg.mesh_cache,
        budget=instantiate(cfg.budget),
        candidates=candidates,
        strengths=OmegaConf.to_container(cfg.strengths, resolve=True),
        data_dir=cfg.data_dir,
        clip_len=check_int(cfg.clip_len, "clip_len", 1),
        clip_stride=check_int(cfg.clip_stride, "clip_stride", 1),
        alpha=check_float(cfg.alpha, "alpha", 0, 1, low_open=True),
        seed=check_int(cfg.seed, "seed", 0),
        sim_seed=check_int(cfg.sim_seed, "sim_seed", 0),
        n_jobs=check_int(cfg.n_jobs, "n_jobs", 1),
        device=check_device(cfg.device, "device"),
        name=name,
        progress=check_bool(cfg.progress, "progress"),
    )
    return run_diagnosis(request, out_dir)


def _command(cfg: DictConfig) -> None:
    """Hydra wrapper around :func:`run`: bad input ends with one line naming the field."""
    try:
        result = run(cfg)
    except ValueError as err:  # the diagnosis's own checks raise ValueErrors naming the field
        raise InputError(" ".join(str(err).split())) from err
    out = cfg.out_dir or f"outputs/sim2real/{result.name}"
    print(verdict(result))
    print(f"report: {Path(out) / 'report.html'}")


main = hydra_command(_command, config_name="diagnose")


if __name__ == "__main__":
    main()
