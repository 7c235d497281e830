"""Lightning DataModule over one or more generated datasets (clip or frame mode).

The labels travel with the data: the module reads its datasets' material set (the class grid)
from their manifests and hands it on as plain numbers (:attr:`ClothVideoDataModule.num_classes`,
:attr:`~ClothVideoDataModule.class_grid`), which ``train.py`` gives the net and the
LightningModule.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import lightning as L
import torch
from torch.utils.data import ConcatDataset, DataLoader, Dataset

from simulator.cloth.material import MaterialSet

from .augment import BackgroundSwap, ClipAugment, TextureSwap
from .clip_dataset import ClothClipDataset, ClothFrameDataset
from .manifest import SPLIT_PROTOCOLS, Manifest
from .spec import check_int

__all__ = ["ClothVideoDataModule"]

MODES = ("clip", "frame")


class ClothVideoDataModule(L.LightningDataModule):
    """Train/val/test loaders of generated cloth datasets.

    Args:
        data_dirs: One dataset directory or several (concatenated, e.g. wind + arm).
        mode: ``clip`` (samples ``video`` (T, 3, H, W)) or ``frame`` (``image`` (3, H, W)).
        eval_mode: Mode of the val/test/predict splits (``None`` = ``mode``); a per-frame
            baseline trains on frames (``frame``) but is scored on whole clips (``clip``).
        batch_size: Samples per batch.
        num_workers: Data-loader worker processes.
        augment: Apply :class:`ClipAugment` to training samples (``None`` = off).
        verify: Check shard checksums when the datasets are opened.
        cache: Keep decoded clips in memory (see :class:`ClothClipDataset`).
        split_protocol: ``simulation`` (held-out simulations, the default) or ``sequence``
            (the thesis's sub-sequence split); see :data:`~datasets.manifest.SPLIT_PROTOCOLS`.
        background_swap: New backgrounds behind the training samples' cloth
            (:class:`BackgroundSwap`; ``None`` or ``prob=0`` = off).
        texture_swap: New textures on the training samples' cloth (:class:`TextureSwap`;
            ``None`` or ``prob=0`` = off).
    """

    def __init__(
        self,
        data_dirs: str | Path | Sequence[str | Path],
        *,
        mode: str = "clip",
        eval_mode: str | None = None,
        batch_size: int = 16,
        num_workers: int = 0,
        augment: ClipAugment | None = None,
        verify: bool = True,
        cache: bool = False,
        split_protocol: str = "simulation",
        background_swap: BackgroundSwap | None = None,
        texture_swap: TextureSwap | None = None,
    ):
        super().__init__()
        if split_protocol not in SPLIT_PROTOCOLS:
            raise ValueError(
                f"split_protocol must be one of {SPLIT_PROTOCOLS}, got {split_protocol!r}"
            )
        eval_mode = mode if eval_mode is None else eval_mode
        for name, value in (("mode", mode), ("eval_mode", eval_mode)):
            if value not in MODES:
                raise ValueError(f"{name} must be one of {MODES}, got {value!r}")
        check_int("batch_size", batch_size)
        check_int("num_workers", num_workers, low=0)
        dirs = [data_dirs] if isinstance(data_dirs, str | Path) else list(data_dirs)
        if not dirs:
            raise ValueError("data_dirs must name at least one dataset directory")
        for path in dirs:
            if not Path(path).is_dir():
                raise FileNotFoundError(f"data directory {path} does not exist")
        self.data_dirs = [Path(p) for p in dirs]
        self.eval_mode = eval_mode
        self.mode, self.batch_size, self.num_workers = mode, batch_size, num_workers
        self.augment, self.verify, self.cache = augment, verify, cache
        self.split_protocol = split_protocol
        self.background_swap = background_swap
        self.texture_swap = texture_swap
        self.datasets: dict[str, Dataset] = {}
        self._material_set: MaterialSet | None = None

    @property
    def material_set(self) -> MaterialSet:
        """The datasets' material set, read from their manifests (all must share it)."""
        if self._material_set is None:
            sets = {path: Manifest.load(path).material_set for path in self.data_dirs}
            first = next(iter(sets.values()))
            other = next((p for p, m in sets.items() if m != first), None)
            if other is not None:
                raise ValueError(
                    f"data_dirs must share one material set (class grid): {self.data_dirs[0]} "
                    f"has {first.name} ({first.num_classes} classes), {other} has "
                    f"{sets[other].name} ({sets[other].num_classes} classes)"
                )
            self._material_set = first
        return self._material_set

    @property
    def num_classes(self) -> int:
        """Classes of the material set (the classifier's outputs)."""
        return self.material_set.num_classes

    @property
    def stretch_count(self) -> int:
        """Stretch indices of the class grid (class id = stretch index * bend count + bend)."""
        return self.material_set.stretch_count

    @property
    def bend_count(self) -> int:
        """Bend indices of the class grid."""
        return self.material_set.bend_count

    @property
    def stretch_multipliers(self) -> list[float]:
        """The basis fabric's stretching multiplier of each stretch index."""
        return list(self.material_set.stretch_multipliers)

    @property
    def bend_multipliers(self) -> list[float]:
        """The basis fabric's bending multiplier of each bend index."""
        return list(self.material_set.bend_multipliers)

    @property
    def class_grid(self) -> dict:
        """The material set as plain JSON (multipliers and counts), for the models."""
        return self.material_set.to_json()

    def _build(self, split: str) -> Dataset:
        mode = self.mode if split == "train" else self.eval_mode
        cls = ClothClipDataset if mode == "clip" else ClothFrameDataset
        transform = self.augment if split == "train" else None
        parts = [
            cls(
                path,
                split,
                transform=transform,
                verify=self.verify,
                cache=self.cache,
                split_protocol=self.split_protocol,
                background_swap=self.background_swap if split == "train" else None,
                texture_swap=self.texture_swap if split == "train" else None,
            )
            for path in self.data_dirs
        ]
        return parts[0] if len(parts) == 1 else ConcatDataset(parts)

    def setup(self, stage: str | None = None) -> None:
        """Open the splits that ``stage`` needs (all for ``None``)."""
        wanted = {
            "fit": ("train", "val"),
            "validate": ("val",),
            "test": ("test",),
            "predict": ("test",),
        }.get(stage or "", ("train", "val", "test"))
        for split in wanted:
            if split not in self.datasets:
                self.datasets[split] = self._build(split)

    def _loader(self, split: str, shuffle: bool) -> DataLoader:
        if split not in self.datasets:
            self.datasets[split] = self._build(split)
        return DataLoader(
            self.datasets[split],
            batch_size=self.batch_size,
            shuffle=shuffle,
            num_workers=self.num_workers,
            pin_memory=torch.cuda.is_available(),
            persistent_workers=self.num_workers > 0,
            drop_last=False,
        )

    def train_dataloader(self) -> DataLoader:
        """Shuffled training batches."""
        return self._loader("train", shuffle=True)

    def val_dataloader(self) -> DataLoader:
        """Validation batches in manifest order."""
        return self._loader("val", shuffle=False)

    def test_dataloader(self) -> DataLoader:
        """Test batches in manifest order."""
        return self._loader("test", shuffle=False)

    def predict_dataloader(self) -> DataLoader:
        """Same as the test loader."""
        return self._loader("test", shuffle=False)
