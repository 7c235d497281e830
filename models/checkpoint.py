"""A training run's files read as data: no pickled code, no foreign ``_target_``.

Runs are exchanged between users, so nothing read from one may run code:

* :func:`read_checkpoint` loads with ``torch.load(weights_only=True)``, whose unpickler builds
  only tensors, containers and numbers; every way a file can fail to be a checkpoint
  (missing, a folder, empty, truncated, text, a bare tensor, pickled code) is one
  :class:`~common.errors.InputError` that names the field and the file.
* A checkpoint's ``net_config`` is instantiated only when each ``_target_`` in it, nested
  ones included, is one of :data:`NET_TARGETS`; a run folder's ``.hydra/config.yaml`` only
  when each is one of :func:`run_config_targets` (:func:`read_run_config`).
"""

from __future__ import annotations

import functools
import re
import zipfile
from pathlib import Path
from typing import Any

import torch

from common.configs import check_targets
from common.errors import InputError

__all__ = [
    "CHECKPOINT_HELP",
    "NET_TARGETS",
    "read_checkpoint",
    "read_run_config",
    "run_config_targets",
]

CHECKPOINT_HELP = "a .ckpt file written by train.py"

NET_TARGETS = (
    "models.components.frame_encoder.FrameEncoder",
    "models.components.video_nets.CNNLSTMNet",
    "models.components.video_nets.FramePoolNet",
)
"""The project's net components: the only ``_target_`` values a checkpoint's net may name."""

_RUN_TARGETS = (
    *NET_TARGETS,
    "models.material_classifier.MaterialClassifierModule",
    "datasets.datamodule.ClothVideoDataModule",
    "datasets.augment.ClipAugment",
    "datasets.augment.TextureSwap",
    "datasets.augment.BackgroundSwap",
    "lightning.pytorch.Trainer",
)


_RUNS_CALLABLES = ("LambdaCallback", "LambdaLR", "MultiplicativeLR")
"""Classes whose purpose is to call functions given to them: never built from a stranger's file."""


def _subclasses_in(module: Any, base: type) -> list[str]:
    """Dotted names of the public classes of ``module`` that derive from ``base``."""
    found = []
    for name in getattr(module, "__all__", dir(module)):
        obj = getattr(module, name, None)
        if isinstance(obj, type) and issubclass(obj, base) and obj is not base:
            found.append(f"{module.__name__}.{name}")
    return found


@functools.cache
def run_config_targets() -> tuple[str, ...]:
    """What a training config read from a run folder may instantiate.

    The project's nets, module, datamodule and augmentations, Lightning's ``Trainer``, its
    callbacks and loggers, and torch's optimizers and learning-rate schedulers: classes that
    take plain settings (those built to call given functions left out).
    """
    from lightning.pytorch import callbacks, loggers
    from lightning.pytorch.callbacks import Callback
    from lightning.pytorch.loggers import Logger

    return tuple(
        name
        for name in sorted(
            {
                *_RUN_TARGETS,
                *_subclasses_in(callbacks, Callback),
                *_subclasses_in(loggers, Logger),
                *_subclasses_in(torch.optim, torch.optim.Optimizer),
                *_subclasses_in(torch.optim.lr_scheduler, torch.optim.lr_scheduler.LRScheduler),
            }
        )
        if name.rsplit(".", 1)[-1] not in _RUNS_CALLABLES
    )


def _one_line(error: BaseException) -> str:
    """The first sentence of an error's message, on one line."""
    text = " ".join(str(error).split()) or type(error).__name__
    return text.split(". ")[0][:160]


def _refused_global(error: BaseException) -> str | None:
    """The pickled global (code) that the weights-only unpickler refused, if that was it."""
    match = re.search(r"GLOBAL ([\w.]+)", str(error))
    return None if match is None else match.group(1)


def read_checkpoint(
    path: str | Path, field: str = "checkpoint", *, map_location: str | torch.device = "cpu"
) -> dict:
    """The dict of a checkpoint file, read without running any code it holds.

    Args:
        path: The file.
        field: The command-line field that named it, for the message.
        map_location: Where its tensors go.

    Raises:
        InputError: one line naming ``field`` and the file, for every file that is not a
            plain checkpoint dict.
    """
    path = Path(path)
    if not path.exists():
        raise InputError(f"{field}: {path} does not exist; give {CHECKPOINT_HELP}")
    if not path.is_file():
        raise InputError(f"{field}: {path} is not a file; give {CHECKPOINT_HELP}")
    if path.stat().st_size == 0:
        raise InputError(f"{field}: {path} is empty; give {CHECKPOINT_HELP}")
    try:
        raw = torch.load(path, map_location=map_location, weights_only=True)
    except Exception as error:  # whatever the bytes made the unpickler raise: not a checkpoint
        refused = _refused_global(error)
        if refused is not None:
            raise InputError(
                f"{field}: {path} holds Python code ({refused}) besides tensors; refused, "
                "because loading it could run that code: only checkpoints of tensors, numbers "
                "and containers load (train.py writes those)"
            ) from None
        if isinstance(error, EOFError | zipfile.BadZipFile) or "zip archive" in str(error):
            what = f"truncated or damaged ({_one_line(error)})"
        else:
            what = "not a torch checkpoint (its bytes are not what torch.save writes)"
        raise InputError(f"{field}: {path} is {what}; give {CHECKPOINT_HELP}") from None
    if not isinstance(raw, dict):
        raise InputError(
            f"{field}: {path} holds a {type(raw).__name__}, not a training checkpoint (a dict "
            f"with state_dict and hyper_parameters); give {CHECKPOINT_HELP}"
        )
    return raw


def checkpoint_state_dict(raw: dict, path: Path, field: str) -> dict[str, torch.Tensor]:
    """The ``state_dict`` of a read checkpoint: a mapping of names to tensors."""
    state = raw.get("state_dict")
    if not isinstance(state, dict) or not all(
        isinstance(k, str) and isinstance(v, torch.Tensor) for k, v in state.items()
    ):
        raise InputError(
            f"{field}: {path} has no state_dict of named tensors; give {CHECKPOINT_HELP}"
        )
    return state


def checked_net_config(raw: dict, path: Path, field: str) -> dict:
    """A checkpoint's ``hyper_parameters.net_config``, refused unless it names only our nets."""
    hparams = raw.get("hyper_parameters")
    net_config = hparams.get("net_config") if isinstance(hparams, dict) else None
    if not isinstance(net_config, dict) or not net_config:
        raise InputError(
            f"{field}: {path} has no hyper_parameters.net_config; give {CHECKPOINT_HELP}"
        )
    check_targets(net_config, f"{field}: {path} net_config", NET_TARGETS)
    return net_config


def read_run_config(path: str | Path, field: str = "run"):
    """A run folder's saved Hydra config, refused unless it builds only allowed targets.

    Every ``_target_`` of ``.hydra/config.yaml`` must be one of :func:`run_config_targets`.

    Returns:
        The config as an ``omegaconf.DictConfig``.
    """
    from omegaconf import DictConfig, OmegaConf

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{field}: {path} does not exist (the run's saved training config)")
    try:
        cfg = OmegaConf.load(path)
        plain = OmegaConf.to_container(cfg, resolve=False)
    except Exception as error:  # YAML or OmegaConf syntax: the file is not a config
        raise InputError(f"{field}: {path} is not a readable config ({_one_line(error)})") from None
    if not isinstance(cfg, DictConfig):
        raise InputError(f"{field}: {path} is not a mapping of config fields")
    check_targets(plain, f"{field}: config {path}", run_config_targets())
    return cfg
