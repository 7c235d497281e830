"""The seal's out-of-library effects on uint8 frames (no simulation, no rendering)."""

import numpy as np
import pytest

from datasets.spec import DatasetSpec, SizePreset
from sim2real.candidates import candidate_library
from sim2real.seal import OPEN_SET_EFFECTS, _apply_open_set, draw_answer
from simulator.cloth.scenes import ScenarioWind

SPEC = DatasetSpec(motion="wind", scenario=ScenarioWind(), preset=SizePreset("t", 2, 1, 0, 0))


def _line_column(frame: np.ndarray, row: int) -> float:
    """Intensity-weighted column of the bright vertical line in ``row``."""
    weight = frame[row, :, 0].astype(float)
    return float((weight * np.arange(frame.shape[1])).sum() / weight.sum())


def test_barrel_distortion_bows_a_straight_line_and_keeps_the_centre():
    frames = np.zeros((2, 64, 64, 3), np.uint8)
    frames[:, :, 47:49] = 255  # a vertical line right of the centre
    frames[:, 31:33, 31:33] = 128  # a mark at the centre
    out = _apply_open_set(frames, "barrel_distortion", 0.25)
    assert out.dtype == np.uint8 and out.shape == frames.shape
    near_axis, top = _line_column(out[0], 24), _line_column(out[0], 0)
    # Barrel: content is pulled towards the centre, the more the farther out it lies
    # (the line at u = 0.5 shows at u (1 + k r²) = 0.5: u 0.48 near the axis, 0.44 at the top).
    assert 45.3 < top < 45.8 < 46.6 < near_axis < 47.0
    np.testing.assert_array_equal(out[0, 31:33, 31:33], frames[0, 31:33, 31:33])


@pytest.mark.parametrize(
    "name", sorted(n for n, (stage, _) in OPEN_SET_EFFECTS.items() if stage == "camera")
)  # the scene change (wind speed) is applied to the scene, not to frames
def test_every_image_open_set_effect_changes_frames_and_keeps_uint8(name):
    rng = np.random.default_rng(0)
    frames = rng.integers(0, 256, size=(3, 32, 32, 3), dtype=np.uint8)
    low, high = OPEN_SET_EFFECTS[name][1]
    out = _apply_open_set(frames, name, 0.5 * (low + high))
    assert out.dtype == np.uint8 and out.shape == frames.shape
    assert np.abs(out.astype(int) - frames).mean() > 1.0


def test_no_open_set_effect_is_a_library_effect():
    library = candidate_library(SPEC)
    short = {name.split(".", 1)[1] for name in library}
    assert not short & set(OPEN_SET_EFFECTS)
    assert "visual.vignetting" in library  # it joined the library after blind round 8
    drawn = {draw_answer(seed, library, "open")["effects"][0]["name"] for seed in range(40)}
    assert drawn == set(OPEN_SET_EFFECTS)
