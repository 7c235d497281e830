"""Torch datasets over a generated dataset: whole clips or single frames, with labels.

Both read the manifest, take the clips of one split, and decode PNG frames from the
shards on access (a 112 x 112 frame decodes in ~0.1 ms, so nothing is cached). Samples
are dicts so that metadata travels with the pixels through ``default_collate``:

* clip mode: ``video`` float (T, 3, H, W) in [0, 1];
* frame mode: ``image`` float (3, H, W) in [0, 1], ``frame`` its index in the clip;

plus ``label`` (class id 0..53), ``stretch_index`` (0..5), ``bend_index`` (0..8),
``stretch_stiffness`` [N/m], ``bend_stiffness`` [N·m], ``density`` [kg/m²], ``wind_level``
(-1 for the arm), ``key`` (str).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import Dataset

from .manifest import Manifest
from .shards import ShardError, ShardReader, frames_sha256

__all__ = ["ClothClipDataset", "ClothFrameDataset", "clip_tensor"]

_META_KEYS = (
    "stretch_index", "bend_index", "stretch_stiffness", "bend_stiffness", "density", "wind_level",
)  # fmt: skip


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
        self._readers: dict[str, ShardReader] = {}
        self._cache: dict[int, tuple[dict, np.ndarray]] | None = {} if cache else None

    def __len__(self) -> int:
        return len(self.records)

    def read(self, index: int) -> tuple[dict, np.ndarray]:
        """Record and uint8 frames (T, H, W, 3) of clip ``index``."""
        if self._cache is not None and index in self._cache:
            return self._cache[index]
        record = self.records[index]
        name = record["shard"]
        reader = self._readers.get(name)
        if reader is None:
            reader = self._readers[name] = ShardReader(self.manifest.shard_path(name))
        stored, frames = reader.read(record["key"])
        if self.check_clips and frames_sha256(frames) != record["sha256"]:
            raise ShardError(f"clip {record['key']} in {reader.path} does not match its checksum")
        if self._cache is not None:
            self._cache[index] = (stored, frames)
        return stored, frames

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
        video = clip_tensor(frames)
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
    ):
        self.clips = ClothClipDataset(
            root, split, verify=verify, cache=cache, split_protocol=split_protocol
        )
        self.transform = transform
        self.index = [
            (c, t) for c, record in enumerate(self.clips.records)
            for t in range(int(record["frame_count"]))
        ]  # fmt: skip

    def __len__(self) -> int:
        return len(self.index)

    def __getitem__(self, index: int) -> dict:
        clip, t = self.index[index]
        record, frames = self.clips.read(clip)
        image = clip_tensor(frames[t : t + 1])
        if self.transform is not None:
            image = self.transform(image)
        return {"image": image[0], "frame": t, "clip": clip, **ClothClipDataset.targets(record)}
