"""A tiny but real dataset spec (2 extreme classes, level-1 mesh, 32 x 32 frames)."""

import dataclasses

import cv2
import pytest

from datasets.generation import generate_dataset
from datasets.spec import DatasetSpec, SizePreset
from render.camera import CameraSpec
from simulator.cloth.rollout import SimSettings
from simulator.cloth.scenes import ScenarioWind

TINY_PRESET = SizePreset(
    "tiny",
    sims_per_class=3,
    clips_per_sim=1,
    val_sims_per_class=1,
    test_sims_per_class=1,
    frames_per_clip=4,
    fps=15.0,
)


def tiny_spec(**changes) -> DatasetSpec:
    """Wind, classes 0 and 53, 3 simulations each, one 4-frame clip per simulation."""
    spec = DatasetSpec(
        motion="wind",
        scenario=ScenarioWind(resolution_level=1, settle_time=0.2),
        preset=TINY_PRESET,
        classes=(0, 53),
        lead_in=0.2,
        sim=SimSettings(dtype="float32"),
        camera=CameraSpec.wind(32, 32),
        texture_size=64,
    )
    return dataclasses.replace(spec, **changes)


@pytest.fixture(scope="session")
def tiny_dataset(tmp_path_factory):
    """A generated tiny dataset (shared read-only by the tests that only read it)."""
    root = tmp_path_factory.mktemp("tiny") / "data"
    manifest = generate_dataset(tiny_spec(), root, progress=False)
    assert manifest is not None
    return root


def write_mp4(path, frames, fps):
    """uint8 (T, H, W, 3) BGR frames -> an mp4v file."""
    height, width = frames.shape[1:3]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (width, height))
    assert writer.isOpened()
    for frame in frames:
        writer.write(frame)
    writer.release()
