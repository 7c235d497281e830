"""Per-clip pixel and motion features: shapes, finiteness, planted effects, invariances."""

import cv2
import numpy as np
import pytest

from render import effects as fx
from sim2real.features import (
    MOTION_FEATURE_NAMES,
    PIXEL_FEATURE_NAMES,
    motion_features,
    pixel_features,
    roi_box,
)
from sim2real.rungs import clip_features

cv2.setNumThreads(1)

SIZE = 64
FRAMES = 10
BOX = (0, SIZE, 0, SIZE)
PIX = {name: i for i, name in enumerate(PIXEL_FEATURE_NAMES)}
MOT = {name: i for i, name in enumerate(MOTION_FEATURE_NAMES)}
DIRECTIONS = [name for name in MOTION_FEATURE_NAMES if name.startswith("flow_dir_")]

# Appearance changes may move the motion vector by at most this fraction of what doubling the
# speed moves it. Measured on these clips: gain, contrast, white balance and flicker give
# 0.1-0.7 %, sensor noise of sigma 2 about 3 %, a different texture seed about 3 %; 10 %
# leaves a 3x margin over the worst while staying far below the speed change (100 %).
INVARIANCE_TOL = 0.10


def texture(seed, size, *, sigma=2.0):
    """Smooth random colour texture, float32 (size, size, 3) in 8-bit levels around 128."""
    rng = np.random.default_rng(seed)
    noise = cv2.GaussianBlur(rng.standard_normal((size, size, 3)).astype(np.float32), (0, 0), sigma)
    return np.clip(128 + 35 * noise / noise.std(), 0, 255)


def moving_clip(dx=2, dy=0, *, seed=0, sigma=2.0, shake=None, frames=FRAMES, size=SIZE):
    """A texture translating by (dx, dy) px/frame (+x right, +y down), uint8 (K, H, W, 3).

    ``shake`` adds a whole-frame integer offset per frame, shape (K, 2) (x, y).
    """
    margin = 48
    canvas = texture(seed, size + 2 * margin, sigma=sigma)
    out = []
    for t in range(frames):
        ox, oy = t * dx, t * dy
        if shake is not None:
            ox, oy = ox + shake[t, 0], oy + shake[t, 1]
        out.append(canvas[margin - oy : margin - oy + size, margin - ox : margin - ox + size])
    return np.rint(np.stack(out)).astype(np.uint8)


def named(names, values):
    return dict(zip(names, values, strict=True))


def noisy(clip, sigma, seed=1):
    return fx.apply_sensor_noise(clip, np.random.default_rng(seed), read_sigma=sigma, shot_gain=0)


def flicker(clip):
    """Every other frame 15 % darker (mains flicker, auto-exposure hunting)."""
    gains = np.where(np.arange(len(clip)) % 2 == 0, 1.0, 0.85)[:, None, None, None]
    return np.clip(np.rint(clip * gains), 0, 255).astype(np.uint8)


def contrast(clip, factor):
    scaled = 128 + factor * (clip.astype(np.float32) - 128)
    return np.clip(np.rint(scaled), 0, 255).astype(np.uint8)


# --- shapes, names, finiteness ---------------------------------------------------------------


def test_names_unique_and_match_vector_lengths():
    clip = moving_clip()
    assert len(set(PIXEL_FEATURE_NAMES)) == len(PIXEL_FEATURE_NAMES)
    assert len(set(MOTION_FEATURE_NAMES)) == len(MOTION_FEATURE_NAMES)
    pixel, motion = pixel_features(clip, BOX), motion_features(clip, BOX)
    assert pixel.shape == (len(PIXEL_FEATURE_NAMES),) and pixel.dtype == np.float64
    assert motion.shape == (len(MOTION_FEATURE_NAMES),) and motion.dtype == np.float64
    assert 30 <= len(PIXEL_FEATURE_NAMES) <= 60


@pytest.mark.parametrize("level", [0, 77, 255])
def test_flat_clips_give_finite_features(level):
    clip = np.full((FRAMES, SIZE, SIZE, 3), level, np.uint8)
    pixel, motion = pixel_features(clip, BOX), motion_features(clip, BOX)
    assert np.isfinite(pixel).all(), named(PIXEL_FEATURE_NAMES, pixel)
    assert np.isfinite(motion).all(), named(MOTION_FEATURE_NAMES, motion)
    assert motion[MOT["flow_mag_p99"]] == 0.0
    assert pixel[PIX["cast_r_over_g"]] == pytest.approx(1.0)
    # Histograms and relative spectra stay on the simplex even with nothing in them.
    for prefix in ("flow_dir_", "flow_mag_hist_", "intensity_tpsd_", "flow_mag_tpsd_"):
        total = sum(
            v for n, v in named(MOTION_FEATURE_NAMES, motion).items() if n.startswith(prefix)
        )
        assert total == pytest.approx(1.0), prefix


def test_features_are_deterministic():
    clip = noisy(moving_clip(1, 1), 3)
    np.testing.assert_array_equal(pixel_features(clip, BOX), pixel_features(clip, BOX))
    np.testing.assert_array_equal(motion_features(clip, BOX), motion_features(clip, BOX))


# --- roi_box ---------------------------------------------------------------------------------


def test_roi_box_pads_a_planted_square():
    coverage = np.zeros((3, SIZE, SIZE), np.uint8)
    coverage[1, 20:30, 30:40] = 255
    assert roi_box(coverage) == (16, 34, 26, 44)
    assert roi_box(coverage, pad=0, min_side=1) == (20, 30, 30, 40)


def test_roi_box_unions_leading_dims_and_respects_threshold():
    coverage = np.zeros((2, 2, SIZE, SIZE), np.uint8)
    coverage[0, 1, 10:20, 10:20] = 255
    coverage[1, 0, 40:50, 30:45] = 200
    coverage[1, 1, 0:5, 0:5] = 100  # below the default threshold: background
    assert roi_box(coverage, pad=0, min_side=1) == (10, 50, 10, 45)
    assert roi_box(coverage, pad=0, min_side=1, threshold=100) == (0, 50, 0, 45)


def test_roi_box_clips_to_the_image_and_grows_to_min_side():
    coverage = np.zeros((SIZE, SIZE), np.uint8)
    coverage[0:5, 60:64] = 255
    assert roi_box(coverage, pad=4, min_side=1) == (0, 9, 56, 64)
    # Grown about the centre, then shifted back inside the image.
    assert roi_box(coverage, pad=0, min_side=16) == (0, 16, 48, 64)
    small = np.zeros((SIZE, SIZE), np.uint8)
    small[31:33, 31:33] = 255
    y0, y1, x0, x1 = roi_box(small, pad=0, min_side=16)
    assert (y1 - y0, x1 - x0) == (16, 16) and y0 <= 31 and y1 >= 33 and x0 <= 31 and x1 >= 33
    assert roi_box(small, pad=0, min_side=100) == (0, SIZE, 0, SIZE)


def test_roi_box_is_the_whole_image_when_nothing_is_covered():
    assert roi_box(np.zeros((4, 40, 50), np.uint8)) == (0, 40, 0, 50)


@pytest.mark.parametrize(
    ("coverage", "kwargs", "name"),
    [
        (np.zeros((8, 8), np.float32), {}, "coverage"),
        (np.zeros(8, np.uint8), {}, "coverage"),
        (np.zeros((8, 8), np.uint8), {"threshold": 0}, "threshold"),
        (np.zeros((8, 8), np.uint8), {"pad": -1}, "pad"),
        (np.zeros((8, 8), np.uint8), {"min_side": 0}, "min_side"),
    ],
)
def test_roi_box_rejects_bad_input(coverage, kwargs, name):
    with pytest.raises(ValueError, match=name):
        roi_box(coverage, **kwargs)


# --- pixel statistics ------------------------------------------------------------------------


def test_noise_features_rise_with_planted_sensor_noise():
    clip = moving_clip(1, 1)
    sigmas = [0, 2, 4, 8]
    feats = np.array([pixel_features(noisy(clip, s), BOX) for s in sigmas])
    for name in ("noise_sigma_r", "noise_sigma_g", "noise_sigma_b", "noise_sigma_luma"):
        assert np.all(np.diff(feats[:, PIX[name]]) > 0), (name, feats[:, PIX[name]])
    assert np.all(np.diff(feats[:, PIX["temporal_noise"]]) > 0), feats[:, PIX["temporal_noise"]]
    # Immerkær's estimate is calibrated: sigma 4 reads as about 4 on a smooth texture.
    assert feats[2, PIX["noise_sigma_g"]] == pytest.approx(4.0, abs=0.5)


def test_sharpness_drops_with_defocus():
    clip = moving_clip(1, 0, sigma=1.0, frames=4)
    radii = [0.0, 1.0, 2.0]
    feats = np.array([pixel_features(fx.apply_defocus_blur(clip, r), BOX) for r in radii])
    for name in ("laplacian_std", "gradient_mean", "hf_mf_ratio"):
        values = feats[:, PIX[name]]
        assert np.all(np.diff(values) < 0), (name, values)
        assert values[-1] < 0.7 * values[0], (name, values)


@pytest.mark.parametrize("box", [BOX, (5, 61, 3, 59)])
def test_blockiness_rises_with_jpeg_on_the_frame_grid(box):
    # The offset box does not start on a multiple of 8: blockiness must still look for block
    # edges at multiples of 8 in frame coordinates, where the codec put them.
    clip = moving_clip(1, 1, sigma=1.0, frames=3)
    low = pixel_features(fx.apply_jpeg(clip, 10), box)[PIX["blockiness"]]
    high = pixel_features(fx.apply_jpeg(clip, 95), box)[PIX["blockiness"]]
    clean = pixel_features(clip, box)[PIX["blockiness"]]
    assert clean == pytest.approx(1.0, abs=0.1)
    assert high < 1.2
    assert low > 1.5 and low > 1.3 * high


@pytest.mark.parametrize("sigma", [0, 2, 4])
def test_duplicate_fraction_rises_with_repeated_frames(sigma):
    clip = moving_clip(1, 1)
    repeated = fx.resample_frame_rate(clip, 2.0, mode="drop")  # every frame shown twice

    # Noise comes after the frame-rate converter, as in the camera pipeline: repeats differ.
    def camera(frames):
        rng = np.random.default_rng(1)
        return fx.apply_sensor_noise(frames, rng, read_sigma=sigma, shot_gain=0.15 * sigma)

    before = pixel_features(camera(clip), BOX)[PIX["duplicate_frac"]]
    after = pixel_features(camera(repeated), BOX)[PIX["duplicate_frac"]]
    assert before < 0.1
    assert after > 0.4


def test_colour_cast_ratios_follow_white_balance_gains():
    clip = moving_clip()
    gains = np.array([1.2, 1.0, 0.8])
    base = pixel_features(clip, BOX)
    cast = pixel_features(fx.apply_white_balance(clip, gains), BOX)
    for name, expected in (("cast_r_over_g", 1.2), ("cast_b_over_g", 0.8)):
        assert cast[PIX[name]] / base[PIX[name]] == pytest.approx(expected, rel=0.02), name


def test_flicker_feature_sees_frame_brightness_changes():
    clip = moving_clip()
    steady = pixel_features(clip, BOX)[PIX["luma_mean_temporal_std"]]
    assert pixel_features(flicker(clip), BOX)[PIX["luma_mean_temporal_std"]] > steady + 5


# --- motion ----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("dx", "dy", "direction", "speed"),
    [
        (2, 0, "flow_dir_e", 2.0),  # +x, rightwards on screen
        (0, -2, "flow_dir_n", 2.0),  # -y, upwards on screen (rows grow downwards)
        (-2, 0, "flow_dir_w", 2.0),
        (0, 2, "flow_dir_s", 2.0),
        (2, -2, "flow_dir_ne", 2.0 * np.sqrt(2)),
    ],
)
def test_translation_gives_its_direction_and_speed(dx, dy, direction, speed):
    motion = motion_features(moving_clip(dx, dy), BOX)
    dirs = motion[[MOT[d] for d in DIRECTIONS]]
    assert DIRECTIONS[int(np.argmax(dirs))] == direction, named(DIRECTIONS, dirs.round(3))
    assert dirs.max() > 0.8
    assert motion[MOT["flow_mag_p50"]] == pytest.approx(speed, abs=0.5)


def test_static_clip_has_no_flow():
    motion = motion_features(noisy(moving_clip(0, 0), 1), BOX)
    assert motion[MOT["flow_mag_p50"]] < 0.05
    assert motion[MOT["flow_mag_p90"]] < 0.1
    assert motion[MOT["global_speed_mean"]] < 0.05


def test_motion_features_ignore_appearance_but_not_speed():
    clip = moving_clip(2, 0)
    base = motion_features(clip, BOX)
    faster = motion_features(moving_clip(4, 0), BOX)
    speed_change = np.linalg.norm(faster - base)
    assert faster[MOT["flow_mag_p50"]] - base[MOT["flow_mag_p50"]] > 1.5
    variants = {
        "gain 0.7": np.clip(np.rint(clip * 0.7), 0, 255).astype(np.uint8),
        "contrast 0.6": contrast(clip, 0.6),
        "contrast 1.4": contrast(clip, 1.4),
        "white balance": fx.apply_white_balance(clip, np.array([1.15, 1.0, 0.85])),
        "noise sigma 2": noisy(clip, 2),
        "flicker": flicker(clip),
    }
    for name, variant in variants.items():
        change = np.linalg.norm(motion_features(variant, BOX) - base)
        assert change < INVARIANCE_TOL * speed_change, (name, change, speed_change)


def test_camera_shake_raises_global_motion_std():
    shake = np.random.default_rng(3).integers(-2, 3, size=(FRAMES, 2))
    steady = motion_features(moving_clip(1, 0), BOX)
    shaky = motion_features(moving_clip(1, 0, shake=shake), BOX)
    for name in ("global_flow_x_std", "global_flow_y_std"):
        assert steady[MOT[name]] < 0.1, name
        assert shaky[MOT[name]] > 1.0, name
    assert shaky[MOT["flow_roughness"]] > steady[MOT["flow_roughness"]] + 0.5


def blend_with_next(clip, weight):
    """Every row shows ``(1 - weight)`` of its frame and ``weight`` of the next (the last
    frame repeats): a frame-rate-like temporal resampling that treats all rows alike."""
    values = clip.astype(np.float32)
    later = np.concatenate([values[1:], values[-1:]])
    return np.clip(np.rint((1 - weight) * values + weight * later), 0, 255).astype(np.uint8)


def blend_by_row(clip, readout):
    """Row y shows ``1 - readout * y / H`` of its frame and the rest of the next: blind rounds
    11-15's image-space rolling shutter (the renderer's ``rolling_shutter`` now renders each
    band of rows at its time instead)."""
    values = clip.astype(np.float32)
    later = np.concatenate([values[1:], values[-1:]])
    share = (readout * np.arange(clip.shape[1]) / clip.shape[1])[None, :, None, None]
    return np.clip(np.rint((1 - share) * values + share * later), 0, 255).astype(np.uint8)


@pytest.mark.parametrize(("dx", "dy"), [(2, 0), (0, 2), (1, 1)])
def test_row_timing_tells_a_row_dependent_blend_from_a_uniform_blend(dx, dy):
    # A blend with the next frame whose weight grows down the frame low-passes the bottom
    # rows in time more than the top ones; the same blend on every row does not. Averaged
    # over four textures (one texture's thirds differ by chance). Measured: row-dependent
    # -0.17 to -0.32, uniform blend within 0.05.
    hi = [
        MOT["rows_bottom_minus_top_tpsd_log_0.25-0.375cpf"],
        MOT["rows_bottom_minus_top_tpsd_log_0.375-0.5cpf"],
    ]
    shifts = {}
    for seed in range(4):
        clip = noisy(moving_clip(dx, dy, frames=16, seed=seed), 1)
        base = motion_features(clip, BOX)[hi].mean()
        variants = {
            "rolling 0.9": blend_by_row(clip, 0.9),
            "rolling 0.5": blend_by_row(clip, 0.5),
            "uniform 0.5": blend_with_next(clip, 0.5),
            "uniform 0.2": blend_with_next(clip, 0.2),
        }
        for name, variant in variants.items():
            shift = motion_features(variant, BOX)[hi].mean() - base
            shifts[name] = shifts.get(name, 0.0) + shift / 4
    for name, shift in shifts.items():
        if name.startswith("rolling"):
            assert shift < -0.12, (name, shifts)
        else:
            assert abs(shift) < 0.08, (name, shifts)


# --- input checks and the batch helper -------------------------------------------------------


@pytest.mark.parametrize("function", [pixel_features, motion_features])
@pytest.mark.parametrize(
    ("clip", "box", "name"),
    [
        (np.zeros((4, 16, 16, 3), np.float32), (0, 16, 0, 16), "clip"),
        (np.zeros((4, 16, 16), np.uint8), (0, 16, 0, 16), "clip"),
        (np.zeros((4, 16, 16, 4), np.uint8), (0, 16, 0, 16), "clip"),
        (np.zeros((4, 16, 16, 3), np.uint8), (5, 5, 0, 16), "box"),
        (np.zeros((4, 16, 16, 3), np.uint8), (0, 17, 0, 16), "box"),
        (np.zeros((4, 16, 16, 3), np.uint8), (0, 16, -1, 16), "box"),
        (np.zeros((4, 16, 16, 3), np.uint8), (0, 4, 0, 16), "box"),
        (np.zeros((4, 16, 16, 3), np.uint8), (0, 16, 0), "box"),
        (np.zeros((4, 16, 16, 3), np.uint8), (0.0, 16.0, 0.0, 16.0), "box"),
    ],
)
def test_bad_input_is_rejected_naming_the_argument(function, clip, box, name):
    with pytest.raises(ValueError, match=name):
        function(clip, box)


def test_motion_needs_three_frames_pixels_do_not():
    clip = moving_clip(frames=2, size=16)
    with pytest.raises(ValueError, match="clip must have K >= 3"):
        motion_features(clip, (0, 16, 0, 16))
    assert np.isfinite(pixel_features(clip[:1], (0, 16, 0, 16))).all()
    motion_features(moving_clip(frames=3, size=16), (0, 16, 0, 16))


def test_clip_features_stacks_per_clip_vectors():
    clips = [moving_clip(1, 0, seed=0, size=32), moving_clip(0, 1, seed=1, size=32)]
    boxes = [(0, 32, 0, 32), (4, 28, 2, 30)]
    out = clip_features(clips, (0, 32, 0, 32))
    assert out["pixel"].shape == (2, len(PIXEL_FEATURE_NAMES))
    assert out["motion"].shape == (2, len(MOTION_FEATURE_NAMES))
    np.testing.assert_array_equal(out["motion"][1], motion_features(clips[1], (0, 32, 0, 32)))
    per_box = clip_features(iter(clips), boxes, progress=True)
    np.testing.assert_array_equal(per_box["pixel"][1], pixel_features(clips[1], boxes[1]))
    empty = clip_features([], (0, 32, 0, 32))
    assert empty["pixel"].shape == (0, len(PIXEL_FEATURE_NAMES))
    with pytest.raises(ValueError, match="box"):
        clip_features(clips, boxes[:1])


def test_linear_detrend_matches_scipy_reference():
    """The closed-form detrend (fast path) equals scipy's least-squares one, lines vanish."""
    from scipy.signal import detrend

    from sim2real.features import _linear_detrend

    rng = np.random.default_rng(3)
    for length in (2, 3, 9, 10):
        series = rng.normal(size=(length, 50)) * 10 + rng.normal(size=50)
        assert np.allclose(
            _linear_detrend(series), detrend(series, axis=0, type="linear"), atol=1e-10
        )
    t = np.arange(10.0)[:, None]
    line = 3.0 + 0.5 * t * np.arange(4.0)[None]
    assert np.allclose(_linear_detrend(line), 0.0, atol=1e-12)
