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
- exposure flicker scales each frame's brightness as a mains-powered light seen with a
  short exposure does (the light's 100 Hz flicker, aliased by the frame rate);
- a tone curve maps each pixel value;
- wind speed scales the scene's wind speeds (applied to the scenario by :mod:`.seal`).

The rolling shutter was one (rounds 11-17) until it became a library effect
(``visual.rolling_shutter``): real CMOS footage has it, and faithfully rendered it reads as
a change of the cloth's motion that no rule could tell from physics (rounds 16-17).
"""

from __future__ import annotations

import dataclasses
import math

import cv2
import numpy as np

from .image_twins import apply_image_twins, without_twinned

__all__ = [
    "FLICKER_LIGHT_HZ",
    "OPEN_SET_EFFECTS",
    "apply_exposure_flicker",
    "apply_tone_curve",
    "barrel_image",
    "barrel_points",
    "flicker_frequency",
    "render_sealed_video",
]

OPEN_SET_EFFECTS = {
    "barrel_distortion": ("camera", (0.1, 0.25)),
    "exposure_flicker": ("camera", (0.04, 0.12)),
    "tone_curve": ("camera", (0.55, 0.75)),
    "wind_speed": ("scene", (1.4, 1.8)),
}
"""Effects no switch models: stage and strength range. Barrel distortion: the pixel at
normalised radius rho (rho² = (u² + v²) / 2, u and v in [-1, 1] across the frame, so rho = 1
at a corner) shows what a pinhole camera shows at rho (1 + k rho²) (a wide-angle lens's
first radial term); exposure flicker: relative amplitude of the frames' brightness
oscillation (:func:`apply_exposure_flicker`); tone curve: gamma (< 1 brightens the
mid-tones); wind speed: factor on the scene's wind speeds. Vignetting (until 2026-11-27)
and the rolling shutter (until 2026-11-29) were ones until they became library effects."""

FLICKER_LIGHT_HZ = 100.0
"""Brightness oscillation of a light on 50 Hz mains (twice the mains frequency)."""


def flicker_frequency(fps: float, light_hz: float = FLICKER_LIGHT_HZ) -> float:
    """Frequency [Hz] at which frames taken at ``fps`` see a light flickering at ``light_hz``.

    Sampling aliases it to its distance from the nearest multiple of the frame rate (5 Hz for
    100 Hz at 15 frames/s: a period of three frames).
    """
    return abs(light_hz - fps * round(light_hz / fps))


def apply_exposure_flicker(
    frames: np.ndarray, amplitude: float, fps: float, phase: float
) -> np.ndarray:
    """uint8 frames (K, H, W, 3) whose brightness oscillates as under a flickering light.

    Frame ``k`` is scaled by ``1 + amplitude sin(2 pi f k / fps + phase)`` with ``f`` from
    :func:`flicker_frequency`: an exposure much shorter than the light's period catches it at
    another point of its cycle in each frame.
    """
    k = np.arange(frames.shape[0])
    gain = 1.0 + amplitude * np.sin(2 * np.pi * flicker_frequency(fps) * k / fps + phase)
    values = frames.astype(np.float32) * gain.astype(np.float32)[:, None, None, None]
    return np.clip(np.rint(values), 0, 255).astype(np.uint8)


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


def render_sealed_video(
    spec,
    seq,
    b: int,
    plan,
    start: int,
    stop: int,
    *,
    rng_seed: list,
    effects: list[dict],
    image_twins: bool = False,
) -> np.ndarray:
    """Frames ``[start, stop)`` of instance ``b`` of ``seq`` with out-of-library image effects.

    Rendered as ``spec`` renders them (:func:`datasets.generation.render_frames`; ``rng_seed``
    seeds the renderer's random draws), with the sealed answer's (``effects``: its entries)
    out-of-library image effects added (with none, the plain render): a barrel lens moves the
    cloth and the arm before rendering, the others act on the rendered frames. With
    ``image_twins`` the spec's image effects that have a second implementation
    (:mod:`.image_twins`) are applied by it instead of the renderer.
    """
    from datasets.generation import render_frames, sim_look

    strengths = {e["name"]: e["strength"] for e in effects if not e["library"]}
    texture, background = sim_look(spec, plan)
    one = slice(b, b + 1)
    video = dataclasses.replace(
        seq, pos=seq.pos[one], capsules=None if seq.capsules is None else seq.capsules[one]
    )
    if "barrel_distortion" in strengths:
        strength = strengths["barrel_distortion"]
        capsules = video.capsules
        if capsules is not None:  # the arm's segments' end points; radii kept
            capsules = capsules.astype(np.float64)
            for end in (slice(0, 3), slice(3, 6)):
                capsules[..., end] = barrel_points(capsules[..., end], spec.camera, strength)
        video = dataclasses.replace(
            video,
            pos=barrel_points(video.pos.astype(np.float64), spec.camera, strength),
            capsules=capsules,
        )
        background = barrel_image(background, strength)
    rendered = spec
    if image_twins:
        rendered = dataclasses.replace(spec, visual=without_twinned(spec.visual))
    frames, _ = render_frames(
        rendered,
        video,
        0,
        plan,
        start,
        stop,
        rng=np.random.default_rng(rng_seed),
        capsules=video.capsules,
        look=(texture, background),
    )
    if image_twins:
        frames = apply_image_twins(frames, spec.visual, np.random.default_rng([*rng_seed, 3]))
    if "exposure_flicker" in strengths:
        phase = np.random.default_rng([*rng_seed, 1]).uniform(0.0, 2 * np.pi)
        frames = apply_exposure_flicker(
            frames, strengths["exposure_flicker"], spec.preset.fps, phase
        )
    if "tone_curve" in strengths:
        frames = apply_tone_curve(frames, strengths["tone_curve"])
    return frames
