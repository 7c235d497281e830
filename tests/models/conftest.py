"""A tiny generated dataset and a tiny real-video folder for the model and pipeline tests."""

import dataclasses

import numpy as np
import pytest

from datasets.generation import generate_dataset
from datasets.spec import SizePreset
from tests.datasets.conftest import tiny_spec, write_mp4

# 2 classes x 4 simulations (2 train, 1 val, 1 test), 4-frame 32 x 32 clips.
MODEL_PRESET = SizePreset(
    "tiny",
    sims_per_class=4,
    clips_per_sim=1,
    val_sims_per_class=1,
    test_sims_per_class=1,
    frames_per_clip=4,
    fps=15.0,
)


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


TINY_NET = {
    "_target_": "models.components.video_nets.CNNLSTMNet",
    "encoder": {
        "_target_": "models.components.frame_encoder.FrameEncoder",
        "name": "alexnet5",
        "feature_dim": 16,
        "width": 0.25,
    },
    "hidden_size": 8,
}


def write_checkpoint(path, classes=54, grid=None):
    """An untrained CNN+LSTM checkpoint in train.py's format, predicting ``classes`` classes.

    ``grid`` (a :class:`~common.grid.ClassGrid`) is recorded as its ``class_grid`` and sets the
    class count; without it the checkpoint records none (read as ``wang54``'s).
    """
    import torch
    from hydra.utils import instantiate

    from models.material_classifier import MaterialClassifierModule

    if grid is not None:
        classes = grid.num_classes
    config = {**TINY_NET, "num_classes": classes}
    torch.manual_seed(0)
    module = MaterialClassifierModule(instantiate(config), net_config=config, method="tiny")
    path.parent.mkdir(parents=True, exist_ok=True)
    hparams = {"net_config": config, "method": "tiny"}
    if grid is not None:
        hparams["class_grid"] = grid.to_json()
    torch.save({"hyper_parameters": hparams, "state_dict": module.state_dict()}, path)
    return path


FABRICS = 6
"""Fabrics of :func:`fabric_folder`, each filmed at W1, W2 and W3."""


@pytest.fixture
def fabric_folder(tmp_path):
    """Bouman-style real set: 6 fabrics x 3 winds in ``videos/``, plus one too-short video.

    ``labels.csv`` has a ``fabric`` group column and a ``bending_rigidity`` column; a fabric's
    measured values repeat on its three rows.
    """
    root = tmp_path / "fabrics"
    (root / "videos").mkdir(parents=True)
    rows = ["video,fabric,stiffness,density,bending_rigidity,wind"]
    for f in range(FABRICS):
        for w in range(3):
            rng = np.random.default_rng(10 * f + w)
            base = rng.integers(0, 255, size=(24, 32, 3), dtype=np.uint8)
            frames = np.stack([np.roll(base, (f + w + 1) * t, axis=1) for t in range(8)])
            write_mp4(root / "videos" / f"f{f}_w{w + 1}.mp4", frames, 15.0)
            rows.append(
                f"f{f}_w{w + 1}.mp4,fabric{f},{1.0 + f},{0.1 + 0.05 * f**2},"
                f"{(f - 2.5) ** 2},W{w + 1}"
            )
    short = np.zeros((2, 24, 32, 3), dtype=np.uint8)
    write_mp4(root / "videos" / "short.mp4", short, 15.0)
    rows.append("short.mp4,fabric9,9.0,0.9,1.0,W1")
    (root / "labels.csv").write_text("\n".join(rows) + "\n")
    return root
