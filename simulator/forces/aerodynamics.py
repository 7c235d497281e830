"""Air: still-air damping, aerodynamic drag and lift on the cloth surface.

All three use the per-vertex area vector ``a_i`` (a third of each adjacent
triangle's area times its normal) and the air velocity ``w_i`` of the control
(zero when there is no wind), with relative velocity ``u_i = v_i - w_i``.

* Drag (normal pressure drag): ``f_i = -1/2 rho C_d |a_i| |u_n| u_n n_i`` with
  ``u_n = u_i . n_i``. It is linearised with the magnitude ``|u_n|`` lagged from the
  start of the step, ``D_i = 1/2 rho C_d |a_i| |u_n| n_i n_i^T``, so it is implicit in
  the velocity and cannot overshoot. With ``isotropy`` s > 0 (switch ``isotropic_drag``) a
  share s of it is blind to the cloth's orientation, ``f_i = -1/2 rho C_d |a_i| |u| u``
  (the point-body fluid model of engines such as MuJoCo; crumpled fabric and skin friction
  keep a drag edge-on), ``D_i = 1/2 rho C_d |a_i| ((1 - s) |u_n| n_i n_i^T + s |u| I)``.
* Lift (switch ``aero_lift``): ``f_i = 1/2 rho C_l |a_i| |u| (u . n_i) l_i``, with ``l_i``
  the unit vector perpendicular to ``u`` in the plane of ``u`` and ``n_i`` (thin
  flat-plate lift), explicit.
* Air damping (switch ``air_damping``): isotropic linear drag
  ``f_i = -c |a_i| u_i`` [c in kg/(m²·s)], a cheap stand-in for skin friction and
  the dissipation of the surrounding air.
"""

from __future__ import annotations

import dataclasses

import torch

from ..geometry import vertex_area_normals
from .base import Force, StepForce

__all__ = ["AERO_MIN_SPEED", "AerodynamicDrag", "AerodynamicLift", "AirDamping"]

AERO_MIN_SPEED = 1e-3
"""Floor on the lagged normal speed [m/s] so drag never vanishes from the implicit system."""


def _area_normals(model, state):
    a = vertex_area_normals(state.pos, model.mesh.tri_indices)
    area = torch.linalg.vector_norm(a, dim=-1, keepdim=True)
    return area, a / area.clamp_min(1e-15)


def _relative_velocity(state, control):
    return state.vel if control.wind_vel is None else state.vel - control.wind_vel


@dataclasses.dataclass(frozen=True)
class AerodynamicDrag(Force):
    """Normal pressure drag of the cloth surface in (possibly moving) air."""

    drag_coefficient: float = 1.0
    air_density: float = 1.2
    """[kg/m³]."""
    isotropy: float = 0.0
    """Share of the drag along the relative air velocity whatever the cloth's orientation."""

    def __post_init__(self):
        if not 0.0 <= self.isotropy <= 1.0:
            raise ValueError(f"drag isotropy must be in [0, 1], got {self.isotropy!r}")

    def linearize(self, model, state, control, energies):
        """Lagged-magnitude drag, implicit in velocity."""
        area, normal = _area_normals(model, state)
        u = _relative_velocity(state, control)
        u_n = (u * normal).sum(-1, keepdim=True)
        scale = 0.5 * self.air_density * self.drag_coefficient * area
        coeff = scale * u_n.abs().clamp_min(AERO_MIN_SPEED)
        damping = coeff[..., None] * normal[..., :, None] * normal[..., None, :]
        if self.isotropy > 0.0:
            speed = torch.linalg.vector_norm(u, dim=-1, keepdim=True).clamp_min(AERO_MIN_SPEED)
            eye = torch.eye(3, dtype=u.dtype, device=u.device)
            isotropic = (scale * speed)[..., None] * eye
            damping = (1.0 - self.isotropy) * damping + self.isotropy * isotropic
        return StepForce(damping_vertex=damping, v_ref=control.wind_vel)


@dataclasses.dataclass(frozen=True)
class AerodynamicLift(Force):
    """Thin-plate lift perpendicular to the relative air flow (explicit)."""

    lift_coefficient: float = 0.5
    air_density: float = 1.2
    """[kg/m³]."""

    def linearize(self, model, state, control, energies):
        """Explicit lift from the start-of-step velocity."""
        area, normal = _area_normals(model, state)
        u = _relative_velocity(state, control)
        speed = torch.linalg.vector_norm(u, dim=-1, keepdim=True)
        u_hat = u / speed.clamp_min(1e-12)
        cos = (u_hat * normal).sum(-1, keepdim=True)
        lift_dir = normal - cos * u_hat  # in the (u, n) plane, perpendicular to u
        lift_len = torch.linalg.vector_norm(lift_dir, dim=-1, keepdim=True)
        lift_dir = lift_dir / lift_len.clamp_min(1e-12)
        # Lift pushes towards -n when air hits the front face (u . n < 0 means flow into +n side).
        force = (
            -0.5 * self.air_density * self.lift_coefficient * area * speed * speed * cos * lift_dir
        )
        return StepForce(f_const=torch.where(lift_len > 1e-9, force, 0.0))


@dataclasses.dataclass(frozen=True)
class AirDamping(Force):
    """Isotropic linear drag relative to the local air velocity."""

    coefficient: float = 0.02
    """Damping per unit area [kg/(m²·s)]."""

    def linearize(self, model, state, control, energies):
        """Per-vertex ``c |a_i| I``."""
        area, _ = _area_normals(model, state)
        eye = torch.eye(3, dtype=state.pos.dtype, device=state.pos.device)
        damping = (self.coefficient * area)[..., None] * eye
        return StepForce(damping_vertex=damping, v_ref=control.wind_vel)
