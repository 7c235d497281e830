"""Tracked-point trajectories: evidence on how the cloth moves that the picture cannot fake.

The motion rung's dense flow reads every pixel of the box, so a texture, a backdrop or a
sharpening filter changes it: flow is defined where the image has gradients, and a plain
cloth on a busy backdrop flows differently from a checked one on a plain backdrop. Here only
points that can be followed are read: corners of the first frame, tracked frame to frame
(pyramidal Lucas-Kanade) and kept when the backward track returns to where the forward one
started. Points that never move (the backdrop, the pole) are dropped, and the statistics
are over the trajectories of the rest, in units of the box: how far and how fast the cloth
moves, in which direction, and how the amplitude grows from the pinned edge down. Which
points carry a corner depends on the texture; what the points do does not, as long as the
cloth carries some texture. Statistics of a trajectory's jitter (its second differences, the
velocity's autocorrelation, the share of motion the points have in common) are left out:
a point's tracking noise depends on the corner it sits on, so they change with the texture
(see benchmarks/sim2real_rung_invariance.py for how far each rung moves).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from .features import check_box, check_clip, normalised_frames

__all__ = ["TRACK_FEATURE_NAMES", "track_features"]

TRACK_FEATURE_NAMES: tuple[str, ...] = (
    "track_speed_log_p50",
    "track_speed_log_p90",
    "track_amplitude_log_x",
    "track_amplitude_log_y",
    "track_amplitude_slope_y",
    "track_horizontal_share",
)
"""Names of :func:`track_features`' entries, in order."""

_MAX_POINTS = 64
_QUALITY = 0.02  # corner strength relative to the strongest corner of the frame
_MIN_DISTANCE = 3  # [px] between corners
_LK = {
    "winSize": (15, 15),
    "maxLevel": 3,
    "criteria": (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 20, 0.01),
}
_BACK_TOLERANCE = 1.0  # [px]: a step whose backward track misses its start by more is lost
_STILL = 0.5  # [px]: a track whose points all stay this close to its start is the backdrop
_MIN_TRACKS = 3  # fewer moving tracks: the clip shows no trackable motion
_EPS = 1e-4  # [box units] keeps the logs finite on still clips


def track_features(clip: np.ndarray, box: tuple[int, int, int, int]) -> np.ndarray:
    """Statistics of the moving trajectories inside ``box``, named by :data:`TRACK_FEATURE_NAMES`.

    Frames are standardised inside the box as for the motion rung (brightness and contrast
    removed). Lengths are in units of the box's height (a trajectory crossing the box
    moves 1), per frame for speeds:

    * ``track_speed_log_p50``, ``_p90``: log of the median and 90th percentile step length;
    * ``track_amplitude_log_x``, ``_y``: log of the median over tracks of each coordinate's
      standard deviation over time;
    * ``track_amplitude_slope_y``: least-squares slope of a track's amplitude (both axes)
      against its mean height in the box, downwards positive (a cloth pinned at the top moves
      more below);
    * ``track_horizontal_share``: share of the squared velocity along x.

    A clip with fewer than three moving tracks (a still cloth, or one without texture) gets
    the entries of a still clip: speeds and amplitudes at the floor, share and slope 0.

    Args:
        clip: Frames, uint8 RGB, shape (K, H, W, 3), K >= 3.
        box: ``(y0, y1, x0, x1)`` [px], end-exclusive, inside the frame, sides >= 8.

    Returns:
        Features, float64, shape (len(TRACK_FEATURE_NAMES),).
    """
    clip = check_clip(clip, 3)
    box = check_box(box, clip.shape[1], clip.shape[2])
    z = normalised_frames(clip, box)
    frames = np.clip(128.0 + 40.0 * z, 0, 255).astype(np.uint8)
    paths = _trajectories(frames)  # (N, K, 2) [px]
    scale = float(box[1] - box[0])
    if paths.shape[0] >= 1:
        moving = np.nanmax(np.abs(paths - paths[:, :1]), axis=(1, 2)) > _STILL
        paths = paths[moving] / scale
    if paths.shape[0] < _MIN_TRACKS:
        still = math.log(_EPS)
        return np.array([still, still, still, still, 0.0, 0.0])
    return _statistics(paths)


def _trajectories(frames: np.ndarray) -> np.ndarray:
    """Corners of the first frame followed until lost: (N, K, 2) [px], NaN once lost.

    A track is lost at the first step that LK does not find, or whose backward track misses
    the point it started from by more than :data:`_BACK_TOLERANCE`. Lost tracks keep their
    earlier positions, so a clip whose fast parts lose their points still shows their start
    (a track kept only when it lasts the clip would leave the slow parts alone).
    """
    corners = cv2.goodFeaturesToTrack(
        frames[0], _MAX_POINTS, _QUALITY, _MIN_DISTANCE, blockSize=5, useHarrisDetector=False
    )
    if corners is None:
        return np.zeros((0, len(frames), 2))
    points = corners.reshape(-1, 1, 2).astype(np.float32)
    path = np.full((len(points), len(frames), 2), np.nan)
    path[:, 0] = points[:, 0]
    alive = np.ones(len(points), bool)
    for k in range(1, len(frames)):
        ahead, found, _ = cv2.calcOpticalFlowPyrLK(frames[k - 1], frames[k], points, None, **_LK)
        back, returned, _ = cv2.calcOpticalFlowPyrLK(frames[k], frames[k - 1], ahead, None, **_LK)
        miss = np.linalg.norm((back - points).reshape(-1, 2), axis=1)
        alive &= (found.ravel() == 1) & (returned.ravel() == 1) & (miss < _BACK_TOLERANCE)
        path[alive, k] = ahead[alive, 0]
        points = ahead
    return path


def _statistics(paths: np.ndarray) -> np.ndarray:
    """The entries of :func:`track_features` from moving trajectories (N, K, 2) [box units].

    Positions are NaN where a track was lost; amplitudes come from the tracks that last half
    the clip or more.
    """
    velocity = np.diff(paths, axis=1)  # (N, K-1, 2), NaN after a loss
    steps = velocity[np.isfinite(velocity).all(axis=2)]  # (S, 2)
    speed = np.hypot(steps[:, 0], steps[:, 1])
    p50, p90 = np.percentile(speed, [50, 90]) if speed.size else (0.0, 0.0)
    lasting = np.isfinite(paths[..., 0]).sum(axis=1) >= (paths.shape[1] + 1) // 2
    spread = np.nanstd(paths[lasting], axis=1) if lasting.any() else np.zeros((1, 2))
    amplitude = np.hypot(spread[:, 0], spread[:, 1])
    height = np.nanmean(paths[lasting][..., 1], axis=1) if lasting.any() else np.zeros(1)
    centred = height - height.mean()
    denominator = float((centred**2).sum())
    slope = float((centred * amplitude).sum() / denominator) if denominator > 1e-12 else 0.0
    energy = (steps**2).sum(axis=0)
    horizontal = float(energy[0] / max(energy.sum(), 1e-12))
    return np.array(
        [
            math.log(p50 + _EPS),
            math.log(p90 + _EPS),
            math.log(float(np.median(spread[:, 0])) + _EPS),
            math.log(float(np.median(spread[:, 1])) + _EPS),
            slope,
            horizontal,
        ],
        dtype=np.float64,
    )
