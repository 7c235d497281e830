"""Named visual effects: each a switch (off by default), composable, with its own parameters.

The sim-to-real study turns these on one at a time, like the physical effects in
:mod:`simulator.cloth.effects`. Two groups:

* **renderer effects** (``lighting_variation``, ``specular``, ``shadows``, ``camera_shake``,
  ``motion_blur``, ``rolling_shutter``) change what :class:`render.renderer.ClothRenderer`
  draws;
* **image effects** are pure numpy/cv2 functions on uint8 clips of shape (K, H, W, 3),
  applied by :func:`apply_image_effects` after rendering in the fixed order
  :data:`IMAGE_EFFECT_ORDER`, which follows a camera pipeline: temporal sampling
  (``frame_rate``), optics (``defocus_blur``, ``vignetting``), sensor (``sensor_noise``),
  image processor (``white_balance``), codec (``compression``).

Randomness: :func:`effect_streams` turns the clip's Generator into one independent stream per
random effect (always all of them, in :data:`RANDOM_EFFECTS` order), so switching one effect
on or off never changes the random draws of another. Deterministic effects (``vignetting``)
have no stream, so adding one leaves every other effect's draws, and so old datasets' bytes,
as they were.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from collections.abc import Mapping
from enum import StrEnum

import cv2
import numpy as np

from common.effect_fields import strength

__all__ = [
    "DETERMINISTIC_EFFECTS",
    "EFFECT_NAMES",
    "IMAGE_EFFECT_ORDER",
    "IMAGE_EFFECT_PARAMETERS",
    "RANDOM_EFFECTS",
    "RENDER_EFFECTS",
    "FrameRateMode",
    "VisualEffects",
    "apply_defocus_blur",
    "apply_image_effects",
    "apply_jpeg",
    "apply_sensor_noise",
    "apply_vignetting",
    "apply_white_balance",
    "draw_white_balance_gains",
    "effect_streams",
    "resample_frame_rate",
    "resampled_frame_count",
    "rolling_shutter_offsets",
    "shake_offsets",
    "source_frame_count",
    "vignetting_gain",
]


class FrameRateMode(StrEnum):
    """How :func:`resample_frame_rate` makes a frame at a time between two input frames."""

    BLEND = "blend"
    """Linear blend of the two neighbouring input frames (a blending frame-rate converter)."""
    DROP = "drop"
    """The nearest input frame (frames dropped when slowing down, repeated when speeding up)."""


def _switch(stage: str):
    """An effect switch (off by default) of pipeline ``stage`` (``camera`` or ``appearance``)."""
    return dataclasses.field(default=False, metadata={"stage": stage})


@dataclasses.dataclass(frozen=True)
class VisualEffects:
    """Switches (and parameters) of the visual effects; all off by default.

    Each switch's ``stage`` metadata (``camera``: the image pipeline; ``appearance``: the
    renderer's lighting and shading) and each strength's plausible range (see
    :func:`_strength`) make the switch a candidate of the sim-to-real diagnosis.
    """

    motion_blur: bool = _switch("camera")
    """Each frame averages ``motion_blur_samples`` renders spread over the shutter interval."""
    sensor_noise: bool = _switch("camera")
    """Per-pixel Gaussian noise with variance ``noise_read_sigma² + noise_shot_gain * level``."""
    compression: bool = _switch("camera")
    """Each frame round-trips through JPEG (cv2.imencode/imdecode) at ``jpeg_quality``."""
    lighting_variation: bool = _switch("appearance")
    """Per-clip jitter of the key light's direction and of the key and ambient intensities."""
    specular: bool = _switch("appearance")
    """Glossy shading (PBR roughness ``specular_roughness`` instead of the matte 1.0)."""
    shadows: bool = _switch("appearance")
    """Cast shadows from the key light (cloth on itself, arm on cloth; not on the background)."""
    camera_shake: bool = _switch("camera")
    """Smooth random per-frame rotation and translation of the camera (hand-held look)."""
    defocus_blur: bool = _switch("camera")
    """Per-clip disc blur of radius drawn in [``defocus_radius_min_px``, ``..._max_px``]."""
    white_balance: bool = _switch("camera")
    """Per-clip colour cast: RGB gains in 1 ± ``white_balance_shift``, normalised to mean 1."""
    frame_rate: bool = _switch("camera")
    """Resample the clip in time to ``frame_rate_ratio`` x its frame rate (changes K)."""
    vignetting: bool = _switch("camera")
    """Lens shading: brightness falls off with the distance from the frame's centre."""
    rolling_shutter: bool = _switch("camera")
    """The sensor reads its rows one after another (a CMOS rolling shutter): the top row
    ``rolling_shutter_readout`` of a frame interval before the bottom row, the frame's time
    halfway; rendered in ``rolling_shutter_bands`` bands of rows."""

    motion_blur_samples: int = 4
    """Sub-frame renders per frame (>= 2)."""
    motion_blur_shutter: float = strength(0.5, "motion_blur", 0.1, 1.0)
    """Fraction of the frame interval the shutter is open, in (0, 1]; the exposure ends at
    the frame's time (positions are interpolated linearly from the previous frame)."""
    noise_read_sigma: float = strength(2.0, "sensor_noise", 0.5, 8.0)
    """Signal-independent noise std [8-bit levels]."""
    noise_shot_gain: float = 0.15
    """Signal-dependent (shot) noise variance per level [8-bit levels]."""
    jpeg_quality: int = strength(50, "compression", 10, 90, integer=True, neutral=100)
    """JPEG quality, 1 (worst) to 100."""
    light_direction_jitter_deg: float = 25.0
    """Largest change of the key light's direction [deg]."""
    light_intensity_jitter: float = strength(0.3, "lighting_variation", 0.05, 0.6)
    """Key and ambient intensities scale by factors drawn in 1 ± this, in [0, 1)."""
    specular_roughness: float = strength(0.35, "specular", 0.1, 0.8, neutral=1.0)
    """PBR roughness of the glossy cloth, in [0.04, 1]."""
    shake_translation: float = strength(0.004, "camera_shake", 0.001, 0.012)
    """Camera shake translation amplitude (std per axis) [m]."""
    shake_rotation_deg: float = 0.4
    """Camera shake rotation amplitude (std per axis) [deg]."""
    shake_period_frames: float = 8.0
    """Typical period of the shake [frames]; the motion mixes periods of 1x, 1/2x and 1/3x."""
    defocus_radius_min_px: float = 0.5
    """Smallest blur-disc radius [px] (output pixels)."""
    defocus_radius_max_px: float = strength(1.5, "defocus_blur", 0.75, 3.0)
    """Largest blur-disc radius [px]."""
    white_balance_shift: float = strength(0.12, "white_balance", 0.03, 0.3)
    """Largest relative change of one channel's gain, in [0, 1)."""
    frame_rate_ratio: float = strength(0.5, "frame_rate", 0.5, 2.0, neutral=1.0)
    """Output frame rate / input frame rate (> 0); the clip keeps its duration."""
    frame_rate_mode: FrameRateMode = FrameRateMode.BLEND
    """``blend`` or ``drop`` (see :class:`FrameRateMode`)."""
    vignetting_strength: float = strength(0.3, "vignetting", 0.05, 0.6)
    """Relative darkening at the frame's corners (gain ``1 - s r²``, r = 1 at a corner)."""
    rolling_shutter_readout: float = strength(0.6, "rolling_shutter", 0.2, 1.0)
    """Readout time from the top row to the bottom row, as a fraction of the frame interval
    (phone and consumer CMOS sensors: about 0.3-1 at 30 frames/s)."""
    rolling_shutter_bands: int = 8
    """Bands of rows, each rendered at its own time (one render per band and frame). With the
    longest readout neighbouring bands lie an eighth of a frame apart at 8: the cloth of the
    wind scene moves about 0.2 px in that time at 112 px, well below what blurs."""

    def __post_init__(self):
        for name in EFFECT_NAMES:
            if not isinstance(getattr(self, name), bool):
                raise ValueError(
                    f"effects.{name} must be true or false, got {getattr(self, name)!r}"
                )
        try:
            object.__setattr__(self, "frame_rate_mode", FrameRateMode(self.frame_rate_mode))
        except ValueError:
            raise ValueError(
                f"effects.frame_rate_mode must be one of {[m.value for m in FrameRateMode]}, "
                f"got {self.frame_rate_mode!r}"
            ) from None
        checks = {
            "motion_blur_samples": (2, 64, True),
            "jpeg_quality": (1, 100, True),
            "motion_blur_shutter": (1e-6, 1.0, False),
            "noise_read_sigma": (0.0, 255.0, False),
            "noise_shot_gain": (0.0, 255.0, False),
            "light_direction_jitter_deg": (0.0, 180.0, False),
            "light_intensity_jitter": (0.0, 0.999, False),
            "specular_roughness": (0.04, 1.0, False),
            "shake_translation": (0.0, 1.0, False),
            "shake_rotation_deg": (0.0, 45.0, False),
            "shake_period_frames": (1e-3, 1e6, False),
            "defocus_radius_min_px": (0.0, 100.0, False),
            "defocus_radius_max_px": (0.0, 100.0, False),
            "white_balance_shift": (0.0, 0.999, False),
            "frame_rate_ratio": (1e-3, 1e3, False),
            "vignetting_strength": (0.0, 1.0, False),
            "rolling_shutter_readout": (0.0, 1.0, False),
            "rolling_shutter_bands": (1, 4096, True),
        }
        for name, (lo, hi, integer) in checks.items():
            value = getattr(self, name)
            ok_type = isinstance(value, numbers.Integral if integer else numbers.Real)
            if isinstance(value, bool) or not ok_type or not lo <= value <= hi:
                kind = "an integer" if integer else "a number"
                raise ValueError(f"effects.{name} must be {kind} in [{lo}, {hi}], got {value!r}")
            object.__setattr__(self, name, int(value) if integer else float(value))
        if self.defocus_radius_min_px > self.defocus_radius_max_px:
            raise ValueError(
                f"effects.defocus_radius_min_px ({self.defocus_radius_min_px}) must be <= "
                f"defocus_radius_max_px ({self.defocus_radius_max_px})"
            )

    @staticmethod
    def from_dict(values: Mapping | None) -> VisualEffects:
        """Build from a (config) mapping; unknown keys raise, naming them and the allowed keys."""
        from common.configs import switches_from_dict  # lazy: keeps torch out of render

        return switches_from_dict(VisualEffects, values, "visual effects")

    def enabled(self) -> dict[str, bool]:
        """The switch values by name."""
        return {name: getattr(self, name) for name in EFFECT_NAMES}

    def before_image_effects(self) -> VisualEffects:
        """These effects with every image effect off and its parameters at their defaults.

        What :meth:`render.renderer.ClothRenderer.render_clip` draws before it applies the
        image effects (:data:`IMAGE_EFFECT_ORDER`, :data:`IMAGE_EFFECT_PARAMETERS`): two
        settings that differ only in image effects give the same value, so their renders
        can be shared.
        """
        defaults = VisualEffects()
        reset = dict.fromkeys(IMAGE_EFFECT_ORDER, False)
        reset.update({name: getattr(defaults, name) for name in IMAGE_EFFECT_PARAMETERS})
        return dataclasses.replace(self, **reset)


EFFECT_NAMES: tuple[str, ...] = tuple(
    f.name for f in dataclasses.fields(VisualEffects) if f.type == "bool"
)
"""All switch names, in field order (also the order of :func:`effect_streams`)."""

IMAGE_EFFECT_ORDER: tuple[str, ...] = (
    "frame_rate",
    "defocus_blur",
    "vignetting",
    "sensor_noise",
    "white_balance",
    "compression",
)
"""Image effects in the order :func:`apply_image_effects` applies them."""

RENDER_EFFECTS: tuple[str, ...] = tuple(n for n in EFFECT_NAMES if n not in IMAGE_EFFECT_ORDER)
"""Effects the renderer itself implements."""

IMAGE_EFFECT_PARAMETERS: tuple[str, ...] = (
    "frame_rate_ratio",
    "frame_rate_mode",
    "defocus_radius_min_px",
    "defocus_radius_max_px",
    "vignetting_strength",
    "noise_read_sigma",
    "noise_shot_gain",
    "white_balance_shift",
    "jpeg_quality",
)
"""The image effects' parameters: :func:`apply_image_effects` reads them, the renderer not."""


DETERMINISTIC_EFFECTS: tuple[str, ...] = ("vignetting", "rolling_shutter")
"""Effects that draw nothing: :func:`effect_streams` makes no stream for them."""

RANDOM_EFFECTS: tuple[str, ...] = tuple(n for n in EFFECT_NAMES if n not in DETERMINISTIC_EFFECTS)
"""Effects with a random stream, in :data:`EFFECT_NAMES` order."""


def rolling_shutter_offsets(effects: VisualEffects) -> np.ndarray:
    """Time of each row band relative to the frame's time [frame intervals], top band first.

    Band ``j`` of ``B`` is read at ``readout ((j + 1/2) / B - 1/2)``: the readout is centred
    on the frame's time, so the skew is all the effect does. A readout that ended (or began)
    at the frame's time would also move the whole video by half a readout, and the first
    clips of a simulation lie in the decay of its start-up motion: that shift alone changed
    the flow statistics more than the skew did (a sealed set read after the frame's time and
    the same set read before it differed in the mean flow with paired t = 5.7, 60 clips).
    One band at 0 without the effect.
    """
    if not effects.rolling_shutter:
        return np.zeros(1)
    bands = effects.rolling_shutter_bands
    return effects.rolling_shutter_readout * ((np.arange(bands) + 0.5) / bands - 0.5)


def effect_streams(rng: np.random.Generator) -> dict[str, np.random.Generator]:
    """One independent Generator per random effect, drawn from ``rng`` (one draw of N seeds)."""
    seeds = rng.integers(0, np.iinfo(np.int64).max, size=len(RANDOM_EFFECTS))
    return {
        name: np.random.default_rng(int(s)) for name, s in zip(RANDOM_EFFECTS, seeds, strict=True)
    }


def _check_clip(clip: np.ndarray) -> np.ndarray:
    clip = np.asarray(clip)
    if clip.dtype != np.uint8 or clip.ndim != 4 or clip.shape[-1] != 3:
        raise ValueError(
            f"clip must be uint8 with shape (K, H, W, 3), got {clip.dtype} {clip.shape}"
        )
    return clip


def resampled_frame_count(frame_count: int, ratio: float) -> int:
    """Frames :func:`resample_frame_rate` returns for ``frame_count`` input frames."""
    return math.floor((frame_count - 1) * ratio + 1e-9) + 1


def source_frame_count(frame_count: int, ratio: float) -> int:
    """Fewest input frames from which :func:`resample_frame_rate` makes ``frame_count`` frames.

    A camera at ``ratio`` x the simulation's frame rate needs this many recorded frames for a
    video of ``frame_count`` frames (more than ``frame_count`` when it is slower).
    """
    if frame_count < 1 or not ratio > 0:
        raise ValueError(f"need frame_count >= 1 and ratio > 0, got {frame_count}, {ratio}")
    count = math.ceil((frame_count - 1) / ratio - 1e-9) + 1
    while count > 1 and resampled_frame_count(count - 1, ratio) >= frame_count:
        count -= 1
    while resampled_frame_count(count, ratio) < frame_count:
        count += 1
    return count


def resample_frame_rate(
    clip: np.ndarray, ratio: float, mode: FrameRateMode | str = FrameRateMode.BLEND
) -> np.ndarray:
    """Resample a clip to ``ratio`` times its frame rate over the same duration.

    Output frame j shows input time ``j / ratio`` (in input frames), for every such time
    within the clip, so K becomes :func:`resampled_frame_count`.

    Args:
        clip: Frames, uint8, shape (K, H, W, 3).
        ratio: Output frame rate / input frame rate (> 0).
        mode: ``blend`` (linear blend of the neighbouring frames) or ``drop`` (nearest).

    Returns:
        Frames, uint8, shape (K', H, W, 3).
    """
    clip = _check_clip(clip)
    mode = FrameRateMode(mode)
    count = resampled_frame_count(clip.shape[0], ratio)
    times = np.arange(count) / ratio
    if mode is FrameRateMode.DROP:
        index = np.minimum(np.floor(times + 0.5).astype(np.int64), clip.shape[0] - 1)
        return clip[index].copy()
    lo = np.minimum(np.floor(times).astype(np.int64), clip.shape[0] - 1)
    hi = np.minimum(lo + 1, clip.shape[0] - 1)
    weight = (times - lo)[:, None, None, None].astype(np.float32)
    blended = (1.0 - weight) * clip[lo] + weight * clip[hi]
    return np.clip(np.rint(blended), 0, 255).astype(np.uint8)


def _disc_kernel(radius: float) -> np.ndarray:
    # Anti-aliased disc: coverage of each tap estimated on an 8 x 8 sub-grid.
    half = math.ceil(radius)
    sub = (np.arange(8) + 0.5) / 8 - 0.5
    taps = np.arange(-half, half + 1)
    x = (taps[:, None] + sub[None, :]).reshape(-1)
    inside = (x[:, None] ** 2 + x[None, :] ** 2) <= radius * radius
    kernel = inside.reshape(len(taps), 8, len(taps), 8).mean(axis=(1, 3))
    return (kernel / kernel.sum()).astype(np.float32)


def apply_defocus_blur(clip: np.ndarray, radius_px: float) -> np.ndarray:
    """Blur every frame with a uniform disc (a defocused lens's PSF) of ``radius_px`` [px]."""
    clip = _check_clip(clip)
    if radius_px < 0.5:
        return clip.copy()
    kernel = _disc_kernel(radius_px)
    return np.stack(
        [cv2.filter2D(frame, -1, kernel, borderType=cv2.BORDER_REFLECT_101) for frame in clip]
    )


def vignetting_gain(height: int, width: int, strength: float) -> np.ndarray:
    """Lens-shading gain ``1 - strength * r²`` per pixel, float32, shape (H, W).

    ``r`` is the distance of the pixel centre from the frame's centre over the half-diagonal,
    so the corners get ``1 - strength``: the even, second-order falloff of a lens's
    off-axis shading (natural vignetting's cos⁴ law is ``1 - 2 θ² + ...`` near the axis).
    """
    y = (np.arange(height, dtype=np.float64) + 0.5 - height / 2) / (height / 2)
    x = (np.arange(width, dtype=np.float64) + 0.5 - width / 2) / (width / 2)
    r2 = (y[:, None] ** 2 + x[None, :] ** 2) / 2.0
    return (1.0 - strength * r2).astype(np.float32)


def apply_vignetting(clip: np.ndarray, strength: float) -> np.ndarray:
    """Darken every frame towards its corners by :func:`vignetting_gain` (rounded, clipped)."""
    clip = _check_clip(clip)
    gain = vignetting_gain(clip.shape[1], clip.shape[2], strength)[None, :, :, None]
    return np.clip(np.rint(clip.astype(np.float32) * gain), 0, 255).astype(np.uint8)


def apply_sensor_noise(
    clip: np.ndarray, rng: np.random.Generator, *, read_sigma: float, shot_gain: float
) -> np.ndarray:
    """Add Gaussian noise of variance ``read_sigma² + shot_gain * level`` [8-bit levels²]."""
    clip = _check_clip(clip)
    level = clip.astype(np.float32)
    sigma = np.sqrt(read_sigma * read_sigma + shot_gain * level)
    noisy = level + sigma * rng.standard_normal(clip.shape, dtype=np.float32)
    return np.clip(np.rint(noisy), 0, 255).astype(np.uint8)


def draw_white_balance_gains(rng: np.random.Generator, shift: float) -> np.ndarray:
    """RGB gains drawn uniformly in ``1 ± shift`` and normalised to mean 1, shape (3,)."""
    gains = rng.uniform(1.0 - shift, 1.0 + shift, size=3)
    return gains / gains.mean()


def apply_white_balance(clip: np.ndarray, gains: np.ndarray) -> np.ndarray:
    """Multiply the R, G, B channels by ``gains`` (shape (3,)), clipping to [0, 255]."""
    clip = _check_clip(clip)
    scaled = clip.astype(np.float32) * np.asarray(gains, np.float32)
    return np.clip(np.rint(scaled), 0, 255).astype(np.uint8)


def apply_jpeg(clip: np.ndarray, quality: int) -> np.ndarray:
    """Encode and decode each frame as JPEG at ``quality`` (1-100) with cv2."""
    clip = _check_clip(clip)
    out = np.empty_like(clip)
    params = [int(cv2.IMWRITE_JPEG_QUALITY), int(quality)]
    for k, frame in enumerate(clip):
        ok, data = cv2.imencode(".jpg", np.ascontiguousarray(frame[..., ::-1]), params)
        if not ok:
            raise RuntimeError(f"cv2.imencode failed on frame {k}")
        out[k] = cv2.imdecode(data, cv2.IMREAD_COLOR)[..., ::-1]
    return out


def shake_offsets(
    rng: np.random.Generator, times: np.ndarray, effects: VisualEffects
) -> np.ndarray:
    """Camera-shake offsets at the given times, from one clip's random draws.

    Each of the six components is a sum of three sinusoids with periods
    ``shake_period_frames`` x (1, 1/2, 1/3), random phases and 1/f-like random amplitudes,
    scaled to the configured std. The draws do not depend on ``times``, so the same stream
    gives a consistent shake for frames and motion-blur sub-frames alike.

    Args:
        rng: The ``camera_shake`` stream.
        times: Times [frames], shape (N,).
        effects: Source of the amplitudes and period.

    Returns:
        Offsets, shape (N, 6): rotation about the camera's x, y, z axes [rad], then
        translation along them [m].
    """
    harmonics = np.array([1.0, 2.0, 3.0])
    phases = rng.uniform(0, 2 * math.pi, size=(6, 3))
    amplitudes = rng.uniform(0.5, 1.0, size=(6, 3)) / harmonics
    # Normalise so that each component's std over time equals 1.
    amplitudes /= np.sqrt(0.5 * (amplitudes**2).sum(axis=1, keepdims=True))
    omega = 2 * math.pi * harmonics / effects.shake_period_frames
    t = np.asarray(times, np.float64)[:, None, None]
    signal = (amplitudes * np.sin(omega * t + phases)).sum(-1)
    scale = np.array(
        [math.radians(effects.shake_rotation_deg)] * 3 + [effects.shake_translation] * 3
    )
    return signal * scale


def apply_image_effects(
    clip: np.ndarray,
    effects: VisualEffects,
    rng: np.random.Generator | Mapping[str, np.random.Generator],
    coverage: np.ndarray | None = None,
):
    """Apply the enabled image effects in :data:`IMAGE_EFFECT_ORDER`.

    Args:
        clip: Frames, uint8, shape (K, H, W, 3).
        effects: The switches and parameters.
        rng: The clip's Generator, or the streams :func:`effect_streams` made from it.
        coverage: The cloth's coverage (alpha) of each frame, uint8, shape (K, H, W), or
            ``None``. When given it goes through the effects that move or spread the image
            (``frame_rate``, ``defocus_blur``) the same way the frames do, not through the
            photometric ones, so it stays the cloth's share of every output pixel.

    Returns:
        Frames, uint8, shape (K', H, W, 3) (K' = K unless ``frame_rate`` is on); with
        ``coverage``, the pair ``(frames, coverage (K', H, W))``.
    """
    clip = _check_clip(clip)
    cover = None
    if coverage is not None:
        coverage = np.asarray(coverage)
        if coverage.dtype != np.uint8 or coverage.shape != clip.shape[:3]:
            raise ValueError(
                f"coverage must be uint8 with shape {clip.shape[:3]}, "
                f"got {coverage.dtype} {coverage.shape}"
            )
        cover = np.repeat(coverage[..., None], 3, axis=-1)
    streams = effect_streams(rng) if isinstance(rng, np.random.Generator) else rng
    if effects.frame_rate:
        clip = resample_frame_rate(clip, effects.frame_rate_ratio, effects.frame_rate_mode)
        if cover is not None:
            cover = resample_frame_rate(cover, effects.frame_rate_ratio, effects.frame_rate_mode)
    if effects.defocus_blur:
        radius = streams["defocus_blur"].uniform(
            effects.defocus_radius_min_px, effects.defocus_radius_max_px
        )
        clip = apply_defocus_blur(clip, radius)
        if cover is not None:
            cover = apply_defocus_blur(cover, radius)
    if effects.vignetting:
        clip = apply_vignetting(clip, effects.vignetting_strength)
    if effects.sensor_noise:
        clip = apply_sensor_noise(
            clip,
            streams["sensor_noise"],
            read_sigma=effects.noise_read_sigma,
            shot_gain=effects.noise_shot_gain,
        )
    if effects.white_balance:
        gains = draw_white_balance_gains(streams["white_balance"], effects.white_balance_shift)
        clip = apply_white_balance(clip, gains)
    if effects.compression:
        clip = apply_jpeg(clip, effects.jpeg_quality)
    if cover is None:
        return clip
    return clip, np.ascontiguousarray(cover[..., 0])
