"""BackgroundSwap: the cloth stays, the background is new, and the stored coverage is right."""

import json
import shutil

import numpy as np
import pytest
import torch

from datasets.augment import BackgroundSwap
from datasets.clip_dataset import ClothClipDataset, ClothFrameDataset
from datasets.generation import _BACKGROUND_STREAM
from datasets.manifest import Manifest
from render.backgrounds import make_background

pytestmark = pytest.mark.render


def _video_and_cover():
    video = torch.rand(3, 3, 8, 10, generator=torch.Generator().manual_seed(0))
    cover = torch.zeros(3, 8, 10, dtype=torch.uint8)
    cover[:, 2:6, 3:7] = 255
    cover[:, 1, 3:7] = 128
    return video, cover


def test_swap_keeps_the_covered_pixels_and_replaces_the_rest_identically_per_frame():
    video, cover = _video_and_cover()
    torch.manual_seed(1)
    out = BackgroundSwap(prob=1.0)(video, cover)
    full, empty = (cover == 255)[:, None].expand_as(video), (cover == 0)[:, None].expand_as(video)
    assert torch.equal(out[full], video[full])
    assert not torch.allclose(out[empty], video[empty])
    assert torch.equal(out[0][empty[0]], out[2][empty[2]]), "one background per clip"
    # Partly covered pixels blend: what is left after the cloth's share is the same
    # background in every frame.
    alpha = 128 / 255
    behind = (out[:, :, 1, 3:7] - alpha * video[:, :, 1, 3:7]) / (1 - alpha)
    torch.testing.assert_close(behind, behind[:1].expand_as(behind))
    assert out.min() >= 0 and out.max() <= 1
    torch.manual_seed(1)
    assert torch.equal(out, BackgroundSwap(prob=1.0)(video, cover)), "seeded by torch"
    assert not torch.equal(out, BackgroundSwap(prob=1.0)(video, cover)), "a new one per draw"
    assert torch.equal(BackgroundSwap(prob=0.0)(video, cover), video)


def test_bad_probability_and_coverage_shape_are_named():
    with pytest.raises(ValueError, match=r"data\.background_swap\.prob"):
        BackgroundSwap(prob=1.5)
    video, cover = _video_and_cover()
    with pytest.raises(ValueError, match="coverage must have shape"):
        BackgroundSwap(prob=1.0)(video, cover[:2])


def test_stored_coverage_is_the_alpha_the_generator_composited_with(tiny_dataset):
    clips = ClothClipDataset(tiny_dataset, None)
    for index, record in enumerate(clips.records):
        assert record["coverage"] is True
        _, frames = clips.read(index)
        cover = clips.read_coverage(index)
        assert cover.shape == frames.shape[:3] and (cover == 255).any()
        background = make_background(
            np.random.default_rng([record["seed"], _BACKGROUND_STREAM]), 32, 32
        )
        empty = cover == 0
        behind = np.broadcast_to(background, frames.shape)
        np.testing.assert_array_equal(frames[empty], behind[empty])


def test_datasets_swap_only_when_asked_and_keep_the_cloth(tiny_dataset):
    swap = BackgroundSwap(prob=1.0)
    plain = ClothClipDataset(tiny_dataset, "train")
    swapped = ClothClipDataset(tiny_dataset, "train", background_swap=swap)
    torch.manual_seed(0)
    video, reference = swapped[0]["video"], plain[0]["video"]
    full = torch.from_numpy(plain.read_coverage(0) == 255)[:, None].expand_as(video)
    assert torch.equal(video[full], reference[full]) and not torch.equal(video, reference)
    frames = ClothFrameDataset(tiny_dataset, "train", background_swap=swap)
    sample = frames[1]
    assert (sample["clip"], sample["frame"]) == (0, 1)
    cover = torch.from_numpy(plain.read_coverage(0)[1] == 255)
    assert torch.equal(sample["image"][:, cover], reference[1][:, cover])
    assert not torch.equal(sample["image"], reference[1])
    off = ClothClipDataset(tiny_dataset, "train", background_swap=BackgroundSwap(prob=0.0))
    assert torch.equal(off[0]["video"], reference)


def test_a_dataset_without_coverage_names_the_switches(tiny_dataset, tmp_path):
    root = tmp_path / "old"
    shutil.copytree(tiny_dataset, root)
    data = json.loads((root / "manifest.json").read_text())
    for record in data["clips"]:
        record.pop("coverage")
    (root / "manifest.json").write_text(json.dumps(data))
    assert Manifest.load(root).clips
    ClothClipDataset(root, "train")  # reading without swapping is fine
    with pytest.raises(ValueError, match=r"render\.store_coverage=true.*background_swap\.prob=0"):
        ClothClipDataset(root, "train", background_swap=BackgroundSwap(prob=1.0))
