"""A new hand-made rung is one entry of the registry: the features, the ladder, the
localisation and the residual stage all take it up (the "How to add a rung" of the docs)."""

import numpy as np
import pytest

from sim2real import rungs
from sim2real.diagnosis import scored_rungs, stage_of_residual
from sim2real.domains import ClipSet
from sim2real.ladder import ladder_features
from sim2real.rungs import Rung, clip_features, hand_rung_names, rungs_revealing


def _mean_luma(clip, box):
    y0, y1, x0, x1 = box
    return np.array([clip[:, y0:y1, x0:x1].mean()], np.float64)


BRIGHTNESS = Rung("brightness", "image", ("mean_luma",), _mean_luma)


@pytest.fixture
def with_brightness(monkeypatch):
    monkeypatch.setattr(rungs, "HAND_RUNGS", (*rungs.HAND_RUNGS, BRIGHTNESS))


def _clips(count=3, frames=6, size=32):
    rng = np.random.default_rng(0)
    return rng.integers(0, 255, size=(count, frames, size, size, 3), dtype=np.uint8)


def test_the_registry_names_what_each_rung_reveals():
    assert hand_rung_names() == ("pixel", "motion", "tracks")
    assert rungs_revealing("image") == ("pixel",)
    assert rungs_revealing("dynamics") == ("motion", "tracks")
    assert rungs.image_proof_rungs() == ("tracks",)  # the dense flow moves with a texture
    with pytest.raises(ValueError, match="reveals must be in"):
        Rung("x", "colour", ("a",), _mean_luma)


def test_a_new_rung_is_measured_on_every_clip(with_brightness):
    features = clip_features(_clips(), (4, 28, 4, 28))
    assert set(features) == {"pixel", "motion", "tracks", "brightness"}
    assert features["brightness"].shape == (3, 1)

    clips = ClipSet(
        frames=_clips(),
        groups=np.array(["a", "b", "c"]),
        class_id=np.zeros(3, int),
        stiffness=np.ones(3),
        density=np.ones(3),
    )
    ladder = ladder_features(clips, (4, 28, 4, 28), net=None)
    assert "brightness" in ladder.rungs


def test_a_new_rung_counts_as_hand_made_in_localisation_and_stage(with_brightness):
    assert hand_rung_names() == ("pixel", "motion", "tracks", "brightness")
    location = {"significant": ["brightness"], "first_significant_layer": None}
    assert scored_rungs(location) == ["brightness"]  # a hand-made rung, not a network layer
    stage = stage_of_residual(location, {}, {"brightness": 0.4})
    assert stage.startswith("appearance or camera")
