"""Hydra entry point of the tissue tools (configs/tissue.yaml, group ``tissue_job``).

``python -m simulator.tools.tissue tissue_job=ukf tissue_job.body=heart`` runs one job
(``tables``, ``sensitivity``, ``ukf`` or ``monocular``) into the run folder. A job config
is a ``_partial_`` of the tool's ``run(out, ...)``, the same function its argparse command
calls, so both entries give the same files.
"""

from __future__ import annotations

import logging
from pathlib import Path

import hydra
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf

from simulator.sequence import atomic_write_bytes

log = logging.getLogger(__name__)


def run(cfg: DictConfig):
    """Run ``cfg.tissue_job`` into ``cfg.out_dir`` (with its resolved config); its result."""
    out = Path(cfg.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    job = OmegaConf.to_yaml(cfg.tissue_job, resolve=True)
    atomic_write_bytes(out / "tissue_job.yaml", job.encode())
    log.info("tissue job %s -> %s", cfg.tissue_job._target_, out)
    return instantiate(cfg.tissue_job, _convert_="all")(out)


@hydra.main(version_base="1.3", config_path="../../configs", config_name="tissue")
def main(cfg: DictConfig) -> None:
    """Hydra wrapper around :func:`run`."""
    run(cfg)


if __name__ == "__main__":
    main()
