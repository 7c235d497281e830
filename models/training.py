"""Training of a material classifier from a composed config (``configs/train.yaml``).

:func:`train` fits (or resumes) the configured module on the configured datamodule, keeps the
best-validation-accuracy checkpoint, then evaluates it on the test split
(:func:`models.evaluate.evaluate_simulated`: JSON + Markdown + confusion PNG in the run's
``eval/``). The run folder is fixed per experiment (``logs/train/<run_name>``), so calling it
again resumes from ``last.ckpt``; a finished run is only re-evaluated. ``train.py`` is its
command line; other commands (``sim2real.shrink``) call it with a config of their own.

The classes come from the data: the datamodule reads its datasets' material set from their
manifests, and the net gets its ``num_classes`` (``model.net.num_classes``) and the module its
``class_grid`` (``model.class_grid``) from there; both are stored in the checkpoint.

A run's identity includes its dataset: ``dataset.json`` in the run folder records the data
folders and the sha256 of their ``manifest.json`` when the run starts, and a later call that
would resume or re-evaluate the run on another dataset is refused. Every field is checked
before anything is built or written; a bad value is an :class:`~common.errors.InputError`
naming the field.
"""

from __future__ import annotations

import hashlib
import json
import logging
from pathlib import Path

import lightning as L
import torch
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf, open_dict

from common.checks import check_bool, check_choice, check_int, check_threads, require_cuda
from common.configs import check_node, config_errors
from common.errors import InputError
from common.files import atomic_write_bytes
from common.paths import check_name

log = logging.getLogger(__name__)

DATASET_RECORD = "dataset.json"
"""File in the run folder naming the datasets the run was made with (see the module doc)."""


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


def _check_fields(cfg: DictConfig) -> None:
    """Type and range checks of the command's fields, before anything is built or written."""
    with config_errors():
        check_int(cfg.seed, "seed", 0, 2**32 - 1)
        check_bool(cfg.train, "train")
        check_bool(cfg.test, "test")
        check_threads(cfg.threads, "threads")
        check_choice(cfg.matmul_precision, "matmul_precision", ("highest", "high", "medium"))
        for name in ("ckpt_path", "init_from"):
            value = cfg.get(name)
            if value is not None and (not isinstance(value, str) or not value.strip()):
                raise InputError(f"{name} must be a checkpoint path or null, got {value!r}")
        for name in ("trainer", "data", "model"):  # trainer first: model reads max_epochs
            check_node(OmegaConf.to_container(cfg[name], resolve=True), name)
        for group in ("callbacks", "logger"):
            for key, node in (cfg.get(group) or {}).items():
                if node is not None:
                    check_node(OmegaConf.to_container(node, resolve=True), f"{group}.{key}")
    accelerator = str(cfg.trainer.get("accelerator", "auto")).lower()
    if accelerator in ("gpu", "cuda"):
        require_cuda(
            f"trainer.accelerator={accelerator}", "use trainer=cpu or trainer.accelerator=auto"
        )


def _data_dirs(cfg: DictConfig) -> list[Path]:
    """The folders the run trains on (``data.data_dirs``) and tests on (``dataset.dir``)."""
    dirs = cfg.data.data_dirs
    dirs = [dirs] if isinstance(dirs, str) else list(dirs)
    dirs.append(cfg.dataset.dir)  # usually data_dirs[0]; the run is named after it
    return list(dict.fromkeys(Path(str(d)).resolve() for d in dirs))


def dataset_identity(cfg: DictConfig) -> list[dict]:
    """Each data folder of the run with the sha256 of its ``manifest.json``.

    Raises the dataset's own clear error (:meth:`datasets.manifest.Manifest.load`) when a
    folder is missing or is not a finished dataset.
    """
    from datasets.manifest import Manifest

    identity = []
    for root in _data_dirs(cfg):
        path = Manifest.path(root)
        if not path.is_file():
            try:
                Manifest.load(root)  # raises, naming the folder
            except FileNotFoundError as err:
                raise FileNotFoundError(f"{err}{_generate_hint(cfg, root)}") from None
        digest = hashlib.sha256(path.read_bytes()).hexdigest()
        identity.append({"dir": str(root), "manifest_sha256": digest})
    return identity


def _generate_hint(cfg: DictConfig, root: Path) -> str:
    """How to make the configured dataset (``dataset.dir``) when it is missing."""
    keys = ("motion", "level", "texture", "preset", "seed")
    if Path(str(cfg.dataset.dir)).resolve() != root or any(k not in cfg.dataset for k in keys):
        return ""
    args = " ".join(f"{k}={cfg.dataset[k]}" for k in keys)
    return f"; make it with: python -m datasets.generate {args} out_dir={cfg.dataset.dir}"


def _describe(identity: list[dict]) -> str:
    return " + ".join(f"{d['dir']} (manifest sha256 {d['manifest_sha256'][:12]})" for d in identity)


def check_dataset_identity(output_dir: Path, identity: list[dict]) -> bool:
    """Refuse a run folder made with another dataset; whether the record must be (re)written.

    The datasets are the same when their manifests are byte-identical (a dataset moved to
    another folder stays the same run, with a warning); anything else is refused, so a run
    is never resumed or re-evaluated on data it was not made with.
    """
    path = output_dir / DATASET_RECORD
    if not path.is_file():
        if any((output_dir / "checkpoints").glob("*.ckpt")):
            log.warning(
                "run folder %s has checkpoints but no %s (made before runs recorded their "
                "dataset): recording %s",
                output_dir,
                DATASET_RECORD,
                _describe(identity),
            )
        return True
    try:
        recorded = json.loads(path.read_text())["datasets"]
        recorded_hashes = [d["manifest_sha256"] for d in recorded]
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise InputError(
            f"cannot read {path} ({err}); delete it to re-record the dataset"
        ) from None
    if recorded_hashes != [d["manifest_sha256"] for d in identity]:
        raise InputError(
            f"run folder {output_dir} was made with dataset {_describe(recorded)}, but this "
            f"command reads {_describe(identity)}; a run is never resumed or re-evaluated on "
            "another dataset: give this one its own run (run_tag=...) or delete the old folder"
        )
    if [d["dir"] for d in recorded] != [d["dir"] for d in identity]:
        log.warning(
            "run folder %s: its dataset moved from %s to %s (same manifest bytes)",
            output_dir,
            _describe(recorded),
            _describe(identity),
        )
        return True
    return False


def _record_dataset(output_dir: Path, identity: list[dict]) -> None:
    text = json.dumps({"datasets": identity}, indent=1, sort_keys=True) + "\n"
    atomic_write_bytes(output_dir / DATASET_RECORD, text.encode())


def _log_early_stop(trainer) -> None:
    """Say so when early stopping ended training: epoch, monitored metric and best value."""
    from lightning.pytorch.callbacks import EarlyStopping

    for callback in trainer.callbacks:
        if not isinstance(callback, EarlyStopping) or callback.stopped_epoch <= 0:
            continue
        reason = str(getattr(callback, "stopping_reason", ""))
        if "PATIENCE" in reason.upper() or not getattr(callback, "stopping_reason_message", ""):
            reason = (
                f"{callback.monitor} did not improve in the last {callback.patience} "
                "validation checks"
            )
        else:  # a threshold or a non-finite metric: Lightning's own words
            reason = " ".join(callback.stopping_reason_message.split())
            reason = reason.replace("Signaling Trainer to stop.", "").strip().rstrip(".")
        log.info(
            "early stopping ended training after epoch %d of max_epochs %s: %s (best %s = %.4f)",
            callback.stopped_epoch + 1,
            trainer.max_epochs,
            reason,
            callback.monitor,
            float(callback.best_score),
        )


def _labels_from_data(cfg: DictConfig, datamodule) -> None:
    """Give the model config the data's classes: ``model.net.num_classes``, ``model.class_grid``.

    A ``num_classes`` set on the command line must be the data's.
    """
    count = datamodule.num_classes
    given = cfg.model.net.get("num_classes")
    if given is not None and given != count:
        raise InputError(
            f"model.net.num_classes must be the data's class count {count} (its material set "
            f"{datamodule.material_set.name}), got {given!r}; leave it out"
        )
    with open_dict(cfg):
        cfg.model.net.num_classes = count
        cfg.model.class_grid = datamodule.class_grid


def _callbacks(cfg: DictConfig) -> list:
    return [instantiate(c) for c in (cfg.get("callbacks") or {}).values() if c is not None]


def _loggers(cfg: DictConfig) -> list:
    return [instantiate(c) for c in (cfg.get("logger") or {}).values() if c is not None]


def _trainer(cfg: DictConfig, loggers: list):
    """The Lightning Trainer; its refusal of a setting (MisconfigurationException) is ours."""
    try:
        return instantiate(cfg.trainer, callbacks=_callbacks(cfg), logger=loggers)
    except Exception as exc:
        cause: BaseException | None = exc
        while cause is not None and type(cause).__name__ != "MisconfigurationException":
            cause = cause.__cause__
        if cause is None:
            raise
        raise InputError(f"trainer: {' '.join(str(cause).split())}") from exc


def _device_name() -> str:
    if torch.cuda.is_available():
        return torch.cuda.get_device_name()
    return f"CPU, {torch.get_num_threads()} threads"


def _training_summary(last: Path) -> dict:
    """Epochs, training minutes and best val accuracy of a run, from its last checkpoint.

    Read from the checkpoint so that resumed and evaluation-only runs report the whole training.
    """
    from models.checkpoint import read_checkpoint

    summary: dict = {"device": _device_name()}
    if last.is_file():
        state = read_checkpoint(last, "ckpt_path")
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

    _check_fields(cfg)
    check_name(cfg.run_name, "run_name")  # the run folder's name, never a path
    output_dir = Path(cfg.paths.output_dir)
    identity = dataset_identity(cfg) if cfg.train or cfg.test else []
    record = bool(identity) and check_dataset_identity(output_dir, identity)
    resume = _resume_path(cfg, output_dir) if cfg.train else None
    if resume is not None:  # a file of tensors only: refused in one line before any work
        from models.checkpoint import read_checkpoint

        read_checkpoint(resume, "ckpt_path")
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
    with config_errors():
        datamodule = instantiate(cfg.data)
        _labels_from_data(cfg, datamodule)
        model = instantiate(cfg.model)
    model.hparams["net_config"] = OmegaConf.to_container(cfg.model.net, resolve=True)
    if init_from and cfg.train and resume is None:
        with config_errors():  # a checkpoint of another model is the user's error
            init_weights_from(model, init_from)
        log.info("weights from %s", init_from)
    with config_errors():
        loggers = _loggers(cfg)
        trainer = _trainer(cfg, loggers)
    if record:
        _record_dataset(output_dir, identity)
    config = OmegaConf.to_container(cfg, resolve=True)
    for logger in loggers:
        logger.log_hyperparams(config)
    if cfg.train:
        trainer.fit(model, datamodule=datamodule, ckpt_path=resume, weights_only=True)
        _log_early_stop(trainer)
    metrics = _training_summary(output_dir / "checkpoints" / "last.ckpt")
    if cfg.test and trainer.is_global_zero:
        best = output_dir / "checkpoints" / "best.ckpt"
        if not best.is_file():
            raise FileNotFoundError(f"no best checkpoint at {best}: did training run?")
        result = evaluate_simulated(
            load_classifier(best),
            cfg.dataset.dir,
            output_dir / "eval",
            split="test",
            split_protocol=str(cfg.data.split_protocol),
            batch_size=int(cfg.data.batch_size),
            extra=metrics,
        )
        metrics.update({f"test/{k}": v for k, v in result.items() if isinstance(v, float)})
        log.info("test top-1 %.3f (best val %.3f)", result["acc"], metrics.get("best_val_acc", 0))
    return metrics
