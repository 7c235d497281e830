"""Lighting of the rendered scenes: one directional key light plus uniform ambient light.

:class:`LightSpec` is a frozen, validated value; the renderer turns it into a pyrender
``DirectionalLight`` and the scene's ambient term (and jitters it per clip when the
``lighting_variation`` effect is on). The key direction is given in the camera's frame by
default (a light rig that moves with the camera, like a photographer's key light), so one
preset lights the cloth side facing the camera in every scene; ``frame="world"`` pins it to
the world instead. Intensities are pyrender's units (the directional
light's irradiance scales the PBR shader's Lambert term; ambient adds
``ambient_intensity * ambient_color * albedo``), with the shader's output gamma of 2.2.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from enum import StrEnum

import numpy as np

__all__ = ["LightFrame", "LightSpec"]


class LightFrame(StrEnum):
    """Coordinate frame of :attr:`LightSpec.direction`."""

    CAMERA = "camera"
    """Camera axes (OpenGL: x right, y up, z towards the viewer), unshaken base pose."""
    WORLD = "world"
    """World axes (z up)."""


def _vector3(name: str, value) -> tuple[float, float, float]:
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"LightSpec.{name} must be 3 finite numbers, got {value!r}") from None
    if array.shape != (3,) or not np.isfinite(array).all():
        raise ValueError(f"LightSpec.{name} must be 3 finite numbers, got {value!r}")
    return (float(array[0]), float(array[1]), float(array[2]))


@dataclasses.dataclass(frozen=True)
class LightSpec:
    """A directional key light and ambient light (defaults = :meth:`default`).

    The default key light comes from over the camera's left shoulder (above, left and
    behind the camera), so the cloth side the camera sees is lit whatever the scene.
    """

    direction: tuple[float, float, float] = (0.4, -0.6, -0.7)
    """Direction the key light travels in (from the light into the scene) in ``frame``
    coordinates, shape (3,); normalised on construction."""
    frame: LightFrame = LightFrame.CAMERA
    """Frame of ``direction``: ``camera`` or ``world``."""
    intensity: float = 3.0
    """Key light intensity (pyrender directional-light units)."""
    color: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """Key light colour, linear RGB in [0, 1], shape (3,)."""
    ambient_intensity: float = 0.35
    """Ambient light intensity (multiplies ``ambient_color``)."""
    ambient_color: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """Ambient colour, linear RGB in [0, 1], shape (3,)."""

    def __post_init__(self):
        try:
            object.__setattr__(self, "frame", LightFrame(self.frame))
        except ValueError:
            raise ValueError(
                f"LightSpec.frame must be one of {[f.value for f in LightFrame]}, "
                f"got {self.frame!r}"
            ) from None
        direction = np.asarray(_vector3("direction", self.direction))
        norm = float(np.linalg.norm(direction))
        if norm < 1e-9:
            raise ValueError(f"LightSpec.direction must be non-zero, got {self.direction}")
        object.__setattr__(self, "direction", tuple(float(d) for d in direction / norm))
        for name in ("color", "ambient_color"):
            value = _vector3(name, getattr(self, name))
            if min(value) < 0 or max(value) > 1:
                raise ValueError(f"LightSpec.{name} must lie in [0, 1], got {value}")
            object.__setattr__(self, name, value)
        for name in ("intensity", "ambient_intensity"):
            value = getattr(self, name)
            if (
                isinstance(value, bool)
                or not isinstance(value, numbers.Real)
                or not math.isfinite(value)
                or value < 0
            ):
                raise ValueError(f"LightSpec.{name} must be a finite number >= 0, got {value!r}")
            object.__setattr__(self, name, float(value))

    @classmethod
    def default(cls) -> LightSpec:
        """The default studio-like lighting (the field defaults)."""
        return cls()

    @property
    def ambient_rgb(self) -> tuple[float, float, float]:
        """Ambient light as pyrender expects it: ``ambient_intensity * ambient_color``."""
        return tuple(self.ambient_intensity * c for c in self.ambient_color)

    def world_direction(self, camera_pose: np.ndarray) -> np.ndarray:
        """Key light travel direction in world coordinates, shape (3,).

        Args:
            camera_pose: Camera-to-world transform (OpenGL axes), shape (4, 4); ignored
                for ``frame="world"``.
        """
        direction = np.asarray(self.direction)
        if self.frame is LightFrame.CAMERA:
            direction = np.asarray(camera_pose)[:3, :3] @ direction
        return direction / np.linalg.norm(direction)

    def pose(self, camera_pose: np.ndarray) -> np.ndarray:
        """Node pose of the key light (pyrender lights shine along their local -z), (4, 4).

        Args:
            camera_pose: Camera-to-world transform, shape (4, 4) (see :meth:`world_direction`).
        """
        back = -self.world_direction(camera_pose)
        helper = np.array([0.0, 0.0, 1.0]) if abs(back[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
        right = np.cross(helper, back)
        right /= np.linalg.norm(right)
        up = np.cross(back, right)
        pose = np.eye(4)
        pose[:3, 0], pose[:3, 1], pose[:3, 2] = right, up, back
        return pose

    def jittered(
        self, rng: np.random.Generator, *, direction_deg: float, intensity_rel: float
    ) -> LightSpec:
        """A randomly perturbed copy (the ``lighting_variation`` effect).

        Args:
            rng: Source of randomness (two draws for the direction, two for intensities).
            direction_deg: Largest angle [deg] between the new and the old key direction;
                the new direction is uniform on that spherical cap.
            intensity_rel: Key and ambient intensities are each scaled by a factor drawn
                uniformly in ``[1 - intensity_rel, 1 + intensity_rel]``.

        Returns:
            The perturbed light.
        """
        old = np.asarray(self.direction)
        cos_max = math.cos(math.radians(direction_deg))
        cos_t = 1.0 - rng.uniform() * (1.0 - cos_max)
        phi = rng.uniform(0.0, 2.0 * math.pi)
        helper = np.array([0.0, 0.0, 1.0]) if abs(old[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
        e1 = np.cross(old, helper)
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(old, e1)
        sin_t = math.sqrt(max(0.0, 1.0 - cos_t * cos_t))
        new = cos_t * old + sin_t * (math.cos(phi) * e1 + math.sin(phi) * e2)
        scale_key, scale_ambient = rng.uniform(1 - intensity_rel, 1 + intensity_rel, size=2)
        return dataclasses.replace(
            self,
            direction=tuple(new),
            intensity=self.intensity * float(scale_key),
            ambient_intensity=self.ambient_intensity * float(scale_ambient),
        )
