"""LightningModule that trains any clip classifier net on the data's material classes.

It receives its ``net`` (and optimizer/scheduler factories) from the config, as in the
lightning-hydra template; ``net_config`` (the net's plain ``_target_`` config, with the data's
``num_classes``) and ``class_grid`` (the data's stretch x bend grid, plain numbers) are stored
in the checkpoint so that :func:`load_classifier` can rebuild the net and read its classes
without the training config. Batches are the datasets' dicts: clips (``video``
(B, T, 3, H, W)) or, for the per-frame baseline, frames (``image`` (B, 3, H, W)).
Every evaluation runs a trained module through Lightning's test loop inside
:class:`ClipOutputsModule`, which keeps each batch's logits and metadata for the reports
(:func:`models.evaluate.predict`).

Logged: ``train/loss``, ``train/acc``, ``val/loss``, ``val/acc``, ``val/acc_best``,
``val/top5``, ``val/stretch_acc``, ``val/bend_acc``, ``val/grid_mae`` (and ``test/*``).
Validation metrics are computed on the whole epoch's predictions, gathered over DDP ranks.
"""

from __future__ import annotations

import copy
import time
from collections.abc import Callable
from pathlib import Path

import lightning as L
import torch
from hydra.utils import instantiate
from torch import nn

from common.errors import InputError
from common.grid import ClassGrid

from .checkpoint import (
    CHECKPOINT_HELP,
    checked_net_config,
    checkpoint_state_dict,
    read_checkpoint,
)
from .metrics import classification_metrics

__all__ = [
    "ENCODER_CHECKPOINT_KEYS",
    "ClipOutputsModule",
    "MaterialClassifierModule",
    "batch_input",
    "init_weights_from",
    "load_classifier",
]

ENCODER_CHECKPOINT_KEYS = ("encoder_checkpoint", "motion_encoder_checkpoint")
"""Net config keys naming other runs' CNNs to start from; moot once a whole state dict loads."""
ENCODER_MODULES = ("encoder", "motion_encoder")
"""Attributes of the nets that hold frame encoders (the CNNs ``encoder_lr_scale`` applies to)."""


PIXELS = ("video", "image")
"""Batch keys of the pixels (clip mode, frame mode); every other key is the samples' metadata."""


def batch_input(batch: dict) -> torch.Tensor:
    """The pixels of a batch: ``video`` (clip mode) or ``image`` (frame mode)."""
    for key in PIXELS:
        if key in batch:
            return batch[key]
    raise KeyError(f"batch has neither 'video' nor 'image' (keys: {sorted(batch)})")


class MaterialClassifierModule(L.LightningModule):
    """Cross-entropy training and epoch-level metrics of a clip classifier.

    Args:
        net: Maps (B, T, 3, H, W) (or (B, 3, H, W) for frame models) to logits (B, classes).
        optimizer: Factory ``params -> Optimizer`` (``_partial_`` config); default AdamW 1e-3.
        scheduler: Factory ``optimizer -> LRScheduler`` stepped per epoch, or ``None``.
        label_smoothing: Cross-entropy label smoothing.
        net_config: The net's ``_target_`` config (plain dict), kept for :func:`load_classifier`.
        method: Short method name for reports (``cnn_lstm``, ``base1``, ``base2``, ...).
        encoder_lr_scale: The frame encoders' learning rate as a fraction of the optimizer's
            (discriminative fine-tuning: a CNN trained beforehand keeps its features while a
            new LSTM and classifier learn at the full rate); 1 = one rate for everything.
        class_grid: The data's class grid (:class:`~common.grid.ClassGrid` or its JSON, e.g.
            the datamodule's ``class_grid``); the metrics need it. ``None``: the attached
            datamodule's, when there is one.
    """

    def __init__(
        self,
        net: nn.Module,
        optimizer: Callable | None = None,
        scheduler: Callable | None = None,
        *,
        label_smoothing: float = 0.0,
        net_config: dict | None = None,
        method: str = "",
        encoder_lr_scale: float = 1.0,
        class_grid: ClassGrid | dict | None = None,
    ):
        super().__init__()
        if not 0 <= label_smoothing < 1:
            raise ValueError(f"label_smoothing must be in [0, 1), got {label_smoothing!r}")
        if isinstance(encoder_lr_scale, bool) or not 0 < float(encoder_lr_scale) <= 1:
            raise ValueError(
                f"model.encoder_lr_scale must be in (0, 1] (freeze_encoder freezes), "
                f"got {encoder_lr_scale!r}"
            )
        self.encoder_lr_scale = float(encoder_lr_scale)
        self.class_grid = None if class_grid is None else ClassGrid.from_json(class_grid)
        self.save_hyperparameters(
            logger=False, ignore=["net", "optimizer", "scheduler", "class_grid"]
        )
        if self.class_grid is not None:  # plain numbers in the checkpoint, never a config node
            self.hparams["class_grid"] = self.class_grid.to_json()
        self.net = net
        self.optimizer_factory = optimizer
        self.scheduler_factory = scheduler
        self.loss = nn.CrossEntropyLoss(label_smoothing=label_smoothing)
        self._outputs: dict[str, list[tuple[torch.Tensor, torch.Tensor]]] = {"val": [], "test": []}
        self.best_val_acc = 0.0
        self.train_seconds = 0.0
        """Wall time of the training epochs and their validation, summed across resumes."""
        self._epoch_started: float | None = None

    def forward(self, pixels: torch.Tensor) -> torch.Tensor:
        """Logits (B, classes) of clips or frames."""
        return self.net(pixels)

    def training_step(self, batch: dict, batch_idx: int) -> torch.Tensor:
        """Cross-entropy on one batch; logs loss and accuracy."""
        logits = self(batch_input(batch))
        labels = batch["label"]
        loss = self.loss(logits, labels)
        size = labels.shape[0]
        self.log(
            "train/loss",
            loss,
            on_step=False,
            on_epoch=True,
            prog_bar=True,
            batch_size=size,
            sync_dist=True,
        )
        acc = (logits.argmax(1) == labels).float().mean()
        self.log(
            "train/acc",
            acc,
            on_step=False,
            on_epoch=True,
            prog_bar=True,
            batch_size=size,
            sync_dist=True,
        )
        return loss

    def _eval_step(self, split: str, batch: dict) -> None:
        logits = self(batch_input(batch))
        self._outputs[split].append((logits.detach(), batch["label"]))

    def validation_step(self, batch: dict, batch_idx: int) -> None:
        """Collect the logits; metrics come at the epoch's end."""
        self._eval_step("val", batch)

    def test_step(self, batch: dict, batch_idx: int) -> None:
        """Collect the logits; metrics come at the epoch's end."""
        self._eval_step("test", batch)

    def _grid(self) -> ClassGrid:
        """The class grid of the metrics: this module's, else its trainer's datamodule's."""
        if self.class_grid is None:
            datamodule = getattr(self._trainer, "datamodule", None)
            grid = getattr(datamodule, "class_grid", None)
            if grid is None:
                raise ValueError(
                    "class_grid is unknown: pass model.class_grid (the data's, e.g. "
                    "datamodule.class_grid) or train with a datamodule that has one"
                )
            self.class_grid = ClassGrid.from_json(grid)
            self.hparams["class_grid"] = self.class_grid.to_json()
        return self.class_grid

    def _epoch_metrics(self, split: str) -> None:
        outputs, self._outputs[split] = self._outputs[split], []
        if not outputs:
            return
        logits = torch.cat([o[0] for o in outputs])
        labels = torch.cat([o[1] for o in outputs])
        if self.trainer is not None and self.trainer.world_size > 1:
            logits = self.all_gather(logits).flatten(0, 1)
            labels = self.all_gather(labels).flatten(0, 1)
        metrics = classification_metrics(logits.float(), labels, self._grid())
        metrics["loss"] = float(self.loss(logits.float(), labels.long()))
        if split == "val" and not self.trainer.sanity_checking:
            self.best_val_acc = max(self.best_val_acc, metrics["acc"])
            metrics["acc_best"] = self.best_val_acc
        for name, value in metrics.items():
            # Every rank holds the same gathered value: syncing only silences the DDP warning.
            self.log(f"{split}/{name}", value, prog_bar=name == "acc", sync_dist=True)

    def on_train_epoch_start(self) -> None:
        """Start the epoch's clock."""
        self._epoch_started = time.perf_counter()

    def on_validation_epoch_end(self) -> None:
        """Log the validation metrics of the whole epoch."""
        self._epoch_metrics("val")
        if self._epoch_started is not None:
            self.train_seconds += time.perf_counter() - self._epoch_started
            self._epoch_started = None

    def on_test_epoch_end(self) -> None:
        """Log the test metrics of the whole split."""
        self._epoch_metrics("test")

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        """Keep the best validation accuracy and the training time across resumes."""
        checkpoint["best_val_acc"] = self.best_val_acc
        checkpoint["train_seconds"] = self.train_seconds

    def on_load_checkpoint(self, checkpoint: dict) -> None:
        """Restore the best validation accuracy and training time of a resumed run."""
        self.best_val_acc = float(checkpoint.get("best_val_acc", 0.0))
        self.train_seconds = float(checkpoint.get("train_seconds", 0.0))

    def _parameter_groups(self) -> list[dict]:
        """Trainable parameters; the encoders' in a group of their own when their rate differs."""
        params = [p for p in self.parameters() if p.requires_grad]
        if self.encoder_lr_scale == 1.0:
            return [{"params": params}]
        encoders = [getattr(self.net, name, None) for name in ENCODER_MODULES]
        in_encoder = {id(p) for m in encoders if m is not None for p in m.parameters()}
        groups = [
            {"params": [p for p in params if id(p) not in in_encoder]},
            {"params": [p for p in params if id(p) in in_encoder], "encoder": True},
        ]
        return [g for g in groups if g["params"]]

    def configure_optimizers(self):
        """The configured optimizer (AdamW 1e-3 by default) and optional per-epoch scheduler.

        The encoders' group runs at ``encoder_lr_scale`` times the optimizer's rate (set before
        the scheduler is built, so a schedule scales both groups alike).
        """
        factory = self.optimizer_factory or (lambda ps: torch.optim.AdamW(ps, lr=1e-3))
        optimizer = factory(self._parameter_groups())
        for group in optimizer.param_groups:
            if group.get("encoder"):
                group["lr"] *= self.encoder_lr_scale
        if self.scheduler_factory is None:
            return optimizer
        scheduler = self.scheduler_factory(optimizer)
        schedule = {"scheduler": scheduler, "interval": "epoch"}
        return {"optimizer": optimizer, "lr_scheduler": schedule}


class ClipOutputsModule(L.LightningModule):
    """Lightning's test loop over a trained classifier, keeping every batch's outputs.

    The reports compute their own metrics (labelled clips, or real footage whose class is
    unknown), so :meth:`test_step` logs nothing and appends each batch's outputs to
    :attr:`outputs`, in the loader's order.

    Args:
        classifier: The trained module whose net maps the batches' pixels to logits.
    """

    def __init__(self, classifier: MaterialClassifierModule):
        super().__init__()
        self.classifier = classifier
        self.outputs: list[dict] = []
        """Per batch: ``logits`` (float32 on the CPU, (B, classes)) and ``meta``."""

    def test_step(self, batch: dict, batch_idx: int, dataloader_idx: int = 0) -> dict:
        """The batch's logits (float32, on the CPU) and its samples' other fields.

        ``meta`` is the batch without its pixels (labels, keys, wind levels, video names:
        whatever the dataset's samples carry), for reports that break results down.
        """
        logits = self.classifier(batch_input(batch)).float().cpu()
        meta = {
            k: v.cpu() if isinstance(v, torch.Tensor) else v
            for k, v in batch.items()
            if k not in PIXELS
        }
        out = {"logits": logits, "meta": meta}
        self.outputs.append(out)
        return out


def _classifier_rows(state_dict: dict) -> int | None:
    """Output classes of a stored net: the rows of its ``classifier`` layer (``None``: none)."""
    weight = state_dict.get("net.classifier.weight")
    return None if weight is None else int(weight.shape[0])


def load_classifier(
    checkpoint: str | Path, map_location: str | torch.device = "cpu", *, field: str = "checkpoint"
) -> MaterialClassifierModule:
    """Rebuild a trained module from its checkpoint alone (net from the stored ``net_config``).

    The file is read as data (:func:`models.checkpoint.read_checkpoint`) and the net is built
    only from the project's components (:data:`models.checkpoint.NET_TARGETS`). Checkpoints
    written before the labels travelled with the data lack ``num_classes`` in ``net_config``
    and the ``class_grid`` hyper-parameter: the class count is read from the stored classifier
    layer, and the grid is that of every dataset of that time, the 54 classes of ``wang54``
    (:func:`datasets.manifest.legacy_class_grid`).

    Raises:
        InputError: one line naming ``field`` and the file when it is not a checkpoint of
            one of our nets.
    """
    path = Path(checkpoint)
    raw = read_checkpoint(path, field, map_location=map_location)
    state = checkpoint_state_dict(raw, path, field)
    hparams = raw["hyper_parameters"]
    net_config = copy.deepcopy(checked_net_config(raw, path, field))
    if "num_classes" not in net_config:  # written before the labels travelled with the data
        rows = _classifier_rows(state)
        if rows is None:
            raise InputError(
                f"{field}: {path} says neither num_classes nor a classifier layer; give "
                f"{CHECKPOINT_HELP}"
            )
        net_config["num_classes"] = rows
    stored_config = {**hparams["net_config"], "num_classes": net_config["num_classes"]}
    for key in ENCODER_CHECKPOINT_KEYS:
        if key in net_config:
            net_config[key] = None  # the encoders' weights are in this state dict
    class_grid = hparams.get("class_grid")
    if class_grid is None:
        from datasets.manifest import legacy_class_grid

        class_grid = legacy_class_grid()
    try:
        net = instantiate(net_config)
        module = MaterialClassifierModule(
            net,
            label_smoothing=float(hparams.get("label_smoothing", 0.0)),
            net_config=stored_config,
            method=str(hparams.get("method", "")),
            class_grid=class_grid,
        )
        module.load_state_dict(state)
        module.best_val_acc = float(raw.get("best_val_acc", 0.0))
    except Exception as error:  # settings or weights that do not build our net
        cause = error.__cause__ if type(error).__module__.startswith("hydra.") else error
        raise InputError(
            f"{field}: {path} does not rebuild its net ({' '.join(str(cause).split())[:300]}); "
            f"give {CHECKPOINT_HELP}"
        ) from None
    return module.eval()


def init_weights_from(module: MaterialClassifierModule, checkpoint: str | Path) -> None:
    """Start ``module`` from the weights of another run's checkpoint (``init_from``).

    Only the weights move: optimizer, schedule, epoch counter and best accuracy start afresh,
    so a second stage can train the same net on a new (e.g. lower) learning-rate schedule.
    The nets must match exactly.
    """
    path = Path(checkpoint)
    state = checkpoint_state_dict(read_checkpoint(path, "init_from"), path, "init_from")
    try:
        module.load_state_dict(state)
    except RuntimeError as error:
        raise InputError(
            f"init_from {path} does not fit this model (method {module.hparams.method!r}): "
            f"{' '.join(str(error).split())[:400]}"
        ) from None
