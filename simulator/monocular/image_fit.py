"""Image-fitting energy (the paper eq. 18): springs from features to their tracked pixels.

``E_s = sum_i 1/2 k w_i |u_i - P(u_i*)|²`` with ``u_i* = sum_j b_ij x_j`` the feature's
barycentric point (eq. 17), ``P`` the pinhole projection and ``u_i`` the tracked pixel. The
paper takes ``k`` "of the order of the Young's modulus" without fixing units; we give ``k``
in N/m and convert the pixel residual to metres at the feature's rest depth,
``w_i = (z_i^0 / f)²``, so ``k`` is the stiffness of a spring that holds the feature on its
line of sight (independent of image resolution).

Newton uses the Gauss-Newton blocks ``k w_i b_ij b_il J_i^T J_i`` (PSD, exact at zero
residual); the exact Hessian-vector product comes from autograd.
"""

from __future__ import annotations

import dataclasses

import torch

from ..energies.base import ElementBlocks, Energy
from ..geometry import flat_indices, scatter_vertices
from .camera import PinholeCamera
from .features import FeatureSet

__all__ = ["EnergyImageFit"]


@dataclasses.dataclass(frozen=True)
class EnergyImageFit(Energy):
    """Eq. 18 for B instances sharing features and camera, each with its own tracks."""

    camera: PinholeCamera
    feature_verts: torch.Tensor
    """Vertex ids of each feature's triangle, int64, shape (N, 3)."""
    bary: torch.Tensor
    """Barycentric coordinates, shape (N, 3)."""
    weight: torch.Tensor
    """``k w_i`` [N/m / px²·m²] = [J/px²], shape (N,)."""
    targets: torch.Tensor
    """Tracked pixel positions u_i [px], shape (B, N, 2)."""
    visible: torch.Tensor | None = None
    """1 where the feature is tracked in this frame, 0 otherwise, shape (B, N); None = all."""

    @staticmethod
    def build(
        mesh,
        features: FeatureSet,
        camera: PinholeCamera,
        targets: torch.Tensor,
        *,
        stiffness: float,
        rest_pos: torch.Tensor | None = None,
    ) -> EnergyImageFit:
        """Energy for features on ``mesh`` seen by ``camera``.

        Args:
            mesh: the reconstruction mesh.
            features: anchored features (at least one).
            camera: the calibrated camera.
            targets: tracked pixels [px], shape (B, N, 2) or (N, 2).
            stiffness: k [N/m], > 0.
            rest_pos: rest placement [m] (V, 3) for the depth weights; default ``mesh.vert_pos``.
        """
        if not stiffness > 0:
            raise ValueError(f"stiffness (k) must be > 0 N/m, got {stiffness}")
        if features.count == 0:
            raise ValueError("features: the feature set is empty")
        targets = torch.as_tensor(targets, dtype=mesh.vert_pos.dtype)
        if targets.dim() == 2:
            targets = targets[None]
        if targets.dim() != 3 or tuple(targets.shape[1:]) != (features.count, 2):
            raise ValueError(
                f"targets must have shape (B, N, 2) with N = {features.count}, "
                f"got {tuple(targets.shape)}"
            )
        rest = mesh.vert_pos if rest_pos is None else rest_pos
        pts = features.points(mesh, rest[None])[0]
        depth = camera.to_camera(pts)[:, 2]
        if bool((depth <= 0).any()):
            raise ValueError("features: some features lie behind the camera (depth <= 0)")
        weight = stiffness * (depth / camera.focal) ** 2
        return EnergyImageFit(
            camera, features.vertices(mesh), features.bary.to(rest), weight, targets
        )

    def with_targets(self, targets: torch.Tensor, visible: torch.Tensor | None = None):
        """Same features with new tracks (B, N, 2) and visibility (B, N) for another frame."""
        return dataclasses.replace(self, targets=targets, visible=visible)

    def _weights(self, batch: int) -> torch.Tensor:
        w = self.weight[None].expand(batch, -1)
        return w if self.visible is None else w * self.visible

    def _points(self, pos):
        return (pos[:, self.feature_verts] * self.bary[None, :, :, None]).sum(2)

    def residual(self, pos: torch.Tensor) -> torch.Tensor:
        """Projected minus tracked pixels [px], shape (B, N, 2)."""
        return self.camera.project(self._points(pos)) - self.targets

    def energy(self, model, pos):
        """Image energy [J], shape (B,)."""
        r = self.residual(pos)
        return 0.5 * (self._weights(pos.shape[0]) * (r * r).sum(-1)).sum(-1)

    def gradient(self, model, pos):
        """Analytic dE/dx [N], shape (B, V, 3)."""
        pix, jac = self.camera.project_jacobian(self._points(pos))
        r = (pix - self.targets) * self._weights(pos.shape[0])[..., None]
        g_point = (jac * r[..., None]).sum(-2)  # (B, N, 3)
        per_vert = self.bary[None, :, :, None] * g_point[:, :, None, :]
        return scatter_vertices(per_vert, self.feature_verts, pos.shape[1])

    def hessian_blocks(self, model, pos):
        """Gauss-Newton blocks, shape (B*N, 3, 3, 3, 3)."""
        _, jac = self.camera.project_jacobian(self._points(pos))
        jtj = jac.transpose(-1, -2) @ jac * self._weights(pos.shape[0])[..., None, None]
        bb = self.bary[:, :, None] * self.bary[:, None, :]  # (N, 3, 3)
        blocks = bb[None, :, :, :, None, None] * jtj[:, :, None, None]
        return ElementBlocks(
            flat_indices(self.feature_verts, pos.shape[0], pos.shape[1]),
            blocks.reshape(-1, 3, 3, 3, 3),
            self.feature_verts,
        )
