"""Hydra entry point of training (configs/train.yaml), shaped like the lightning-hydra template.

``python train.py experiment=train/cnn_lstm dataset=wind protocol=simulation`` trains a method
(``configs/experiment/train/``) on a generated dataset (``configs/dataset/``) under a split
protocol (``configs/protocol/``), keeps the best-validation-accuracy checkpoint, then evaluates it
on the test split; running the same command again resumes the run, a finished run is only
re-evaluated (:mod:`models.training`). A bad value ends the command with one line
``error: <field> must be ...`` (:mod:`common.commands`).
"""

from __future__ import annotations

import os

import hydra
from omegaconf import DictConfig

from common.commands import report_user_errors
from models.training import train


@report_user_errors  # outside: Hydra's own errors (overrides, run folder) in one line
@hydra.main(version_base="1.3", config_path="configs", config_name="train")
@report_user_errors
def main(cfg: DictConfig) -> float | None:
    """Hydra wrapper around :func:`train`; returns test top-1 for sweepers."""
    # Deterministic cuBLAS for the LSTM on CUDA (set before CUDA initialises).
    os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")
    metrics = train(cfg)
    return metrics.get("test/acc")


if __name__ == "__main__":
    main()
