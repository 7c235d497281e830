"""Pinhole camera: intrinsics K and world-to-camera pose, with projection and its Jacobian.

Conventions (OpenCV): the camera looks along its +z axis, image x to the right and y down;
``x_cam = R x_world + t`` and ``u = (K x_cam)[:2] / (K x_cam)[2]`` in pixels. The paper's
virtual camera is ``K = diag(500, 500, 1)``: focal 500 px, principal point at the origin.
"""

from __future__ import annotations

import dataclasses

import torch

__all__ = ["PinholeCamera", "look_at"]


@dataclasses.dataclass(frozen=True)
class PinholeCamera:
    """A fixed, calibrated pinhole camera (the paper's known projection matrix P)."""

    intrinsics: torch.Tensor
    """``K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` [px], shape (3, 3)."""
    rotation: torch.Tensor
    """World-to-camera rotation R, shape (3, 3)."""
    translation: torch.Tensor
    """World-to-camera translation t [m], shape (3,)."""

    def __post_init__(self):
        k, r, t = self.intrinsics, self.rotation, self.translation
        if tuple(k.shape) != (3, 3):
            raise ValueError(f"intrinsics must have shape (3, 3), got {tuple(k.shape)}")
        if tuple(r.shape) != (3, 3):
            raise ValueError(f"rotation must have shape (3, 3), got {tuple(r.shape)}")
        if tuple(t.shape) != (3,):
            raise ValueError(f"translation must have shape (3,), got {tuple(t.shape)}")
        if not bool(
            torch.isfinite(k).all() and torch.isfinite(r).all() and torch.isfinite(t).all()
        ):
            raise ValueError("intrinsics/rotation/translation must be finite")
        for name, value in (("fx", k[0, 0]), ("fy", k[1, 1])):
            if not float(value) > 0:
                raise ValueError(f"intrinsics focal {name} must be > 0 px, got {float(value)}")
        if float(k[0, 1]) != 0.0 or k[2].tolist() != [0.0, 0.0, 1.0] or float(k[1, 0]) != 0.0:
            raise ValueError("intrinsics must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (no skew)")
        eye = torch.eye(3, dtype=r.dtype, device=r.device)
        if not torch.allclose(r @ r.T, eye, atol=1e-6) or float(torch.linalg.det(r)) <= 0:
            raise ValueError("rotation must be a proper rotation matrix (R R^T = I, det R = 1)")

    @property
    def focal(self) -> float:
        """Mean focal length [px]."""
        return 0.5 * float(self.intrinsics[0, 0] + self.intrinsics[1, 1])

    def to_camera(self, points: torch.Tensor) -> torch.Tensor:
        """Camera-frame coordinates [m] of world points (..., 3)."""
        return points @ self.rotation.T.to(points) + self.translation.to(points)

    def project(self, points: torch.Tensor) -> torch.Tensor:
        """Pixel coordinates (..., 2) of world points (..., 3); depth must be positive."""
        pc = self.to_camera(points)
        k = self.intrinsics.to(points)
        z = pc[..., 2:3]
        return pc[..., :2] / z * torch.stack([k[0, 0], k[1, 1]]) + k[:2, 2]

    def project_jacobian(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Pixels (..., 2) and d pixels / d world point (..., 2, 3)."""
        pc = self.to_camera(points)
        k = self.intrinsics.to(points)
        fx, fy = k[0, 0], k[1, 1]
        x, y, z = pc.unbind(-1)
        inv_z = 1.0 / z
        zero = torch.zeros_like(z)
        d_cam = torch.stack(
            [
                torch.stack([fx * inv_z, zero, -fx * x * inv_z * inv_z], -1),
                torch.stack([zero, fy * inv_z, -fy * y * inv_z * inv_z], -1),
            ],
            dim=-2,
        )
        pix = torch.stack([fx * x * inv_z + k[0, 2], fy * y * inv_z + k[1, 2]], -1)
        return pix, d_cam @ self.rotation.to(points)


def look_at(
    eye: torch.Tensor,
    target: torch.Tensor,
    up: torch.Tensor,
    *,
    focal: float = 500.0,
    principal: tuple[float, float] = (0.0, 0.0),
) -> PinholeCamera:
    """Camera at ``eye`` [m] looking at ``target`` [m] with image up roughly along ``up``."""
    eye, target, up = (torch.as_tensor(v, dtype=torch.float64) for v in (eye, target, up))
    fwd = target - eye
    fwd = fwd / torch.linalg.vector_norm(fwd)
    right = torch.linalg.cross(fwd, up, dim=-1)
    right = right / torch.linalg.vector_norm(right)
    down = torch.linalg.cross(fwd, right, dim=-1)
    rot = torch.stack([right, down, fwd])
    k = torch.tensor(
        [[focal, 0.0, principal[0]], [0.0, focal, principal[1]], [0.0, 0.0, 1.0]],
        dtype=torch.float64,
    )
    return PinholeCamera(k, rot, -rot @ eye)
