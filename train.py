"""Hydra entry point of training (configs/train.yaml), shaped like the lightning-hydra template.

``python train.py experiment=wind_L1_random_cnn_lstm`` trains on a generated dataset, keeps
the best-validation-accuracy checkpoint, then evaluates it on the test split
(:func:`models.evaluate.evaluate_simulated`: JSON + Markdown + confusion PNG in the run's
``eval/``). The run folder is fixed per experiment (``logs/train/<run_name>``), so running
the command again resumes from ``last.ckpt``; a finished run is only re-evaluated.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import hydra
import lightning as L
import torch
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf, open_dict

log = logging.getLogger(__name__)


def _resume_path(cfg: DictConfig, output_dir: Path) -> str | None:
    if cfg.ckpt_path is None:
        return None
    if cfg.ckpt_path == "auto":
        last = output_dir / "checkpoints" / "last.ckpt"
        return str(last) if last.is_file() else None
    path = Path(cfg.ckpt_path)
    if not path.is_file():
        raise FileNotFoundError(f"ckpt_path {path} does not exist")
    return str(path)


def _callbacks(cfg: DictConfig) -> list:
    return [instantiate(c) for c in (cfg.get("callbacks") or {}).values() if c is not None]


def _loggers(cfg: DictConfig) -> list:
    return [instantiate(c) for c in (cfg.get("logger") or {}).values() if c is not None]


def _device_name() -> str:
    if torch.cuda.is_available():
        return torch.cuda.get_device_name()
    return f"CPU, {torch.get_num_threads()} threads"


def _training_summary(last: Path) -> dict:
    """Epochs, training minutes and best val accuracy of a run, from its last checkpoint.

    Read from the checkpoint so that resumed and evaluation-only runs report the whole training.
    """
    summary: dict = {"device": _device_name()}
    if last.is_file():
        state = torch.load(last, map_location="cpu", weights_only=False)
        summary["epochs"] = int(state.get("epoch", -1)) + 1
        summary["train_minutes"] = float(state.get("train_seconds", 0.0)) / 60
        summary["best_val_acc"] = float(state.get("best_val_acc", 0.0))
    return summary


def train(cfg: DictConfig) -> dict:
    """Fit (or resume), then evaluate the best checkpoint; returns the test metrics."""
    from models.evaluate import evaluate_simulated
    from models.material_classifier import (
        ENCODER_CHECKPOINT_KEYS,
        init_weights_from,
        load_classifier,
    )

    output_dir = Path(cfg.paths.output_dir)
    resume = _resume_path(cfg, output_dir) if cfg.train else None
    init_from = cfg.get("init_from")
    if init_from:  # the whole net comes from that checkpoint, not from its stages' CNNs
        with open_dict(cfg):
            for key in ENCODER_CHECKPOINT_KEYS:
                if key in cfg.model.net:
                    cfg.model.net[key] = None
    if cfg.threads:
        torch.set_num_threads(int(cfg.threads))
    if torch.cuda.is_available():
        torch.set_float32_matmul_precision(str(cfg.matmul_precision))
    L.seed_everything(int(cfg.seed), workers=True)
    datamodule = instantiate(cfg.data)
    model = instantiate(cfg.model)
    model.hparams["net_config"] = OmegaConf.to_container(cfg.model.net, resolve=True)
    if init_from and cfg.train and resume is None:
        init_weights_from(model, init_from)
        log.info("weights from %s", init_from)
    loggers = _loggers(cfg)
    trainer = instantiate(cfg.trainer, callbacks=_callbacks(cfg), logger=loggers)
    config = OmegaConf.to_container(cfg, resolve=True)
    for logger in loggers:
        logger.log_hyperparams(config)
    if cfg.train:
        trainer.fit(model, datamodule=datamodule, ckpt_path=resume)
    metrics = _training_summary(output_dir / "checkpoints" / "last.ckpt")
    if cfg.test and trainer.is_global_zero:
        best = output_dir / "checkpoints" / "best.ckpt"
        if not best.is_file():
            raise FileNotFoundError(f"no best checkpoint at {best}: did training run?")
        result = evaluate_simulated(
            load_classifier(best), cfg.dataset.dir, output_dir / "eval",
            split="test", split_protocol=str(cfg.data.split_protocol),
            batch_size=int(cfg.data.batch_size), extra=metrics,
        )  # fmt: skip
        metrics.update({f"test/{k}": v for k, v in result.items() if isinstance(v, float)})
        log.info("test top-1 %.3f (best val %.3f)", result["acc"], metrics.get("best_val_acc", 0))
    return metrics


@hydra.main(version_base="1.3", config_path="configs", config_name="train")
def main(cfg: DictConfig) -> float | None:
    """Hydra wrapper around :func:`train`; returns test top-1 for sweepers."""
    # Deterministic cuBLAS for the LSTM on CUDA (set before CUDA initialises).
    os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")
    metrics = train(cfg)
    return metrics.get("test/acc")


if __name__ == "__main__":
    main()
