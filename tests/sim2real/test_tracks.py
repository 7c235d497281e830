"""The tracks rung (sim2real.tracks): trajectories of followed points, not moved by the picture.

A synthetic sheet pinned along its top edge sways in a travelling wave over a backdrop; its
texture, the backdrop and a sharpening filter change the picture alone, a larger sway changes
the motion. benchmarks/sim2real_rung_invariance.py measures the same on rendered cloth.
"""

import math

import cv2
import numpy as np
import pytest

from sim2real.features import motion_features
from sim2real.tracks import TRACK_FEATURE_NAMES, track_features

SIZE, SHEET, TOP, LEFT = 72, 40, 12, 16
BOX = (4, 68, 4, 68)
FEATURE = {name: i for i, name in enumerate(TRACK_FEATURE_NAMES)}


def _texture(kind: str) -> np.ndarray:
    y, x = np.mgrid[0:SHEET, 0:SHEET]
    if kind == "checks":
        t = ((x // 5 + y // 5) % 2) * 180.0 + 40
        image = np.stack([t, 0.8 * t, 0.6 * t], -1)
    elif kind == "noise":
        rng = np.random.default_rng(1)
        t = cv2.GaussianBlur(rng.uniform(0, 255, (SHEET, SHEET)).astype(np.float32), (0, 0), 1.2)
        t = (t - t.mean()) / t.std() * 50 + 128
        image = np.stack([0.6 * t, t, 0.7 * t], -1)
    else:  # dots
        t = np.where(((x % 8) - 4) ** 2 + ((y % 8) - 4) ** 2 < 6, 230.0, 60.0)
        image = np.stack([0.9 * t, 0.5 * t, t], -1)
    return np.clip(image, 0, 255).astype(np.float32)


def _backdrop(kind: str) -> np.ndarray:
    if kind == "plain":
        return np.full((SIZE, SIZE, 3), 110, np.float32)
    rng = np.random.default_rng(2)
    blobs = cv2.GaussianBlur(rng.uniform(0, 255, (SIZE, SIZE, 3)).astype(np.float32), (0, 0), 4)
    return (blobs - blobs.mean()) * 3 + 120


def _sway(motion, texture: np.ndarray, backdrop: np.ndarray, frames: int = 10) -> np.ndarray:
    """x shift A v^1.5 sin(2 pi (f k + x / L) + phase), v the depth below the pinned edge."""
    amplitude, frequency, phase, wavelength = motion
    yy, xx = np.mgrid[0:SIZE, 0:SIZE].astype(np.float32)
    depth = np.clip((yy - TOP) / SHEET, 0, 1)
    out = []
    for k in range(frames):
        wave = 2 * math.pi * (frequency * k + (xx - LEFT) / wavelength) + phase
        dx = amplitude * depth**1.5 * np.sin(wave)
        dy = 0.3 * amplitude * depth**2 * np.cos(2 * math.pi * frequency * k + phase)
        map_x = (xx - LEFT - dx).astype(np.float32)
        map_y = (yy - TOP - dy).astype(np.float32)
        sheet = cv2.remap(texture, map_x, map_y, cv2.INTER_LINEAR, borderValue=(0, 0, 0))
        ones = np.ones((SHEET, SHEET), np.float32)
        alpha = cv2.remap(ones, map_x, map_y, cv2.INTER_LINEAR, borderValue=0)[..., None]
        out.append(np.clip(alpha * sheet + (1 - alpha) * backdrop, 0, 255).astype(np.uint8))
    return np.stack(out)


def _sharpen(clip: np.ndarray) -> np.ndarray:
    frames = clip.astype(np.float32)
    blurred = np.stack([cv2.GaussianBlur(f, (0, 0), 1.0) for f in frames])
    return np.clip(frames + 1.5 * (frames - blurred), 0, 255).astype(np.uint8)


MOTIONS = [
    (
        rng.uniform(1.5, 3.5),
        rng.uniform(0.05, 0.15),
        rng.uniform(0, 2 * math.pi),
        rng.uniform(30, 60),
    )
    for rng in [np.random.default_rng(0)]
    for _ in range(12)
]


def _features(measure, texture="checks", backdrop="blobs", sharpen=False, scale=1.0):
    t, b = _texture(texture), _backdrop(backdrop)
    clips = [_sway((m[0] * scale, *m[1:]), t, b) for m in MOTIONS]
    return np.stack([measure(_sharpen(c) if sharpen else c, BOX) for c in clips])


@pytest.fixture(scope="module")
def shifts():
    """Rung -> change -> each feature's mean shift over the clips, in between-clip stds."""
    changes = {
        "noise texture": {"texture": "noise"},
        "dots texture": {"texture": "dots"},
        "plain backdrop": {"backdrop": "plain"},
        "sharpening": {"sharpen": True},
        "sway x 2": {"scale": 2.0},
    }
    out = {}
    for rung, measure in (("tracks", track_features), ("motion", motion_features)):
        base = _features(measure)
        spread = base.std(0) + 1e-9
        out[rung] = {
            name: np.abs((_features(measure, **kw) - base).mean(0)) / spread
            for name, kw in changes.items()
        }
    return out


@pytest.mark.parametrize(
    "change", ["noise texture", "dots texture", "plain backdrop", "sharpening"]
)
def test_a_change_of_the_picture_alone_barely_moves_the_tracks(shifts, change):
    tracks = shifts["tracks"]
    assert tracks[change].mean() < 0.5, tracks[change].round(2)
    assert tracks["sway x 2"].mean() > 4 * tracks[change].mean()


def test_the_motion_rung_is_moved_by_what_the_tracks_rung_ignores(shifts):
    for change in ("noise texture", "sharpening"):
        assert shifts["motion"][change].max() > 2 * shifts["tracks"][change].max()


def test_a_larger_sway_gives_larger_amplitudes_and_speeds():
    small, large = _features(track_features), _features(track_features, scale=2.0)
    for name in ("track_amplitude_log_x", "track_speed_log_p90"):
        gain = (large - small)[:, FEATURE[name]].mean()
        assert 0.35 < gain < 0.9, (name, gain)  # log 2 = 0.69, less where points are lost
    assert large[:, FEATURE["track_amplitude_slope_y"]].mean() > 0  # more sway further down


def test_a_translating_square_gives_its_speed_and_direction_and_the_backdrop_is_dropped():
    rng = np.random.default_rng(3)
    backdrop = cv2.GaussianBlur(rng.uniform(0, 255, (SIZE, SIZE)).astype(np.float32), (0, 0), 2)
    square = _texture("checks")[:24, :24, 0]
    frames = []
    for k in range(10):
        frame = backdrop.copy() * 0.5 + 60
        frame[24:48, 10 + k : 34 + k] = square
        frames.append(np.repeat(frame[..., None], 3, -1).astype(np.uint8))
    out = track_features(np.stack(frames), BOX)
    height = BOX[1] - BOX[0]
    assert math.exp(out[FEATURE["track_speed_log_p50"]]) == pytest.approx(1 / height, rel=0.05)
    assert out[FEATURE["track_horizontal_share"]] > 0.99


def test_a_still_or_flat_clip_gives_the_still_entries_and_the_result_is_deterministic():
    flat = np.full((6, 40, 40, 3), 90, np.uint8)
    still = track_features(flat, (0, 40, 0, 40))
    assert still.shape == (len(TRACK_FEATURE_NAMES),) and np.isfinite(still).all()
    assert still[FEATURE["track_horizontal_share"]] == 0.0
    clip = _sway(MOTIONS[0], _texture("checks"), _backdrop("blobs"))
    assert np.array_equal(track_features(clip, BOX), track_features(clip, BOX))
    assert np.array_equal(track_features(clip[:1].repeat(6, 0), BOX), still)  # a frozen frame


@pytest.mark.parametrize(
    ("clip", "box", "name"),
    [
        (np.zeros((2, 40, 40, 3), np.uint8), (0, 40, 0, 40), "clip"),
        (np.zeros((6, 40, 40), np.uint8), (0, 40, 0, 40), "clip"),
        (np.zeros((6, 40, 40, 3), np.uint8), (0, 4, 0, 40), "box"),
    ],
)
def test_bad_input_is_rejected_naming_the_argument(clip, box, name):
    with pytest.raises(ValueError, match=name):
        track_features(clip, box)
