"""Shared fixtures of the sim-to-real tests."""

import pytest

from datasets.spec import DatasetSpec, SizePreset
from render.camera import CameraSpec
from sim2real.domains import diagnosis_spec
from simulator.cloth.rollout import SimSettings
from simulator.cloth.scenes import ScenarioWind


@pytest.fixture(scope="module")
def nominal() -> DatasetSpec:
    """A tiny nominal domain S: two cloths (classes 0 and 53) at 32 px, two 4-frame clips each."""
    train = DatasetSpec(
        motion="wind",
        scenario=ScenarioWind(resolution_level=1, settle_time=0.2),
        preset=SizePreset(
            "tiny",
            sims_per_class=1,
            clips_per_sim=1,
            val_sims_per_class=0,
            test_sims_per_class=0,
            frames_per_clip=4,
        ),
        classes=(0, 53),
        lead_in=0.2,
        sim=SimSettings(dtype="float32", max_dt=0.00834, settle_max_dt=0.0167),
        camera=CameraSpec.wind(32, 32),
        texture_size=64,
    )
    return diagnosis_spec(train, classes=(0, 53), sims_per_class=1, clips_per_sim=2)
