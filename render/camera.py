"""Pinhole camera description for the offscreen renderer, with one framing preset per scene.

:class:`CameraSpec` is a frozen, validated value (world coordinates in metres, z up) that
the renderer turns into a pyrender camera; it also projects points itself (numpy only), which
the presets' framing tests use. Default resolution: **112 x 112** (``DEFAULT_RESOLUTION``).
Why: it is the native input size of torchvision's video ResNets (R3D-18 and relatives are
trained on 112 x 112 clips), so clips need no resizing at train time; it costs 0.77x the
pixels of 128 x 128 and 0.25x those of 224 x 224 in storage and in every convolution of CPU
training (rendering itself is dominated by fixed per-frame costs: 112 vs 128 px changes it
by under 10 %); and wrinkles stay resolved: the presets show the 0.5 m cloth 50-65 px wide,
so one cell of the finest (32 x 32-vertex) mesh covers 1.6-2.1 px and the shortest wrinkle
that mesh can hold (a two-cell wavelength, 3.2 cm) spans 3.2-4.2 px, above the 2 px Nyquist
limit. Larger sizes add texture detail, but no geometric detail the simulation has.
"""

from __future__ import annotations

import dataclasses
import math
import numbers

import numpy as np

__all__ = ["DEFAULT_RESOLUTION", "CameraSpec"]

DEFAULT_RESOLUTION = 112
"""Default image width and height [px] (see the module docstring)."""


def _vector3(name: str, value) -> tuple[float, float, float]:
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"CameraSpec.{name} must be 3 finite numbers, got {value!r}") from None
    if array.shape != (3,) or not np.isfinite(array).all():
        raise ValueError(f"CameraSpec.{name} must be 3 finite numbers, got {value!r}")
    return (float(array[0]), float(array[1]), float(array[2]))


def _positive_int(name: str, value) -> int:
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value <= 0:
        raise ValueError(f"CameraSpec.{name} must be a positive integer [px], got {value!r}")
    return int(value)


def _finite(name: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(value):
        raise ValueError(f"CameraSpec.{name} must be a finite number, got {value!r}")
    return float(value)


@dataclasses.dataclass(frozen=True)
class CameraSpec:
    """A perspective camera looking from ``position`` at ``look_at``.

    Image axes: x to the right, y down, pixel (0, 0) at the top-left corner. The camera
    frame follows OpenGL (it looks along its -z axis with +y up), as pyrender does.
    """

    position: tuple[float, float, float] = (0.0, -1.5, 1.0)
    """Optical centre in world coordinates [m], shape (3,)."""
    look_at: tuple[float, float, float] = (0.0, 0.0, 1.0)
    """Point the optical axis passes through [m], shape (3,)."""
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    """World direction that appears upwards in the image, shape (3,); need not be unit."""
    yfov_deg: float = 40.0
    """Vertical field of view [deg], in (0, 180)."""
    width: int = DEFAULT_RESOLUTION
    """Image width [px]."""
    height: int = DEFAULT_RESOLUTION
    """Image height [px]."""
    znear: float = 0.05
    """Near clipping distance [m]."""
    zfar: float = 20.0
    """Far clipping distance [m]."""

    def __post_init__(self):
        # Coerce as well as check: Hydra configs pass lists and ints as floats' neighbours.
        for name in ("position", "look_at", "up"):
            object.__setattr__(self, name, _vector3(name, getattr(self, name)))
        for name in ("width", "height"):
            object.__setattr__(self, name, _positive_int(name, getattr(self, name)))
        for name in ("yfov_deg", "znear", "zfar"):
            object.__setattr__(self, name, _finite(name, getattr(self, name)))
        if not 0.0 < self.yfov_deg < 180.0:
            raise ValueError(f"CameraSpec.yfov_deg must be in (0, 180), got {self.yfov_deg}")
        if not self.znear > 0:
            raise ValueError(f"CameraSpec.znear must be > 0 m, got {self.znear}")
        if not self.zfar > self.znear:
            raise ValueError(f"CameraSpec.zfar must be > znear ({self.znear} m), got {self.zfar}")
        forward = np.subtract(self.look_at, self.position)
        if np.linalg.norm(forward) < 1e-9:
            raise ValueError(
                f"CameraSpec.look_at must differ from position, both are {self.position}"
            )
        up = np.asarray(self.up)
        cross = np.linalg.norm(np.cross(forward, up))
        if cross < 1e-6 * np.linalg.norm(forward) * max(np.linalg.norm(up), 1e-300):
            raise ValueError(
                f"CameraSpec.up must not be parallel to the viewing direction "
                f"(look_at - position = {tuple(forward)}), got {self.up}"
            )

    @property
    def aspect(self) -> float:
        """Width / height."""
        return self.width / self.height

    def resized(self, width: int, height: int) -> CameraSpec:
        """The same view at another image size [px]."""
        return dataclasses.replace(self, width=width, height=height)

    def pose(self) -> np.ndarray:
        """Camera-to-world transform, float64, shape (4, 4) (OpenGL camera axes)."""
        forward = np.subtract(self.look_at, self.position)
        forward /= np.linalg.norm(forward)
        right = np.cross(forward, self.up)
        right /= np.linalg.norm(right)
        true_up = np.cross(right, forward)
        pose = np.eye(4)
        pose[:3, 0], pose[:3, 1], pose[:3, 2] = right, true_up, -forward
        pose[:3, 3] = self.position
        return pose

    def project(
        self, points: np.ndarray, pose: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates and depth of world points.

        Args:
            points: World points [m], shape (N, 3).
            pose: Camera-to-world transform overriding :meth:`pose`, shape (4, 4).

        Returns:
            ``(pixels, depth)``: pixel coordinates (x right, y down, continuous, pixel
            centres at half-integers) [px], shape (N, 2); distance along the optical axis [m],
            shape (N,), positive in front of the camera.
        """
        pose = self.pose() if pose is None else pose
        world_to_cam = np.linalg.inv(pose)
        homog = np.concatenate([np.asarray(points, np.float64), np.ones((len(points), 1))], 1)
        cam = homog @ world_to_cam.T
        depth = -cam[:, 2]
        focal = 0.5 * self.height / math.tan(math.radians(self.yfov_deg) / 2)
        with np.errstate(divide="ignore", invalid="ignore"):
            x = 0.5 * self.width + focal * cam[:, 0] / depth
            y = 0.5 * self.height - focal * cam[:, 1] / depth
        return np.stack([x, y], -1), depth

    @classmethod
    def wind(cls, width: int = DEFAULT_RESOLUTION, height: int = DEFAULT_RESOLUTION) -> CameraSpec:
        """Framing of the wind scene (``ScenarioWind`` defaults: 0.5 m cloth, top edge z = 1).

        The camera stands downwind (+y) and 40 degrees above the cloth, 10 degrees off its
        centre line. From there the cloth is never seen edge-on while the wind lifts it from
        hanging (normal along y) to horizontal (normal along z): the cosine between the
        visible face's normal and the view stays >= 0.6, whereas from any upwind viewpoint
        above the cloth some lift angle is exactly edge-on. The frame holds the whole motion
        range: hanging to horizontal towards +y, with the scene's +-15 degree wind-yaw jitter.
        """
        return cls(
            position=(0.22, 1.66, 2.06),
            look_at=(-0.04, 0.20, 0.81),
            up=(0.0, 0.0, 1.0),
            yfov_deg=30.0,
            width=width,
            height=height,
        )

    @classmethod
    def arm(cls, width: int = DEFAULT_RESOLUTION, height: int = DEFAULT_RESOLUTION) -> CameraSpec:
        """Framing of the arm scene (``ScenarioArmBend`` defaults: arm along x at z = 1).

        The camera looks across the arm (from -y, i.e. perpendicular to the plane the forearm
        flexes in) from 20 degrees above, so the drape on both sides of the arm and the
        forearm's full 90-degree flexion stay in view.
        """
        return cls(
            position=(-0.06, -1.15, 1.45),
            look_at=(-0.06, 0.0, 1.0),
            up=(0.0, 0.0, 1.0),
            yfov_deg=40.0,
            width=width,
            height=height,
        )
