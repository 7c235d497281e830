"""Per-clip features for the representation ladder: pixel statistics and motion.

Two rungs, each one fixed-length float64 vector per clip, computed inside the cloth's region
of interest (a box from :func:`roi_box`):

* **pixel statistics** (:func:`pixel_features`, names :data:`PIXEL_FEATURE_NAMES`): what a
  camera or a renderer changes: exposure and colour, clipping, sharpness, sensor noise, JPEG
  blocking, frame duplication and flicker (the effects of :mod:`render.effects`);
* **motion** (:func:`motion_features`, names :data:`MOTION_FEATURE_NAMES`): what the physics
  changes, from dense Farneback optical flow on frames that are contrast-normalised one by
  one inside the box, so that colour, brightness, contrast, texture and mild noise matter
  little.

Clips are uint8 RGB, shape (K, H, W, 3), as cut by :mod:`datasets.real_video` (112 x 112,
15 fps, K = 10) or rendered. Boxes are ``(y0, y1, x0, x1)`` in pixels, end-exclusive.
Intensities are in 8-bit levels [0, 255]; flow in px/frame; temporal frequencies in
cycles/frame (multiply by the frame rate for Hz). Every feature is finite for any valid
clip (constant and all-black ones included) and the functions are deterministic.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence

import cv2
import numpy as np

__all__ = [
    "MIN_BOX_SIDE",
    "MOTION_FEATURE_NAMES",
    "PIXEL_FEATURE_NAMES",
    "check_box",
    "check_clip",
    "is_int",
    "motion_features",
    "normalised_frames",
    "pixel_features",
    "roi_box",
]

MIN_BOX_SIDE = 8
"""Smallest box side [px] the feature functions accept (an 8 x 8 JPEG block)."""

_LUMA = np.array([0.299, 0.587, 0.114])
"""Rec. 601 luma weights of R, G, B."""

# Pixel-statistics constants.
_LUMA_PERCENTILES = (5, 25, 50, 75, 95)
_NEAR_BLACK = 3  # levels <= this count as crushed/clipped black
_NEAR_WHITE = 252  # levels >= this count as clipped white
_SPATIAL_BAND_EDGES = (0.0, 1 / 16, 1 / 8, 1 / 4, math.inf)
"""Radial spatial-frequency bands [cycles/px]; the last one (> 1/4) is 'high', the one
before (1/8, 1/4] is 'mid' for the high-to-mid ratio."""
_RATIO_EPS = 1.0  # [levels]: keeps colour ratios bounded on black clips
_POWER_EPS = 1e-6  # [levels²]: keeps power ratios finite on flat clips
_DUP_ABS = 0.01  # [levels²]: a pair whose change beyond noise is this small is a duplicate,
_DUP_NOISE = 0.5  # ... or below this fraction of the noise energy 2 sigma² (estimate error),
_DUP_REL = 0.1  # ... or below this fraction of the clip's 75th-percentile change.
_IMMERKAER = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)

# Motion constants.
_FARNEBACK = {
    "pyr_scale": 0.5,
    "levels": 3,
    "winsize": 15,
    "iterations": 3,
    "poly_n": 5,
    "poly_sigma": 1.2,
    "flags": 0,
}
_NORM_STD_FLOOR = 1.0  # [levels]: a frame flatter than this is treated as featureless
_NORM_SCALE = 48.0  # normalised frames are 128 + 48 z (an 8-bit-like range for Farneback)
_MAG_EDGES = (0.0, *np.geomspace(0.05, 8.0, 7).tolist(), math.inf)
"""Flow-magnitude histogram edges [px/frame]: [0, 0.05), six log-spaced bins, [8, inf)."""
_DIRECTIONS = ("e", "ne", "n", "nw", "w", "sw", "s", "se")
_MAG_PERCENTILES = (50, 90, 99)
_TEMPORAL_BAND_EDGES = (0.0, 0.125, 0.25, 0.375, 0.5)
"""Temporal-frequency bands [cycles/frame], DC excluded (at 15 fps: 1.9, 3.8, 5.6, 7.5 Hz)."""
_FLOW_EPS = 1e-3  # [px/frame]: keeps the smoothness ratio finite on static clips
_ROW_PARTS = ("top", "middle", "bottom")
"""Horizontal thirds of the box whose temporal statistics are compared (rolling shutter)."""
_LOG_EPS = 1e-6  # keeps the logs of the row statistics finite on flat clips


def _band_names(prefix: str, edges: Sequence[float], unit: str) -> tuple[str, ...]:
    names = []
    for lo, hi in itertools.pairwise(edges):
        hi_text = "inf" if math.isinf(hi) else f"{hi:.3g}"
        names.append(f"{prefix}_{lo:.3g}-{hi_text}{unit}")
    return tuple(names)


PIXEL_FEATURE_NAMES: tuple[str, ...] = (
    "mean_r",
    "mean_g",
    "mean_b",
    "std_r",
    "std_g",
    "std_b",
    *(f"luma_p{p:02d}" for p in _LUMA_PERCENTILES),
    "chroma_mean",
    "saturation_mean",
    "saturation_std",
    "cast_r_over_g",
    "cast_b_over_g",
    "frac_near_black",
    "frac_near_white",
    "laplacian_std",
    "gradient_mean",
    "hf_mf_ratio",
    *_band_names("spatial_power", _SPATIAL_BAND_EDGES, "cpp"),
    "noise_sigma_r",
    "noise_sigma_g",
    "noise_sigma_b",
    "noise_sigma_luma",
    "temporal_noise",
    "blockiness",
    "frame_diff_mean",
    "frame_diff_cv",
    "duplicate_frac",
    "luma_mean_temporal_std",
)
"""Names of :func:`pixel_features`' entries, in order (35). Units: means, stds, percentiles,
chroma, noise sigmas, ``temporal_noise`` and frame differences in 8-bit levels;
``laplacian_std`` in levels (4-neighbour Laplacian); ``gradient_mean`` in levels/px;
saturation, fractions, ratios and relative powers dimensionless. See :func:`pixel_features`."""

MOTION_FEATURE_NAMES: tuple[str, ...] = (
    *_band_names("flow_mag_hist", _MAG_EDGES, "px"),
    *(f"flow_dir_{d}" for d in _DIRECTIONS),
    *(f"flow_mag_p{p:02d}" for p in _MAG_PERCENTILES),
    "flow_mag_mean",
    "divergence_mean",
    "divergence_abs_mean",
    "curl_abs_mean",
    "global_flow_x_std",
    "global_flow_y_std",
    "global_speed_mean",
    "local_flow_mean",
    "flow_roughness",
    *_band_names("intensity_tpsd", _TEMPORAL_BAND_EDGES, "cpf"),
    *_band_names("flow_mag_tpsd", _TEMPORAL_BAND_EDGES, "cpf"),
    *(
        name
        for part in (*_ROW_PARTS, "bottom_minus_top")
        for name in (
            f"rows_{part}_d2_d1_log",
            *_band_names(f"rows_{part}_tpsd_log", _TEMPORAL_BAND_EDGES, "cpf"),
        )
    ),
)
"""Names of :func:`motion_features`' entries, in order (56). Units: flow magnitudes and global
or local flow in px/frame; divergence and curl in 1/frame; histograms, ``flow_roughness`` and
relative powers dimensionless; ``rows_*`` natural logs of dimensionless ratios. See
:func:`motion_features`."""


def is_int(value) -> bool:
    """Whether ``value`` is an integer (numpy's too), not a bool."""
    return isinstance(value, int | np.integer) and not isinstance(value, bool | np.bool_)


def roi_box(
    coverage: np.ndarray, *, threshold: int = 128, pad: int = 4, min_side: int = 16
) -> tuple[int, int, int, int]:
    """Box around every pixel the cloth covers in any frame, padded, so features ignore the rest.

    Args:
        coverage: Cloth alpha, uint8 (0 = background, 255 = cloth), shape (..., H, W): any
            leading dims (clips, frames) are pooled.
        threshold: A pixel is covered where ``coverage >= threshold``, an integer in [1, 255].
        pad: Margin added on every side [px], >= 0.
        min_side: The box grows (about its centre, shifted to stay inside the image) to at
            least this side [px], >= 1, or to the whole image side if that is smaller. The
            feature functions need sides >= :data:`MIN_BOX_SIDE`.

    Returns:
        ``(y0, y1, x0, x1)`` [px], end-exclusive, inside the image; the whole image when
        nothing is covered.

    Raises:
        ValueError: For a coverage that is not uint8 with >= 2 dims and H, W >= 1, or a bad
            ``threshold``, ``pad`` or ``min_side``.
    """
    coverage = np.asarray(coverage)
    if coverage.dtype != np.uint8 or coverage.ndim < 2 or 0 in coverage.shape[-2:]:
        raise ValueError(
            "coverage must be uint8 with shape (..., H, W), H, W >= 1, "
            f"got {coverage.dtype} {coverage.shape}"
        )
    if not is_int(threshold) or not 1 <= threshold <= 255:
        raise ValueError(f"threshold must be an integer in [1, 255], got {threshold!r}")
    if not is_int(pad) or pad < 0:
        raise ValueError(f"pad must be an integer >= 0, got {pad!r}")
    if not is_int(min_side) or min_side < 1:
        raise ValueError(f"min_side must be an integer >= 1, got {min_side!r}")
    height, width = coverage.shape[-2:]
    covered = (coverage >= threshold).reshape(-1, height, width).any(axis=0)
    rows = np.flatnonzero(covered.any(axis=1))
    if rows.size == 0:
        return 0, int(height), 0, int(width)
    cols = np.flatnonzero(covered.any(axis=0))
    y0, y1 = _pad_span(int(rows[0]), int(rows[-1]) + 1, int(pad), int(min_side), int(height))
    x0, x1 = _pad_span(int(cols[0]), int(cols[-1]) + 1, int(pad), int(min_side), int(width))
    return y0, y1, x0, x1


def _pad_span(lo: int, hi: int, pad: int, min_side: int, size: int) -> tuple[int, int]:
    lo, hi = max(0, lo - pad), min(size, hi + pad)
    side = min(min_side, size)
    if hi - lo < side:
        lo = max(0, (lo + hi - side) // 2)
        hi = lo + side
        if hi > size:
            lo, hi = size - side, size
    return lo, hi


def check_clip(clip: np.ndarray, min_frames: int) -> np.ndarray:
    """``clip`` as a uint8 RGB array (K, H, W, 3) with K >= ``min_frames``, else a ValueError."""
    clip = np.asarray(clip)
    if clip.dtype != np.uint8 or clip.ndim != 4 or clip.shape[-1] != 3:
        raise ValueError(
            f"clip must be uint8 RGB with shape (K, H, W, 3), got {clip.dtype} {clip.shape}"
        )
    if clip.shape[0] < min_frames:
        raise ValueError(f"clip must have K >= {min_frames} frames, got shape {clip.shape}")
    return clip


def check_box(box, height: int, width: int) -> tuple[int, int, int, int]:
    """``box`` as 4 ints inside an H x W frame, sides >= :data:`MIN_BOX_SIDE`, else a ValueError."""
    allowed = (
        f"box must be 4 integers (y0, y1, x0, x1) with 0 <= y0, y1 - y0 >= {MIN_BOX_SIDE}, "
        f"y1 <= H = {height}, 0 <= x0, x1 - x0 >= {MIN_BOX_SIDE}, x1 <= W = {width}"
    )
    try:
        values = tuple(box)
    except TypeError:
        raise ValueError(f"{allowed}; got {box!r}") from None
    if len(values) != 4 or not all(is_int(v) for v in values):
        raise ValueError(f"{allowed}; got {box!r}")
    y0, y1, x0, x1 = (int(v) for v in values)
    ok = (
        0 <= y0
        and y1 <= height
        and 0 <= x0
        and x1 <= width
        and y1 - y0 >= MIN_BOX_SIDE
        and x1 - x0 >= MIN_BOX_SIDE
    )
    if not ok:
        raise ValueError(f"{allowed}; got {box!r}")
    return y0, y1, x0, x1


def _relative_bands(power: np.ndarray, freq: np.ndarray, edges: Sequence[float]) -> np.ndarray:
    # Relative power per band, DC excluded; uniform when there is no power at all, so that a
    # flat signal sits in the middle of the simplex rather than on an arbitrary corner.
    keep = freq > 0
    power, freq = power[keep], freq[keep]
    bands = np.array(
        [power[(freq > lo) & (freq <= hi)].sum() for lo, hi in itertools.pairwise(edges)]
    )
    total = bands.sum()
    if not total > 1e-12:
        return np.full(len(bands), 1.0 / len(bands))
    return bands / total


def _spatial_spectrum(luma: np.ndarray) -> tuple[np.ndarray, float]:
    """Relative radial power in the spatial bands and the high/mid energy ratio."""
    _, h, w = luma.shape
    window = np.outer(np.hanning(h), np.hanning(w))
    centred = (luma - luma.mean(axis=(1, 2), keepdims=True)) * window
    # Mean periodogram over frames; the Hann window stops the box's edges from posing as
    # high-frequency detail.
    power = (np.abs(np.fft.fft2(centred)) ** 2).mean(axis=0) / (h * w)
    radius = np.hypot(np.fft.fftfreq(h)[:, None], np.fft.fftfreq(w)[None, :])
    bands = _relative_bands(power.ravel(), radius.ravel(), _SPATIAL_BAND_EDGES)
    mid = power[(radius > _SPATIAL_BAND_EDGES[2]) & (radius <= _SPATIAL_BAND_EDGES[3])].sum()
    high = power[radius > _SPATIAL_BAND_EDGES[3]].sum()
    return bands, float(high / (mid + _POWER_EPS))


def _immerkaer_sigma(image: np.ndarray) -> float:
    """Immerkær (1996) fast noise std of one float32 (h, w) image [levels]."""
    h, w = image.shape
    response = cv2.filter2D(image, cv2.CV_32F, _IMMERKAER, borderType=cv2.BORDER_REFLECT_101)
    interior = np.abs(response[1:-1, 1:-1], dtype=np.float64)
    return float(math.sqrt(math.pi / 2) * interior.sum() / (6.0 * (w - 2) * (h - 2)))


def _blockiness(crop: np.ndarray, box: tuple[int, int, int, int]) -> float:
    """Mean |step| across 8-px block boundaries / that inside blocks, on the frame's grid.

    ``crop`` is the luma inside ``box``, shape (K, y1 - y0, x1 - x0).
    """
    y0, y1, x0, x1 = box
    # Step between image columns c and c + 1 crosses a JPEG boundary when (c + 1) % 8 == 0;
    # image coordinates, not box ones, since the codec's grid is the full frame's.
    dx = np.abs(np.diff(crop, axis=2))
    dy = np.abs(np.diff(crop, axis=1))
    across_x = (np.arange(x0, x1 - 1) + 1) % 8 == 0
    across_y = (np.arange(y0, y1 - 1) + 1) % 8 == 0
    boundary = [dx[:, :, across_x].ravel(), dy[:, across_y, :].ravel()]
    inside = [dx[:, :, ~across_x].ravel(), dy[:, ~across_y, :].ravel()]
    boundary, inside = np.concatenate(boundary), np.concatenate(inside)
    if boundary.size == 0 or inside.size == 0:
        return 1.0
    return float((boundary.mean() + _POWER_EPS) / (inside.mean() + _POWER_EPS))


def pixel_features(clip: np.ndarray, box: tuple[int, int, int, int]) -> np.ndarray:
    """Image-pipeline and appearance statistics of one clip inside ``box``.

    Evidence for what a camera or renderer changes (exposure, colour cast, clipping, blur,
    sensor noise, JPEG, frame-rate conversion, flicker); entries are named by
    :data:`PIXEL_FEATURE_NAMES`:

    * ``mean_*``, ``std_*``: per-channel mean and std over all pixels and frames [levels];
    * ``luma_pNN``: Rec. 601 luma percentiles [levels];
    * ``chroma_mean`` (max - min channel) [levels], ``saturation_*`` (HSV saturation, [0, 1]);
    * ``cast_r_over_g``, ``cast_b_over_g``: ratios of channel means (1 level added to each
      so a black clip gives 1);
    * ``frac_near_black`` / ``frac_near_white``: share of channel values <= 3 / >= 252;
    * ``laplacian_std`` (std of the 4-neighbour Laplacian of luma) [levels],
      ``gradient_mean`` (Sobel gradient magnitude) [levels/px], ``hf_mf_ratio`` (radial
      power above 1/4 cycles/px over that in (1/8, 1/4], Hann-windowed), and
      ``spatial_power_*`` (relative radial power in 4 bands, summing to 1);
    * ``noise_sigma_*``: Immerkær's (1996) noise std per channel and of luma, median over
      frames [levels] (fine texture raises it too, so compare like with like);
    * ``temporal_noise``: mean |frame - median of it and its two neighbours| [levels];
    * ``blockiness``: mean |luma step| across 8-px block boundaries, at multiples of 8 in
      frame coordinates, over that inside blocks (about 1 without JPEG blocking);
    * ``frame_diff_mean`` and ``frame_diff_cv``: mean and coefficient of variation of the
      per-pair mean |luma difference| [levels]; ``duplicate_frac``: share of consecutive
      pairs that do not change beyond noise: mean squared luma difference minus 2 x
      ``noise_sigma_luma``² below 0.01 levels², below half that noise energy, or below 0.1 x
      its 75th percentile over the clip's pairs (repeated frames amid motion; a static clip
      counts as all duplicates);
      ``luma_mean_temporal_std``: std over frames of the frame's mean luma [levels]
      (flicker, lighting change).

    Temporal entries are 0 where K is too small for them (K < 2, or K < 3 for
    ``temporal_noise``).

    Args:
        clip: Frames, uint8 RGB, shape (K, H, W, 3), K >= 1.
        box: ``(y0, y1, x0, x1)`` [px], end-exclusive, inside the frame, sides >= 8.

    Returns:
        Features, float64, shape (len(PIXEL_FEATURE_NAMES),) = (35,).

    Raises:
        ValueError: For a clip that is not uint8 (K, H, W, 3) or a box outside the frame or
            with a side below :data:`MIN_BOX_SIDE`.
    """
    clip = check_clip(clip, 1)
    box = check_box(box, clip.shape[1], clip.shape[2])
    y0, y1, x0, x1 = box
    frame_count = clip.shape[0]
    crop = clip[:, y0:y1, x0:x1]
    # Channel planes, not an (N, 3) array: reductions over a length-3 axis are slow.
    planes = [crop[..., c].astype(np.float64) for c in range(3)]
    luma = _LUMA[0] * planes[0] + _LUMA[1] * planes[1] + _LUMA[2] * planes[2]  # (K, h, w)

    means = np.array([plane.mean() for plane in planes])
    stds = np.array([plane.std() for plane in planes])
    percentiles = np.percentile(luma, _LUMA_PERCENTILES)
    high = np.maximum(np.maximum(planes[0], planes[1]), planes[2])
    chroma = high - np.minimum(np.minimum(planes[0], planes[1]), planes[2])
    saturation = np.divide(chroma, high, out=np.zeros_like(chroma), where=high > 0)
    cast = (means[[0, 2]] + _RATIO_EPS) / (means[1] + _RATIO_EPS)
    near_black = float(np.mean(crop <= _NEAR_BLACK))
    near_white = float(np.mean(crop >= _NEAR_WHITE))

    luma32 = luma.astype(np.float32)
    lap_var, grad_mean = [], []
    for frame in luma32:
        lap = cv2.Laplacian(frame, cv2.CV_32F, ksize=1, borderType=cv2.BORDER_REFLECT_101)
        gx = cv2.Sobel(frame, cv2.CV_32F, 1, 0, ksize=3, borderType=cv2.BORDER_REFLECT_101)
        gy = cv2.Sobel(frame, cv2.CV_32F, 0, 1, ksize=3, borderType=cv2.BORDER_REFLECT_101)
        # Interior only: the reflected border is not image content. Sobel's gain is 8.
        lap_var.append(np.var(lap[1:-1, 1:-1], dtype=np.float64))
        grad_mean.append(np.mean(np.hypot(gx[1:-1, 1:-1], gy[1:-1, 1:-1]), dtype=np.float64) / 8)
    laplacian_std = math.sqrt(float(np.mean(lap_var)))
    spatial_bands, hf_mf = _spatial_spectrum(luma)

    planes32 = [plane.astype(np.float32) for plane in planes]
    planes32.append(luma.astype(np.float32))
    noise = np.median(
        [[_immerkaer_sigma(plane[k]) for plane in planes32] for k in range(frame_count)],
        axis=0,
    )  # R, G, B, luma
    if frame_count >= 3:
        before, now, after = luma[:-2], luma[1:-1], luma[2:]
        # Median of three without a sort: max(min(a, b), min(max(a, b), c)).
        median = np.maximum(np.minimum(before, now), np.minimum(np.maximum(before, now), after))
        temporal_noise = float(np.mean(np.abs(now - median)))
    else:
        temporal_noise = 0.0

    blockiness = _blockiness(luma, box)

    if frame_count >= 2:
        step = np.diff(luma, axis=0)
        diffs = np.abs(step).mean(axis=(1, 2))
        diff_mean = float(diffs.mean())
        diff_cv = float(diffs.std() / (diff_mean + _POWER_EPS))
        # A repeated frame still differs by its fresh sensor noise (noise comes after the
        # frame-rate converter), so judge the mean squared change beyond the 2 sigma² that
        # two noisy copies of one frame differ by.
        noise_energy = 2.0 * noise[3] ** 2
        change = np.maximum((step**2).mean(axis=(1, 2)) - noise_energy, 0.0)
        floor = max(_DUP_ABS, _DUP_NOISE * noise_energy)
        reference = np.percentile(change, 75)
        duplicate = float(np.mean((change <= floor) | (change < _DUP_REL * reference)))
    else:
        diff_mean = diff_cv = duplicate = 0.0
    flicker = float(luma.mean(axis=(1, 2)).std())

    out = np.concatenate(
        [
            means,
            stds,
            percentiles,
            [chroma.mean(), saturation.mean(), saturation.std()],
            cast,
            [near_black, near_white, laplacian_std, float(np.mean(grad_mean))],
            [hf_mf],
            spatial_bands,
            noise,
            [temporal_noise, blockiness, diff_mean, diff_cv, duplicate, flicker],
        ]
    ).astype(np.float64)
    return out


def normalised_frames(clip: np.ndarray, box: tuple[int, int, int, int]) -> np.ndarray:
    """Luma inside the box, each frame standardised: z-scores, float32 (K, h, w)."""
    y0, y1, x0, x1 = box
    luma = clip[:, y0:y1, x0:x1].astype(np.float32) @ _LUMA.astype(np.float32)
    mean = luma.mean(axis=(1, 2), keepdims=True)
    std = np.maximum(luma.std(axis=(1, 2), keepdims=True), _NORM_STD_FLOOR)
    return (luma - mean) / std


def _dense_flow(z: np.ndarray) -> np.ndarray:
    """Farneback flow from each frame to the next [px/frame], float32 (K - 1, h, w, 2)."""
    # Farneback takes float32 as well as 8-bit; float keeps the normalised frames
    # unquantised, so a contrast change cannot alter the flow through rounding.
    images = (128.0 + _NORM_SCALE * z).astype(np.float32)
    return np.stack(
        [
            cv2.calcOpticalFlowFarneback(images[k], images[k + 1], None, **_FARNEBACK)
            for k in range(len(images) - 1)
        ]
    )


def _linear_detrend(series: np.ndarray) -> np.ndarray:
    """Each column of ``series`` (T, N) less its least-squares line in time, float64.

    The closed form of ``scipy.signal.detrend(series, axis=0, type="linear")``: with time
    centred, the constant and the slope are orthogonal, so each is one projection. It is a
    few vector products where scipy solves a least-squares problem over every column (about
    a third of the hand-made rungs' time).
    """
    x = np.asarray(series, dtype=np.float64)
    t = np.arange(len(x), dtype=np.float64)
    t -= t.mean()
    slope = (t @ x) / (t @ t) if len(x) > 1 else np.zeros(x.shape[1:])
    return x - x.mean(axis=0) - np.multiply.outer(t, slope)


def _temporal_bands(series: np.ndarray) -> np.ndarray:
    """Relative temporal power of per-pixel series (T, ...) in the temporal bands (sum 1)."""
    length = series.shape[0]
    if length < 2:
        return np.full(len(_TEMPORAL_BAND_EDGES) - 1, 0.25)
    flat = _linear_detrend(series.reshape(length, -1))
    power = (np.abs(np.fft.rfft(flat, axis=0)) ** 2).mean(axis=1)
    return _relative_bands(power, np.fft.rfftfreq(length), _TEMPORAL_BAND_EDGES)


def motion_features(clip: np.ndarray, box: tuple[int, int, int, int]) -> np.ndarray:
    """Appearance-free motion statistics of one clip inside ``box``, evidence on the dynamics.

    Each frame's luma is standardised inside the box (zero mean, unit std; std floored at 1
    level so flat frames stay flat), which removes brightness, contrast and most colour
    changes; dense Farneback flow (pyramid 0.5 x 3 levels, window 15 px) then runs between
    consecutive frames. Entries, named by :data:`MOTION_FEATURE_NAMES`:

    * ``flow_mag_hist_*``: share of flow vectors per magnitude bin [px/frame]: [0, 0.05),
      six log-spaced bins up to 8, [8, inf);
    * ``flow_dir_*``: magnitude-weighted direction histogram (sum 1; uniform when nothing
      moves). Eight 45° bins centred on compass directions as seen on screen: ``e`` is +x
      (rightwards), ``n`` is -y (upwards, image rows grow downwards), counter-clockwise;
    * ``flow_mag_pNN``, ``flow_mag_mean``: magnitude percentiles and mean [px/frame];
    * ``divergence_mean`` (signed), ``divergence_abs_mean``, ``curl_abs_mean`` [1/frame];
    * ``global_flow_x_std``, ``global_flow_y_std``: std over time of the per-frame median
      flow's components [px/frame] (camera shake), ``global_speed_mean``: mean length of
      that median flow, ``local_flow_mean``: mean |flow - median flow| (deformation);
    * ``flow_roughness``: mean |flow_t+1 - flow_t| / mean |flow| (temporal non-smoothness);
    * ``intensity_tpsd_*`` and ``flow_mag_tpsd_*``: per-pixel temporal power spectrum of the
      normalised intensity and of the flow magnitude (linearly detrended, averaged over
      pixels), as relative power in four bands of (0, 0.5] cycles/frame, DC excluded (sum
      1; uniform when the series are flat);
    * ``rows_<part>_*`` for the top, middle and bottom third of the box, and their
      ``bottom_minus_top`` difference: ``d2_d1_log``, log of the mean squared second time
      difference of the normalised intensity over the mean squared first difference, and
      ``tpsd_log_*``, logs of that third's relative temporal band powers. Anything that
      acts on time row by row (a rolling shutter's readout) shows in the difference; a
      frame-rate change or motion blur treats every row alike, so a row-blind ladder cannot
      tell them apart. The library's ``visual.rolling_shutter`` renders each band of rows
      at its time, which shifts a row's series in time without changing its spectrum: it
      shows as a skew of the motion (decision record: docs/design/sim2real-row-aware-features.md).

    Args:
        clip: Frames, uint8 RGB, shape (K, H, W, 3), K >= 3 (flow needs two frame pairs for
            its temporal statistics).
        box: ``(y0, y1, x0, x1)`` [px], end-exclusive, inside the frame, sides >= 8.

    Returns:
        Features, float64, shape (len(MOTION_FEATURE_NAMES),) = (56,).

    Raises:
        ValueError: For a clip that is not uint8 (K, H, W, 3) with K >= 3, or a box outside
            the frame or with a side below :data:`MIN_BOX_SIDE`.
    """
    clip = check_clip(clip, 3)
    box = check_box(box, clip.shape[1], clip.shape[2])
    z = normalised_frames(clip, box)
    flow = _dense_flow(z).astype(np.float64)  # (T, h, w, 2), T = K - 1
    fx, fy = flow[..., 0], flow[..., 1]
    magnitude = np.hypot(fx, fy)

    mag_hist = np.histogram(magnitude, bins=np.asarray(_MAG_EDGES))[0] / magnitude.size
    angle = np.arctan2(-fy, fx)  # counter-clockwise from +x with y pointing up on screen
    sector = np.floor((angle + math.pi / 8) / (math.pi / 4)).astype(np.int64) % 8
    dir_hist = np.bincount(sector.ravel(), weights=magnitude.ravel(), minlength=8)
    dir_total = dir_hist.sum()
    dir_hist = dir_hist / dir_total if dir_total > 1e-12 else np.full(8, 1.0 / 8)
    percentiles = np.percentile(magnitude, _MAG_PERCENTILES)
    mag_mean = float(magnitude.mean())

    dudx = np.gradient(fx, axis=2)
    dudy = np.gradient(fx, axis=1)
    dvdx = np.gradient(fy, axis=2)
    dvdy = np.gradient(fy, axis=1)
    divergence = dudx + dvdy
    curl = dvdx - dudy

    global_flow = np.median(flow.reshape(len(flow), -1, 2), axis=1)  # (T, 2)
    global_std = global_flow.std(axis=0)
    global_speed = float(np.hypot(global_flow[:, 0], global_flow[:, 1]).mean())
    residual = flow - global_flow[:, None, None, :]
    local = float(np.hypot(residual[..., 0], residual[..., 1]).mean())
    step = np.diff(flow, axis=0)
    roughness = float(np.hypot(step[..., 0], step[..., 1]).mean() / (mag_mean + _FLOW_EPS))

    out = np.concatenate(
        [
            mag_hist,
            dir_hist,
            percentiles,
            [mag_mean, divergence.mean(), np.abs(divergence).mean(), np.abs(curl).mean()],
            global_std,
            [global_speed, local, roughness],
            _temporal_bands(z),
            _temporal_bands(magnitude),
            _row_timing(z),
        ]
    ).astype(np.float64)
    return out


def _row_timing(z: np.ndarray) -> np.ndarray:
    """The ``rows_*`` entries of :func:`motion_features` from normalised frames (K, h, w).

    Per third of the rows, then the bottom third's minus the top third's.
    """
    z = z.astype(np.float64)
    edges = np.linspace(0, z.shape[1], len(_ROW_PARTS) + 1).round().astype(int)
    parts = []
    for top, bottom in itertools.pairwise(edges):
        rows = z[:, top:bottom]
        first = np.mean(np.diff(rows, axis=0) ** 2)
        second = np.mean(np.diff(rows, n=2, axis=0) ** 2)
        parts.append(
            [
                math.log(second + _LOG_EPS) - math.log(first + _LOG_EPS),
                *np.log(_temporal_bands(rows) + _LOG_EPS),
            ]
        )
    parts = np.asarray(parts)
    return np.concatenate([parts.ravel(), parts[-1] - parts[0]])
