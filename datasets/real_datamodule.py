"""Lightning DataModule over a folder of real footage (``labels.csv`` and its videos).

Evaluation on real footage is Lightning's test loop over :meth:`RealVideoDataModule.
test_dataloader`: the clips of :class:`~datasets.real_video.RealVideoDataset`, video by video
in ``labels.csv`` order and clip by clip in time, each with its measured values, wind label,
group and video name. The folder is read when the module is made, so its errors (one line each)
come first and a report can check the listed, used and skipped videos before any clip is
predicted.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import lightning as L
from torch.utils.data import DataLoader

from .real_video import RealVideoDataset

__all__ = ["RealVideoDataModule"]


class RealVideoDataModule(L.LightningDataModule):
    """The test loader of one real-footage folder, its clips in order.

    Args:
        root: Folder with ``labels.csv`` and the videos (beside it or in ``videos/``).
        batch_size: Clips per batch.
        **clips: How the videos are cut and which columns the samples carry: the keyword
            arguments of :class:`~datasets.real_video.RealVideoDataset` (``columns``,
            ``group``, ``clip_len``, ``clip_stride``, ``target_fps``, ``size``).

    Attributes:
        dataset: The folder's clips (:class:`~datasets.real_video.RealVideoDataset`): its
            ``videos``, ``skipped``, ``columns`` and group rule are what reports count.
    """

    def __init__(self, root: str | Path, *, batch_size: int = 16, **clips: Any):
        super().__init__()
        self.batch_size = batch_size
        self.dataset = RealVideoDataset(root, **clips)

    def test_dataloader(self) -> DataLoader:
        """Every clip, video by video in ``labels.csv`` order, in one worker."""
        return DataLoader(self.dataset, batch_size=self.batch_size, shuffle=False, num_workers=0)
