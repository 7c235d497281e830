"""Torch datasets (clip and frame mode) and the Lightning DataModule."""

import pytest
import torch

from datasets.augment import ClipAugment
from datasets.clip_dataset import ClothClipDataset, ClothFrameDataset
from datasets.datamodule import ClothVideoDataModule

pytestmark = pytest.mark.render


def test_clip_and_frame_modes(tiny_dataset):
    clips = ClothClipDataset(tiny_dataset, "train")
    assert len(clips) == 2
    sample = clips[0]
    assert sample["video"].shape == (4, 3, 32, 32)
    assert sample["label"] in (0, 53) and sample["stretch_index"] in (0, 5)
    assert sample["clip_index"] == 0  # one clip per simulation in the tiny preset
    frames = ClothFrameDataset(tiny_dataset, "train")
    assert len(frames) == 8
    frame = frames[5]
    assert frame["image"].shape == (3, 32, 32) and frame["frame"] == 1
    assert torch.equal(frame["image"], clips[frame["clip"]]["video"][1])


def test_datamodule_batches(tiny_dataset):
    module = ClothVideoDataModule(tiny_dataset, batch_size=2, augment=ClipAugment())
    module.setup("fit")
    batch = next(iter(module.train_dataloader()))
    assert batch["video"].shape == (2, 4, 3, 32, 32)
    assert batch["label"].dtype == torch.int64
    assert len(batch["key"]) == 2
    module = ClothVideoDataModule([tiny_dataset, tiny_dataset], mode="frame", batch_size=3)
    module.setup("test")
    batch = next(iter(module.test_dataloader()))
    assert batch["image"].shape == (3, 3, 32, 32)
    assert len(module.datasets["test"]) == 2 * 2 * 4  # 2 datasets x 2 clips x 4 frames


def test_augment_keeps_shape_and_range():
    torch.manual_seed(0)
    clip = torch.rand(5, 3, 24, 24)
    out = ClipAugment()(clip)
    assert out.shape == clip.shape and 0 <= float(out.min()) and float(out.max()) <= 1
    with pytest.raises(ValueError, match="crop_scale"):
        ClipAugment(crop_scale=(0.0, 1.0))


def test_bad_arguments_are_named(tmp_path, tiny_dataset):
    with pytest.raises(FileNotFoundError, match="does not exist"):
        ClothVideoDataModule(tmp_path / "nowhere")
    with pytest.raises(ValueError, match="mode"):
        ClothVideoDataModule(tiny_dataset, mode="video")
    with pytest.raises(ValueError, match="batch_size"):
        ClothVideoDataModule(tiny_dataset, batch_size=0)
    with pytest.raises(FileNotFoundError, match="not a finished dataset"):
        ClothClipDataset(tmp_path)
    with pytest.raises(ValueError, match="split"):
        ClothClipDataset(tiny_dataset, "holdout")
