"""Coulomb friction against the capsule obstacles, lagged and smoothed.

The normal force ``lambda_i`` of each vertex (from the penalty contact at the start
of the step) and the tangent plane are frozen over the step; the friction is the
velocity-dependent force ``f = -mu lambda / max(|v_t|, eps_v) P_t (v - v_obstacle)``,
an implicit, smoothed Coulomb law (sticking below ``eps_v``, sliding with magnitude
``mu lambda`` above), as in IPC's lagged friction.
"""

from __future__ import annotations

import dataclasses

import torch

from ..energies.contact import EnergyContactCapsule, capsule_penetration
from .base import Force, StepForce

__all__ = ["FrictionCapsule"]


@dataclasses.dataclass(frozen=True)
class FrictionCapsule(Force):
    """Friction between cloth and capsules."""

    mu: float = 0.5
    """Coulomb friction coefficient."""
    slip_speed: float = 1e-2
    """Speed [m/s] below which contact sticks (smoothing of the Coulomb cone)."""

    def linearize(self, model, state, control, energies):
        """Per-vertex tangential damping from the lagged normal force."""
        contact = next((e for e in energies if isinstance(e, EnergyContactCapsule)), None)
        if contact is None or control.capsules is None:
            return StepForce()
        depth, normal = capsule_penetration(state.pos, control.capsules, contact.thickness)
        lam = contact.normal_force(model, state.pos)  # (B, V, C)
        end_vel = (
            control.capsule_vel
            if control.capsule_vel is not None
            else torch.zeros_like(control.capsules[..., :6])
        )
        obstacle_vel = _capsule_point_velocity(state.pos, control.capsules, end_vel)
        rel = state.vel[:, :, None, :] - obstacle_vel
        eye = torch.eye(3, dtype=state.pos.dtype, device=state.pos.device)
        proj = eye - normal[..., :, None] * normal[..., None, :]
        v_t = torch.linalg.vector_norm((proj @ rel[..., None])[..., 0], dim=-1)
        coeff = self.mu * lam / v_t.clamp_min(self.slip_speed) * (depth > 0)
        damping = (coeff[..., None, None] * proj).sum(dim=2)
        weight = coeff.sum(dim=2, keepdim=True).clamp_min(1e-30)
        v_ref = (coeff[..., None] * obstacle_vel).sum(dim=2) / weight
        return StepForce(damping_vertex=damping, v_ref=v_ref)


def _capsule_point_velocity(pos, capsules, end_vel):
    """Velocity [m/s] of the capsule axis point nearest each vertex, shape (B, V, C, 3)."""
    p0 = capsules[:, None, :, 0:3]
    axis = capsules[:, None, :, 3:6] - p0
    rel = pos[:, :, None, :] - p0
    t = ((rel * axis).sum(-1) / (axis * axis).sum(-1).clamp_min(1e-12)).clamp(0.0, 1.0)[..., None]
    return end_vel[:, None, :, 0:3] * (1 - t) + end_vel[:, None, :, 3:6] * t
