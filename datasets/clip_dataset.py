"""Torch datasets over a generated dataset: whole clips or single frames, with labels.

Both read the manifest, take the clips of one split, and decode PNG frames from the
shards on access (a 112 x 112 frame decodes in ~0.1 ms, so nothing is cached). Samples
are dicts so that metadata travels with the pixels through ``default_collate``:

* clip mode: ``video`` float (T, 3, H, W) in [0, 1];
* frame mode: ``image`` float (3, H, W) in [0, 1], ``frame`` its index in the clip;

plus ``label`` (class id 0..53), ``stretch_index`` (0..5), ``bend_index`` (0..8),
``stretch_stiffness`` [N/m], ``bend_stiffness`` [N·m], ``density`` [kg/m²], ``wind_level``
(-1 for the arm), ``clip_index`` (the clip's position in its simulation, 0 first), ``key`` (str).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import Dataset

from render.passes import PASS_NAMES

from .augment import BackgroundSwap, TextureSwap
from .manifest import Manifest
from .shards import ShardError, ShardReader, frames_sha256

__all__ = ["ClothClipDataset", "ClothFrameDataset", "clip_tensor"]

_META_KEYS = (
    "stretch_index",
    "bend_index",
    "stretch_stiffness",
    "bend_stiffness",
    "density",
    "wind_level",
    "clip_index",
)


def clip_tensor(frames: np.ndarray) -> torch.Tensor:
    """uint8 (T, H, W, 3) -> float (T, 3, H, W) in [0, 1]."""
    return torch.from_numpy(np.ascontiguousarray(frames)).permute(0, 3, 1, 2).float() / 255.0


class ClothClipDataset(Dataset):
    """The clips of one split of a generated dataset.

    Args:
        root: Dataset directory (holds ``manifest.json``).
        split: ``train``, ``val``, ``test`` or ``None`` for all.
        transform: Called on each ``video`` tensor (T, 3, H, W), e.g. :class:`ClipAugment`.
        verify: Check every shard's checksum first (a missing or corrupted shard raises
            :class:`~datasets.shards.ShardError` naming it).
        check_clips: Also compare each decoded clip with its recorded pixel checksum.
        cache: Keep each decoded clip (uint8) in memory after its first read, so later
            epochs skip PNG decoding (a full preset is ~0.75 GB per process).
        split_protocol: How clips are assigned to splits, one of
            :data:`~datasets.manifest.SPLIT_PROTOCOLS` (``simulation``: as generated).
        background_swap: Re-composite each clip over a new background before
            ``transform`` (:class:`~datasets.augment.BackgroundSwap`); needs a dataset
            generated with ``render.store_coverage=true``.
        texture_swap: Re-texture each clip's cloth before the background swap
            (:class:`~datasets.augment.TextureSwap`); needs a dataset generated with
            ``render.store_passes=true``.
    """

    def __init__(
        self,
        root: str | Path,
        split: str | None = "train",
        *,
        transform: Callable[[torch.Tensor], torch.Tensor] | None = None,
        verify: bool = True,
        check_clips: bool = False,
        cache: bool = False,
        split_protocol: str = "simulation",
        background_swap: BackgroundSwap | None = None,
        texture_swap: TextureSwap | None = None,
    ):
        self.manifest = Manifest.load(root)
        self.split = split
        self.records = self.manifest.clips_of(split, split_protocol)
        if not self.records:
            raise ValueError(f"split {split!r} of {root} has no clips")
        if verify:  # only the shards this split reads: each split opens once
            self.manifest.verify(names={r["shard"] for r in self.records})
        self.transform = transform
        self.check_clips = check_clips
        self.background_swap = self._swap_if_stored(
            root, background_swap, "background_swap", "coverage", "coverage", "store_coverage"
        )
        self.texture_swap = self._swap_if_stored(
            root, texture_swap, "texture_swap", "passes", "render passes", "store_passes"
        )
        self._readers: dict[str, ShardReader] = {}
        self._cache: dict[int, tuple[dict, np.ndarray]] | None = {} if cache else None
        self._coverage_cache: dict[int, np.ndarray] | None = {} if cache else None
        self._layer_cache: dict[int, dict[str, np.ndarray]] | None = {} if cache else None

    def _swap_if_stored(self, root, swap, name: str, flag: str, what: str, switch: str):
        """``swap`` if it is on (``None`` if off), after checking every clip stored ``flag``."""
        if swap is None or not swap.enabled:
            return None
        lacking = [r["key"] for r in self.records if not r.get(flag, False)]
        if lacking:
            raise ValueError(
                f"data.{name} needs each clip's {what}, but {len(lacking)} clips of {root} "
                f"(e.g. {lacking[0]}) have none: regenerate the dataset with "
                f"render.{switch}=true, or set data.{name}.prob=0"
            )
        return swap

    def __len__(self) -> int:
        return len(self.records)

    def _reader(self, record: dict) -> ShardReader:
        name = record["shard"]
        reader = self._readers.get(name)
        if reader is None:
            reader = self._readers[name] = ShardReader(self.manifest.shard_path(name))
        return reader

    def read(self, index: int) -> tuple[dict, np.ndarray]:
        """Record and uint8 frames (T, H, W, 3) of clip ``index``."""
        if self._cache is not None and index in self._cache:
            return self._cache[index]
        record = self.records[index]
        reader = self._reader(record)
        stored, frames = reader.read(record["key"])
        if self.check_clips and frames_sha256(frames) != record["sha256"]:
            raise ShardError(f"clip {record['key']} in {reader.path} does not match its checksum")
        if self._cache is not None:
            self._cache[index] = (stored, frames)
        return stored, frames

    def read_coverage(self, index: int) -> np.ndarray:
        """The cloth's coverage uint8 (T, H, W) of clip ``index`` (0 = background only)."""
        if self._coverage_cache is not None and index in self._coverage_cache:
            return self._coverage_cache[index]
        record = self.records[index]
        reader = self._reader(record)
        coverage = reader.read_coverage(record["key"], int(record["frame_count"]))
        if coverage is None:
            raise ShardError(f"clip {record['key']} in {reader.path} has no coverage stored")
        if self._coverage_cache is not None:
            self._coverage_cache[index] = coverage
        return coverage

    def read_layers(self, index: int) -> dict[str, np.ndarray]:
        """Render passes (T, H, W, 3) and background (1, H, W, 3) of clip ``index``, uint8."""
        if self._layer_cache is not None and index in self._layer_cache:
            return self._layer_cache[index]
        record = self.records[index]
        reader = self._reader(record)
        count = int(record["frame_count"])
        layers = {}
        for name, images in (*((n, count) for n in PASS_NAMES), ("background", 1)):
            layer = reader.read_layer(record["key"], name, images)
            if layer is None:
                raise ShardError(f"clip {record['key']} in {reader.path} has no {name!r} layer")
            layers[name] = layer
        if self._layer_cache is not None:
            self._layer_cache[index] = layers
        return layers

    def swapped(self, index: int, pixels: np.ndarray, frames: slice = slice(None)):
        """Frames ``frames`` of clip ``index`` (``pixels``, uint8) as a float clip tensor.

        Re-textured and over a new background where those swaps are enabled.
        """
        if self.texture_swap is not None:
            layers = {
                name: layer if name == "background" else layer[frames]
                for name, layer in self.read_layers(index).items()
            }
            coverage = self.read_coverage(index)[frames]
            retextured = self.texture_swap(layers, coverage)
            pixels = pixels if retextured is None else retextured
        video = clip_tensor(pixels)
        if self.background_swap is None:
            return video
        coverage = torch.from_numpy(self.read_coverage(index)[frames])
        return self.background_swap(video, coverage)

    @staticmethod
    def targets(record: dict) -> dict:
        """Label and metadata entries of a sample."""
        out = {"label": int(record["class_id"]), "key": record["key"]}
        for name in _META_KEYS:
            value = record[name]
            out[name] = int(value) if isinstance(value, int) else float(value)
        return out

    def __getitem__(self, index: int) -> dict:
        record, frames = self.read(index)
        video = self.swapped(index, frames)
        if self.transform is not None:
            video = self.transform(video)
        return {"video": video, **self.targets(record)}


class ClothFrameDataset(Dataset):
    """Every frame of every clip of one split, for per-frame baselines (thesis 7.7.2.1)."""

    def __init__(
        self,
        root: str | Path,
        split: str | None = "train",
        *,
        transform: Callable[[torch.Tensor], torch.Tensor] | None = None,
        verify: bool = True,
        cache: bool = False,
        split_protocol: str = "simulation",
        background_swap: BackgroundSwap | None = None,
        texture_swap: TextureSwap | None = None,
    ):
        self.clips = ClothClipDataset(
            root,
            split,
            verify=verify,
            cache=cache,
            split_protocol=split_protocol,
            background_swap=background_swap,
            texture_swap=texture_swap,
        )
        self.transform = transform
        self.index = [
            (c, t)
            for c, record in enumerate(self.clips.records)
            for t in range(int(record["frame_count"]))
        ]

    def __len__(self) -> int:
        return len(self.index)

    def __getitem__(self, index: int) -> dict:
        clip, t = self.index[index]
        record, frames = self.clips.read(clip)
        image = self.clips.swapped(clip, frames[t : t + 1], slice(t, t + 1))
        if self.transform is not None:
            image = self.transform(image)
        return {"image": image[0], "frame": t, "clip": clip, **ClothClipDataset.targets(record)}
