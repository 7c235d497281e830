"""Out-of-library effects of the sealed sets, each made the way a camera or scene makes it.

The open-set sealed sets withhold an effect that no switch models, to check that the
diagnosis then answers "unexplained" instead of naming a library effect. That test is only
fair when the set holds that effect and nothing else. Image-space stand-ins do not: blind
rounds 11-15 resampled each frame with a bilinear remap for the barrel distortion (which
lowers the cloth's Laplacian energy by 29-33 %, as a defocus of 0.6 px does) and blended
each row with the next frame for the rolling shutter (a temporal low-pass, which is what
motion blur is). Their look-alike answers, defocus and motion blur, were partly right.
So here:

- barrel distortion moves the cloth's vertices to where a barrel lens images them (what a
  vertex shader does; the render samples the texture as the nominal one does); only the
  background image, which has no geometry, is resampled;
- rolling shutter renders each band of rows at that band's readout time, with positions
  interpolated linearly within the frame interval (as the renderer's motion blur does), so
  a moving edge is skewed, not ghosted;
- a tone curve maps each pixel value;
- wind speed scales the scene's wind speeds (applied to the scenario by :mod:`.seal`).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

__all__ = [
    "OPEN_SET_EFFECTS",
    "ROLLING_SHUTTER_BANDS",
    "apply_tone_curve",
    "barrel_image",
    "barrel_points",
    "render_sealed_video",
    "rolling_shutter_times",
]

OPEN_SET_EFFECTS = {
    "rolling_shutter": ("camera", (0.5, 1.0)),
    "barrel_distortion": ("camera", (0.1, 0.25)),
    "tone_curve": ("camera", (0.55, 0.75)),
    "wind_speed": ("scene", (1.4, 1.8)),
}
"""Effects no switch models: stage and strength range. Rolling shutter: readout time of the
frame (top row to bottom row) as a fraction of the frame interval; barrel distortion: the
pixel at normalised radius rho (rho² = (u² + v²) / 2, u and v in [-1, 1] across the frame,
so rho = 1 at a corner) shows what a pinhole camera shows at rho (1 + k rho²) (a wide-angle
lens's first radial term); tone curve: gamma (< 1 brightens the mid-tones); wind speed:
factor on the scene's wind speeds. Vignetting was one until it became a library effect
(``visual.vignetting``, 2026-11-27)."""

ROLLING_SHUTTER_BANDS = 8
"""Row bands of a rolling-shutter frame, each rendered at its own time. With the strongest
readout (one frame interval) neighbouring bands lie an eighth of a frame apart: the cloth of
the wind scene moves about 0.2 px in that time at 112 px, well below what blurs."""


def apply_tone_curve(frames: np.ndarray, gamma: float) -> np.ndarray:
    """uint8 frames through the tone curve ``255 (x / 255) ** gamma``."""
    values = 255.0 * (frames.astype(np.float32) / 255.0) ** gamma
    return np.clip(np.rint(values), 0, 255).astype(np.uint8)


def _undistorted_radius(rho: np.ndarray, strength: float) -> np.ndarray:
    """Image radius rho_d under the barrel lens of a point a pinhole camera shows at ``rho``.

    Solves rho_d (1 + k rho_d²) = rho by Newton's method: the left side is increasing and
    convex, so the iteration converges from rho without overshoot.
    """
    out = rho.copy()
    for _ in range(30):
        step = (out * (1 + strength * out * out) - rho) / (1 + 3 * strength * out * out)
        out -= step
        if np.max(np.abs(step), initial=0.0) < 1e-12:
            break
    return out


def barrel_points(points: np.ndarray, camera, strength: float) -> np.ndarray:
    """World points moved so that the pinhole ``camera`` images them where a barrel lens does.

    ``camera`` is a :class:`render.camera.CameraSpec`; points keep their shape (..., 3).
    A pinhole image point (u, v) of normalised radius rho shows at (u, v) rho_d / rho, where
    rho_d (1 + k rho_d²) = rho (:data:`OPEN_SET_EFFECTS`). Depth is kept, so the triangles'
    visibility, the texture and the lighting barely change; the straight edges between
    vertices stay straight, which at the mesh's vertex spacing is far below a pixel.
    """
    points = np.asarray(points, np.float64)
    pose = camera.pose()
    to_camera = np.linalg.inv(pose)
    cam = points @ to_camera[:3, :3].T + to_camera[:3, 3]
    depth = -cam[..., 2]
    focal = 0.5 * camera.height / math.tan(math.radians(camera.yfov_deg) / 2)
    u = focal * cam[..., 0] / depth / (0.5 * camera.width)
    v = focal * cam[..., 1] / depth / (0.5 * camera.height)
    rho = np.sqrt(0.5 * (u * u + v * v))
    rho_d = _undistorted_radius(rho, strength)
    ratio = np.divide(rho_d, rho, out=np.ones_like(rho), where=rho > 0)
    cam[..., 0] *= ratio
    cam[..., 1] *= ratio
    return cam @ pose[:3, :3].T + pose[:3, 3]


def barrel_image(image: np.ndarray, strength: float, interpolation: int = cv2.INTER_NEAREST):
    """An image (H, W, C) as a barrel lens of ``strength`` shows it.

    The pixel at normalised radius rho takes the source at rho (1 + k rho²). Used for the
    background, which has no geometry to move. The nearest source pixel, not an interpolated
    value: the background's blurred shapes move by under half a pixel more or less, and its
    pixel grain keeps its statistics instead of being low-passed (a bilinear remap does that,
    as blind rounds 11-15's image-space stand-in did to the whole frame).
    """
    height, width = image.shape[:2]
    y, x = np.mgrid[0:height, 0:width].astype(np.float32) + 0.5
    u, v = (x - width / 2) / (width / 2), (y - height / 2) / (height / 2)
    scale = 1 + strength * (u * u + v * v) / 2
    map_x = (u * scale * (width / 2) + width / 2 - 0.5).astype(np.float32)
    map_y = (v * scale * (height / 2) + height / 2 - 0.5).astype(np.float32)
    return cv2.remap(image, map_x, map_y, interpolation, borderMode=cv2.BORDER_REFLECT_101)


def rolling_shutter_times(readout: float, bands: int = ROLLING_SHUTTER_BANDS) -> np.ndarray:
    """Each row band's exposure time after its frame's, in frame intervals.

    That is the band's middle row's readout, ``readout * (j + 0.5) / bands``; the top row is
    read first.
    """
    return readout * (np.arange(bands) + 0.5) / bands


def _at_time(values: np.ndarray, start: int, stop: int, offset: float) -> np.ndarray:
    """Frames ``[start, stop)`` of ``values`` (K, ...), ``offset`` of a frame interval later.

    Interpolated linearly (``offset`` in [0, 1]); needs ``stop < K``.
    """
    now, later = values[start:stop].astype(np.float64), values[start + 1 : stop + 1]
    return now + offset * (later - now)


def render_sealed_video(spec, seq, b: int, plan, start: int, stop: int, *, rng_seed: list,
                        effects: list[dict]) -> np.ndarray:  # fmt: skip
    """Frames ``[start, stop)`` of instance ``b`` of ``seq`` with out-of-library image effects.

    Rendered as ``spec`` renders them, with the sealed answer's (``effects``: its entries)
    out-of-library image effects added.

    ``rng_seed`` seeds the renderer's random draws; a rolling shutter renders every band with
    the same draws, so only time differs between bands. The rolling shutter needs the frame
    after ``stop - 1`` in ``seq`` (the sealer records one more).
    """
    from datasets.generation import renderer_for, sim_look

    strengths = {e["name"]: e["strength"] for e in effects if not e["library"]}
    if "rolling_shutter" in strengths and seq.pos.shape[1] <= stop:
        raise ValueError(
            f"seq: a rolling shutter reads its last rows after frame {stop - 1}; record at least "
            f"{stop + 1} frames, got {seq.pos.shape[1]}"
        )
    texture, background = sim_look(spec, plan)
    pos = seq.pos[b].astype(np.float64)
    capsules = None if seq.capsules is None else seq.capsules[b].astype(np.float64)
    if "barrel_distortion" in strengths:
        strength = strengths["barrel_distortion"]
        pos = barrel_points(pos, spec.camera, strength)
        if capsules is not None:  # the arm's segments' end points; radii kept
            capsules = capsules.copy()
            for end in (slice(0, 3), slice(3, 6)):
                capsules[..., end] = barrel_points(capsules[..., end], spec.camera, strength)
        background = barrel_image(background, strength)
    renderer = renderer_for(spec)

    def render(offset: float) -> np.ndarray:
        frames, _ = renderer.render_clip(
            _at_time(pos, start, stop, offset) if offset else pos[start:stop],
            seq.tri_indices, seq.uv, texture, background,
            capsules=None if capsules is None else (
                _at_time(capsules, start, stop, offset) if offset else capsules[start:stop]
            ),
            rng=np.random.default_rng(rng_seed), coverage=True,
        )  # fmt: skip
        return frames

    if "rolling_shutter" in strengths:
        times = rolling_shutter_times(strengths["rolling_shutter"])
        height = spec.camera.height
        edges = np.linspace(0, height, len(times) + 1).round().astype(int)
        frames = None
        for j, offset in enumerate(times):
            band = render(float(offset))
            frames = band if frames is None else frames
            frames[:, edges[j] : edges[j + 1]] = band[:, edges[j] : edges[j + 1]]
    else:
        frames = render(0.0)
    if "tone_curve" in strengths:
        frames = apply_tone_curve(frames, strengths["tone_curve"])
    return frames
