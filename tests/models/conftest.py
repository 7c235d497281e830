"""A tiny generated dataset and a tiny real-video folder for the model and pipeline tests."""

import dataclasses

import numpy as np
import pytest

from datasets.generation import generate_dataset
from datasets.spec import SizePreset
from tests.datasets.conftest import tiny_spec, write_mp4

# 2 classes x 4 simulations (2 train, 1 val, 1 test), 4-frame 32 x 32 clips.
MODEL_PRESET = SizePreset(
    "tiny", sims_per_class=4, clips_per_sim=1, val_sims_per_class=1, test_sims_per_class=1,
    frames_per_clip=4, fps=15.0,
)  # fmt: skip


@pytest.fixture(scope="session")
def model_dataset(tmp_path_factory):
    """Generated wind clips of classes 0 and 53 (read-only for the tests)."""
    root = tmp_path_factory.mktemp("model-data") / "wind-tiny"
    spec = dataclasses.replace(tiny_spec(), preset=MODEL_PRESET)
    assert generate_dataset(spec, root, progress=False) is not None
    return root


@pytest.fixture
def real_folder(tmp_path):
    """Four short synthetic 'fabric' videos with stiffness, density and wind labels."""
    rows = ["video,stiffness,density,wind"]
    for i in range(4):
        base = np.random.default_rng(i).integers(0, 255, size=(40, 48, 3), dtype=np.uint8)
        frames = np.stack([np.roll(base, (i + 1) * t, axis=1) for t in range(12)])
        write_mp4(tmp_path / f"fabric{i}.mp4", frames, 15.0)
        rows.append(f"fabric{i}.mp4,{1.0 + i},{0.2 + 0.1 * i**2},W{1 + i % 2}")
    (tmp_path / "labels.csv").write_text("\n".join(rows) + "\n")
    return tmp_path
