"""Visual effects: config parsing, and every image-space effect on uint8 clips (no rendering)."""

import dataclasses

import numpy as np
import pytest

from render.effects import (
    DETERMINISTIC_EFFECTS,
    EFFECT_NAMES,
    IMAGE_EFFECT_ORDER,
    IMAGE_EFFECT_PARAMETERS,
    RANDOM_EFFECTS,
    RENDER_EFFECTS,
    VisualEffects,
    apply_image_effects,
    apply_jpeg,
    apply_vignetting,
    effect_streams,
    resample_frame_rate,
    resampled_frame_count,
    shake_offsets,
    source_frame_count,
)
from render.textures import make_texture


@pytest.fixture
def clip():
    """Four 40 x 40 frames of a textured pattern sliding right by 2 px per frame."""
    texture = make_texture("random", np.random.default_rng(0), size=64, kinds=["noise"])
    return np.stack([texture[10:50, 2 * k : 2 * k + 40] for k in range(4)])


def test_all_effects_off_by_default_and_partitioned():
    effects = VisualEffects()
    assert not any(effects.enabled().values())
    assert set(EFFECT_NAMES) == set(IMAGE_EFFECT_ORDER) | set(RENDER_EFFECTS)
    assert len(EFFECT_NAMES) == 12


def test_before_image_effects_keeps_what_the_renderer_draws_and_resets_the_rest():
    fields = {f.name: f for f in dataclasses.fields(VisualEffects)}
    assert set(IMAGE_EFFECT_PARAMETERS) <= set(fields)
    # Every strength of an image effect is one of its parameters.
    assert {
        n for n, f in fields.items() if f.metadata.get("strength_of") in IMAGE_EFFECT_ORDER
    } <= set(IMAGE_EFFECT_PARAMETERS)
    # The renderer reads none of them (it hands them to apply_image_effects whole).
    from pathlib import Path

    import render.renderer

    source = Path(render.renderer.__file__).read_text()
    assert not [n for n in IMAGE_EFFECT_PARAMETERS if f"effects.{n}" in source]
    everything = VisualEffects(
        **dict.fromkeys(EFFECT_NAMES, True),
        noise_read_sigma=6.0,
        jpeg_quality=20,
        frame_rate_ratio=2.0,
        specular_roughness=0.2,
        shake_translation=0.01,
    )
    base = everything.before_image_effects()
    assert not any(getattr(base, n) for n in IMAGE_EFFECT_ORDER)
    assert all(getattr(base, n) for n in RENDER_EFFECTS)
    assert (base.specular_roughness, base.shake_translation) == (0.2, 0.01)
    defaults = VisualEffects()
    assert all(getattr(base, n) == getattr(defaults, n) for n in IMAGE_EFFECT_PARAMETERS)
    assert VisualEffects(sensor_noise=True, noise_read_sigma=6.0).before_image_effects() == defaults


def test_from_dict_names_unknown_keys_and_the_allowed_ones():
    with pytest.raises(ValueError, match="foo") as info:
        VisualEffects.from_dict({"foo": 1, "sensor_noise": True})
    assert "motion_blur" in str(info.value)
    effects = VisualEffects.from_dict({"compression": True, "jpeg_quality": 80})
    assert effects.compression and effects.jpeg_quality == 80
    assert VisualEffects.from_dict(None) == VisualEffects()


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("jpeg_quality", 0),
        ("jpeg_quality", 101),
        ("motion_blur_samples", 1),
        ("motion_blur_shutter", 0.0),
        ("frame_rate_ratio", -1.0),
        ("frame_rate_mode", "cubic"),
        ("sensor_noise", "yes"),
        ("specular_roughness", 2.0),
        ("defocus_radius_min_px", 5.0),
        ("vignetting_strength", 1.5),
        ("rolling_shutter_readout", 1.2),
        ("rolling_shutter_bands", 0),
    ],
)
def test_bad_parameters_raise_naming_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        VisualEffects(**{field: value})


@pytest.mark.parametrize("name", IMAGE_EFFECT_ORDER)
def test_each_image_effect_changes_the_clip_and_keeps_uint8(clip, name):
    effects = VisualEffects(**{name: True})
    out = apply_image_effects(clip, effects, np.random.default_rng(1))
    assert out.dtype == np.uint8 and out.shape[1:] == clip.shape[1:]
    if name == "frame_rate":
        # Default ratio 1/2: 4 frames at times 0..3 -> 2 frames at times 0 and 2.
        assert out.shape[0] == resampled_frame_count(4, effects.frame_rate_ratio) == 2
        np.testing.assert_array_equal(out, clip[[0, 2]])
        # A non-integer ratio blends neighbours: times 0, 2/3, 4/3, 2, 8/3.
        out = apply_image_effects(
            clip, VisualEffects(frame_rate=True, frame_rate_ratio=1.5), np.random.default_rng(1)
        )
        assert out.shape[0] == 5
        changed = [np.abs(out[1].astype(int) - clip[k]).mean() for k in (0, 1)]
        assert min(changed) > 0.5
    else:
        assert out.shape[0] == clip.shape[0]
        assert np.abs(out.astype(int) - clip).mean() > 0.5, name
    np.testing.assert_array_equal(
        apply_image_effects(clip, effects, np.random.default_rng(1)),
        apply_image_effects(clip, effects, np.random.default_rng(1)),
    )


def test_compression_round_trips_through_cv2(clip):
    import cv2

    out = apply_jpeg(clip, 40)
    for k in range(clip.shape[0]):
        ok, data = cv2.imencode(".jpg", clip[k][..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, 40])
        assert ok
        np.testing.assert_array_equal(out[k], cv2.imdecode(data, cv2.IMREAD_COLOR)[..., ::-1])
    error = {q: np.abs(apply_jpeg(clip, q).astype(int) - clip).mean() for q in (10, 95)}
    assert error[95] < error[10]
    assert error[95] < 5.0


def test_frame_rate_modes():
    clip = np.stack([np.full((2, 2, 3), v, np.uint8) for v in (0, 100, 200)])
    blend = resample_frame_rate(clip, 2.0, "blend")
    np.testing.assert_array_equal(blend[:, 0, 0, 0], [0, 50, 100, 150, 200])
    drop = resample_frame_rate(clip, 2.0, "drop")
    assert set(drop[:, 0, 0, 0].tolist()) <= {0, 100, 200}
    np.testing.assert_array_equal(resample_frame_rate(clip, 0.5, "drop")[:, 0, 0, 0], [0, 200])
    assert resampled_frame_count(61, 0.5) == 31


@pytest.mark.parametrize("ratio", [0.3, 0.5, 0.5229, 0.875, 1.0, 1.794, 2.0, 3.0])
def test_source_frame_count_is_the_fewest_recorded_frames_for_a_video(ratio):
    for frames in range(1, 70):
        source = source_frame_count(frames, ratio)
        assert resampled_frame_count(source, ratio) >= frames
        assert source == 1 or resampled_frame_count(source - 1, ratio) < frames
    assert source_frame_count(30, 0.5) == 59 and source_frame_count(30, 2.0) == 16
    with pytest.raises(ValueError, match="ratio > 0"):
        source_frame_count(10, 0.0)


def test_effect_streams_are_independent_of_other_switches(clip):
    wb = VisualEffects(white_balance=True)
    both = dataclasses.replace(
        wb, defocus_blur=True, defocus_radius_min_px=0.0, defocus_radius_max_px=0.4
    )  # radius < 0.5 px: identity blur
    a = apply_image_effects(clip, wb, np.random.default_rng(7))
    b = apply_image_effects(clip, both, np.random.default_rng(7))
    np.testing.assert_array_equal(a, b)
    streams = effect_streams(np.random.default_rng(7))
    assert list(streams) == list(RANDOM_EFFECTS)
    assert set(RANDOM_EFFECTS) | set(DETERMINISTIC_EFFECTS) == set(EFFECT_NAMES)


def test_a_deterministic_effect_leaves_every_stream_as_before():
    """Streams are the draws of the ten effects that existed before vignetting, in order."""
    before = (
        "motion_blur",
        "sensor_noise",
        "compression",
        "lighting_variation",
        "specular",
        "shadows",
        "camera_shake",
        "defocus_blur",
        "white_balance",
        "frame_rate",
    )
    assert RANDOM_EFFECTS == before
    seeds = np.random.default_rng(7).integers(0, np.iinfo(np.int64).max, size=len(before))
    streams = effect_streams(np.random.default_rng(7))
    for name, seed in zip(before, seeds, strict=True):
        assert streams[name].random() == np.random.default_rng(int(seed)).random()


def test_vignetting_is_an_even_radial_falloff_reaching_one_minus_strength_at_the_corners():
    flat = np.full((1, 64, 48, 3), 200, np.uint8)
    out = apply_vignetting(flat, 0.4).astype(float)[0, ..., 0]
    assert out[31:33, 23:25].min() >= 199  # the centre keeps its level
    np.testing.assert_allclose(out[[0, 0, -1, -1], [0, -1, 0, -1]], 200 * 0.6, atol=3)
    np.testing.assert_array_equal(out, out[::-1, ::-1])  # symmetric about the centre
    np.testing.assert_array_equal(out, out[:, ::-1])
    row = out[32, 24:]  # falls off monotonically towards the edge
    assert np.all(np.diff(row) <= 0) and row[-1] < row[0] - 10
    weaker = apply_vignetting(flat, 0.1).astype(float)[0, ..., 0]
    assert np.all(weaker >= out) and weaker[0, 0] > out[0, 0] + 30
    np.testing.assert_array_equal(apply_vignetting(flat, 0.0), flat)


def test_shake_offsets_amplitude_and_smoothness():
    effects = VisualEffects(camera_shake=True, shake_rotation_deg=0.5, shake_translation=0.01)
    offsets = shake_offsets(np.random.default_rng(0), np.arange(0, 400, 0.5), effects)
    assert offsets.shape == (800, 6)
    np.testing.assert_allclose(offsets[:, 3:].std(0), 0.01, rtol=0.35)
    np.testing.assert_allclose(offsets[:, :3].std(0), np.radians(0.5), rtol=0.35)
    # Smooth: offsets half a frame apart are strongly correlated.
    for c in range(6):
        assert np.corrcoef(offsets[:-1, c], offsets[1:, c])[0, 1] > 0.7


def test_image_effects_reject_non_uint8():
    with pytest.raises(ValueError, match="uint8"):
        apply_image_effects(np.zeros((2, 4, 4, 3)), VisualEffects(), np.random.default_rng(0))


def test_coverage_follows_the_geometric_effects_only(clip):
    cover = np.where(clip[..., 0] > 128, 255, 0).astype(np.uint8)
    as_rgb = np.repeat(cover[..., None], 3, axis=-1)
    for name in IMAGE_EFFECT_ORDER:
        effects = VisualEffects(**{name: True})
        out, moved = apply_image_effects(clip, effects, np.random.default_rng(1), cover)
        alone = apply_image_effects(clip, effects, np.random.default_rng(1))
        np.testing.assert_array_equal(out, alone)
        if name in ("frame_rate", "defocus_blur"):  # same resampling / same drawn radius
            expected = apply_image_effects(as_rgb, effects, np.random.default_rng(1))[..., 0]
            assert not np.array_equal(moved, cover[: len(moved)]), name
            np.testing.assert_array_equal(moved, expected)
        else:
            np.testing.assert_array_equal(moved, cover)
    with pytest.raises(ValueError, match="coverage"):
        apply_image_effects(clip, VisualEffects(), np.random.default_rng(1), cover[:2])
