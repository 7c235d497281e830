"""Second implementations of the image effects for sealed sets: same meaning, other code."""

import dataclasses
import math

import numpy as np
import pytest

from render.effects import VisualEffects, apply_image_effects
from sim2real.study.image_twins import (
    TWIN_EFFECTS,
    apply_image_twins,
    hexagon_kernel,
    without_twinned,
)

OFF = VisualEffects()


def _only(name: str, **params) -> VisualEffects:
    return dataclasses.replace(OFF, **{name: True}, **params)


def _grey(level=128, k=4, size=48) -> np.ndarray:
    return np.full((k, size, size, 3), level, np.uint8)


def test_sensor_noise_has_the_renderers_variance_from_another_model():
    clip = _grey(128, k=8)
    effects = _only("sensor_noise", noise_read_sigma=2.0, noise_shot_gain=0.15)
    twin = apply_image_twins(clip, effects, np.random.default_rng(0)).astype(float)
    library = apply_image_effects(clip, effects, np.random.default_rng(0)).astype(float)
    expected = math.sqrt(2.0**2 + 0.15 * 128)  # read² + gain x level [levels²]
    assert twin.std() == pytest.approx(expected, rel=0.05)
    assert library.std() == pytest.approx(expected, rel=0.05)
    assert not np.array_equal(twin, library)


def test_vignetting_has_the_corner_gain_but_the_cos4_shape():
    clip = _grey(200, k=1, size=64)
    effects = _only("vignetting", vignetting_strength=0.4)
    twin = apply_image_twins(clip, effects, np.random.default_rng(0))[0, ..., 0].astype(float)
    library = apply_image_effects(clip, effects, np.random.default_rng(0))[0, ..., 0]
    assert twin[0, 0] / 200 == pytest.approx(0.6, abs=0.02)  # the corner, as the renderer's
    assert twin[32, 32] / 200 == pytest.approx(1.0, abs=0.01)
    assert abs(twin[16, 16] - float(library[16, 16])) >= 2  # halfway: another falloff


def test_the_hexagonal_aperture_is_normalised_and_six_fold():
    kernel = hexagon_kernel(3.0, 9)
    assert kernel.sum() == pytest.approx(1.0)
    assert kernel[4, 4] == kernel.max() and kernel[0, 0] == 0.0
    np.testing.assert_allclose(kernel, kernel[::-1, ::-1], atol=1e-12)  # point symmetric
    # a hexagon, not a disc: it reaches its circumradius along y, its apothem along x
    wide = hexagon_kernel(6.0, 15)
    assert wide[7, 7 + 5] < 0.85 * wide[7 + 5, 7]
    assert wide[7, 7 + 6] == 0.0 < wide[7 + 6, 7]


def test_defocus_blurs_an_edge_over_its_radius_and_keeps_the_mean():
    clip = np.zeros((1, 32, 32, 3), np.uint8)
    clip[:, :, 16:] = 200
    effects = _only("defocus_blur", defocus_radius_min_px=2.0, defocus_radius_max_px=2.0)
    out = apply_image_twins(clip, effects, np.random.default_rng(0))[0, 10, :, 0].astype(float)
    assert out[:13].max() == 0 and out[19:].min() == 200
    assert 0 < out[15] < 100 < out[16] < 200
    assert out.mean() == pytest.approx(100, abs=1)


def test_white_balance_in_linear_light_and_jpeg_through_pillow():
    rng = np.random.default_rng(1)
    clip = rng.integers(40, 220, size=(2, 32, 32, 3), dtype=np.uint8)
    effects = _only("white_balance", white_balance_shift=0.2)
    twin = apply_image_twins(clip, effects, np.random.default_rng(3)).astype(float)
    ratio = twin.reshape(-1, 3).mean(0) / clip.reshape(-1, 3).mean(0)
    assert np.ptp(ratio) > 0.05  # the channels were scaled apart
    worse = apply_image_twins(clip, _only("compression", jpeg_quality=10), rng)
    better = apply_image_twins(clip, _only("compression", jpeg_quality=90), rng)
    error = lambda out: np.abs(out.astype(float) - clip).mean()  # noqa: E731
    assert error(worse) > error(better) > 0


def test_the_renderer_keeps_the_effects_without_a_twin():
    effects = dataclasses.replace(OFF, **dict.fromkeys(TWIN_EFFECTS, True), motion_blur=True)
    left = without_twinned(effects)
    assert not any(getattr(left, n) for n in TWIN_EFFECTS) and left.motion_blur
    with pytest.raises(ValueError, match="uint8"):
        apply_image_twins(np.zeros((2, 4, 4, 3), np.float32), effects, np.random.default_rng(0))
