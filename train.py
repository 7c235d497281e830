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

from omegaconf import DictConfig

from common.commands import hydra_command
from models.training import train


def _command(cfg: DictConfig) -> float | None:
    """Hydra wrapper around :func:`train`; returns test top-1 for sweepers."""
    # Deterministic cuBLAS for the LSTM on CUDA (set before CUDA initialises).
    os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")
    metrics = train(cfg)
    return metrics.get("test/acc")


main = hydra_command(_command, config_name="train", config_path="configs")


if __name__ == "__main__":
    main()
