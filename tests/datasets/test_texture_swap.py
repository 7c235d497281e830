"""TextureSwap: stored render passes re-texture the cloth; background and labels stay."""

import dataclasses

import numpy as np
import pytest
import torch

from datasets.augment import TextureSwap
from datasets.clip_dataset import ClothClipDataset, ClothFrameDataset
from datasets.datamodule import ClothVideoDataModule
from datasets.generation import _BACKGROUND_STREAM, _TEXTURE_STREAM, generate_dataset
from render.backgrounds import make_background
from render.effects import VisualEffects
from render.passes import PASS_NAMES, retexture
from render.textures import make_texture

from .conftest import tiny_spec

pytestmark = pytest.mark.render


@pytest.fixture(scope="module")
def passes_dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("passes") / "data"
    assert generate_dataset(tiny_spec(store_passes=True), root, progress=False) is not None
    return root


def test_stored_passes_rebuild_the_stored_frames(passes_dataset):
    clips = ClothClipDataset(passes_dataset, None)
    spec = clips.manifest.spec
    for index, record in enumerate(clips.records):
        assert record["passes"] is True
        _, frames = clips.read(index)
        layers = clips.read_layers(index)
        assert {*PASS_NAMES, "background"} == set(layers)
        background = make_background(
            np.random.default_rng([record["seed"], _BACKGROUND_STREAM]), 32, 32
        )
        np.testing.assert_array_equal(layers["background"][0], background)
        texture = make_texture(
            spec["texture_mode"],
            np.random.default_rng([record["seed"], _TEXTURE_STREAM]),
            spec["texture_size"],
        )
        passes = (layers[name] for name in PASS_NAMES)
        rebuilt = retexture(*passes, clips.read_coverage(index), background, texture)
        assert np.abs(rebuilt.astype(int) - frames).max(-1).mean() < 2.0


def test_datasets_retexture_only_the_cloth_and_only_when_asked(passes_dataset):
    swap = TextureSwap(prob=1.0)
    plain = ClothClipDataset(passes_dataset, "train")
    swapped = ClothClipDataset(passes_dataset, "train", texture_swap=swap)
    torch.manual_seed(0)
    video, reference = swapped[0]["video"], plain[0]["video"]
    cover = torch.from_numpy(plain.read_coverage(0))[:, None].expand_as(video)
    assert torch.equal(video[cover == 0], reference[cover == 0])  # background as rendered
    assert (video[cover == 255] - reference[cover == 255]).abs().mean() > 0.02
    torch.manual_seed(0)
    assert torch.equal(swapped[0]["video"], video), "seeded by torch"
    assert not torch.equal(swapped[0]["video"], video), "a new texture per draw"
    assert swapped[0]["label"] == plain[0]["label"]
    frames = ClothFrameDataset(passes_dataset, "train", texture_swap=swap)
    image = frames[1]["image"]
    empty = torch.from_numpy(plain.read_coverage(0)[1] == 0)
    assert torch.equal(image[:, empty], reference[1][:, empty])
    assert not torch.equal(image, reference[1])
    off = ClothClipDataset(passes_dataset, "train", texture_swap=TextureSwap(prob=0.0))
    assert torch.equal(off[0]["video"], reference)
    module = ClothVideoDataModule(passes_dataset, texture_swap=swap)
    module.setup("fit")
    assert module.datasets["train"].texture_swap is swap
    assert module.datasets["val"].texture_swap is None  # evaluation sees clips as rendered


def test_missing_passes_and_bad_settings_are_named(tiny_dataset):
    with pytest.raises(ValueError, match=r"render\.store_passes=true.*texture_swap\.prob=0"):
        ClothClipDataset(tiny_dataset, "train", texture_swap=TextureSwap(prob=1.0))
    with pytest.raises(ValueError, match=r"data\.texture_swap\.prob"):
        TextureSwap(prob=-0.1)
    with pytest.raises(ValueError, match=r"data\.texture_swap\.mode"):
        TextureSwap(prob=1.0, mode="tartan")
    with pytest.raises(ValueError, match=r"data\.texture_swap\.size"):
        TextureSwap(prob=1.0, size=4)


def test_spec_keeps_old_keys_and_refuses_passes_it_cannot_store():
    spec = tiny_spec()
    assert "store_passes" not in spec.to_json()  # datasets made before the switch keep keys
    with_passes = tiny_spec(store_passes=True)
    assert with_passes.to_json()["store_passes"] is True and with_passes.key() != spec.key()
    assert with_passes.physics_key() == spec.physics_key()  # same meshes: render only
    with pytest.raises(ValueError, match=r"store_passes=true needs render\.store_coverage"):
        tiny_spec(store_passes=True, store_coverage=False)
    frame_rate = dataclasses.replace(VisualEffects(), frame_rate=True)
    with pytest.raises(ValueError, match=r"render\.effects\.frame_rate=false"):
        tiny_spec(store_passes=True, visual=frame_rate)
    with pytest.raises(ValueError, match=r"render\.store_passes must be true or false"):
        tiny_spec(store_passes="yes")
