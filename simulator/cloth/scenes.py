"""The thesis's two motion scenes (section 7.4.3): wind-blown cloth and arm bending.

A scenario turns materials plus per-instance variations (seed, wind level) into
a :class:`SimModel`, an initial :class:`SimState` and a driver that produces the
:class:`SimControl` of every step. Both scenes first *settle* (gravity only, the
arm straight) for ``settle_time`` seconds and only then start the recorded
motion, so every clip starts from rest.

Coordinates: z up, metres. The wind scene hangs a square cloth in the x-z plane
(top edge at ``height``) and blows along +y, rotated by a per-instance yaw
jitter. The arm scene drapes a cloth over a horizontal two-capsule arm along x
with the elbow at the origin's x; the forearm then flexes upwards by
``bend_angle_deg`` in the x-z plane.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import torch

from simulator.cloth.effects import PhysicsEffects
from simulator.cloth.material import ClothMaterial
from simulator.cloth.model import ClothModelKind, build_cloth_model
from simulator.cloth.wind import WindField
from simulator.mesh import TriMesh
from simulator.model import SimControl, SimModel, SimState

__all__ = [
    "RESOLUTION_LEVELS",
    "ArmDriver",
    "ScenarioArmBend",
    "ScenarioWind",
    "WindDriver",
    "smoothstep",
]

RESOLUTION_LEVELS: dict[int, int] = {1: 16, 2: 24, 3: 32}
"""Uniform mesh resolution level (thesis Unif-1/2/3) -> vertices per side."""


def smoothstep(t: float) -> float:
    """C1 ramp from 0 (t <= 0) to 1 (t >= 1)."""
    t = min(max(t, 0.0), 1.0)
    return t * t * (3.0 - 2.0 * t)


def _smoothstep_rate(t: float) -> float:
    return 6.0 * t * (1.0 - t) if 0.0 < t < 1.0 else 0.0


def stroke_profile(phase: float, strokes: int) -> tuple[float, float]:
    """Flexion fraction and its rate (per unit phase) after ``phase`` strokes.

    Strokes alternate flexion (0 -> 1) and extension (1 -> 0), each a :func:`smoothstep`
    one phase unit long, so the profile is C1 and rests at both ends of every stroke.
    """
    if phase <= 0.0:
        return 0.0, 0.0
    if phase >= strokes:
        return float(strokes % 2), 0.0
    stroke = int(phase)
    local = phase - stroke
    flexing = stroke % 2 == 0
    value = smoothstep(local) if flexing else 1.0 - smoothstep(local)
    rate = _smoothstep_rate(local) * (1.0 if flexing else -1.0)
    return value, rate


def _check_level(level: int) -> int:
    if level not in RESOLUTION_LEVELS:
        raise ValueError(
            f"scenario.resolution_level must be one of {sorted(RESOLUTION_LEVELS)}, got {level!r}"
        )
    return RESOLUTION_LEVELS[level]


def _check_positive(name: str, value: float) -> None:
    if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be > 0, got {value!r}")


def _vary_density(material: ClothMaterial, seeds, effects: PhysicsEffects) -> ClothMaterial:
    """``material`` with each instance's density times its ``effects.density_factors``."""
    if not effects.density_variation:
        return material
    factors = material.density.new_tensor(effects.density_factors(seeds))
    return dataclasses.replace(material, density=material.density * factors)


def _out_of_plane_noise(seeds, verts: int, amplitude: float, normal) -> torch.Tensor:
    """Seeded smooth-ish perturbation along ``normal`` [m], shape (B, V, 3)."""
    rows = [np.random.default_rng([int(s), 3]).uniform(-1, 1, verts) for s in seeds]
    noise = torch.tensor(np.stack(rows)) * amplitude
    return noise[..., None] * torch.tensor(normal, dtype=torch.float64)


def _grid_in_plane(verts: int, size: float, origin, axis_u, axis_v, dtype) -> TriMesh:
    grid = TriMesh.grid(verts, size_u=size, dtype=dtype)
    u, v = grid.uv[:, :1].double(), grid.uv[:, 1:].double()
    pos = (
        torch.tensor(origin, dtype=torch.float64)
        + u * torch.tensor(axis_u, dtype=torch.float64)
        + v * torch.tensor(axis_v, dtype=torch.float64)
    )
    return TriMesh.from_arrays(pos.numpy(), grid.tri_indices.numpy(), grid.uv.numpy(), dtype=dtype)


@dataclasses.dataclass(frozen=True)
class WindDriver:
    """Controls of the wind scene: fixed pins and a wind that ramps in after settling."""

    pin_pos: torch.Tensor
    """[m], shape (B, P, 3)."""
    wind: WindField
    settle_time: float
    ramp_time: float

    def control(self, time: float, pos: torch.Tensor) -> SimControl:
        """Controls for the step ending at ``time`` [s]."""
        ramp = smoothstep((time - self.settle_time) / self.ramp_time)
        wind = self.wind.velocity(pos, time, ramp) if ramp > 0 else None
        return SimControl(pin_pos=self.pin_pos, wind_vel=wind)


WIND_POSES = ("corners", "clips", "edge")
"""How the wind scene's cloth hangs from its top edge."""


@dataclasses.dataclass(frozen=True)
class ScenarioWind:
    """Cloth hung from its top corners (or whole top edge) in constant-velocity wind."""

    resolution_level: int = 3
    size: float = dataclasses.field(default=0.5, metadata={"plausible": (0.3, 0.8)})
    """Side of the square cloth [m]. (``plausible`` metadata: the range of swatch sizes a
    user may have filmed; the sim-to-real diagnosis tries scene fields that carry it.)"""
    pose: str = dataclasses.field(default="corners", metadata={"choices": WIND_POSES})
    """``corners``: the two top corners pinned; ``clips``: the corners and the middle of the top
    edge (three clips on a rod); ``edge``: the whole top edge pinned."""
    wind_speeds: tuple[float, ...] = (0.75, 1.5, 2.5)
    """Wind strengths W1 < W2 < W3 [m/s]."""
    wind_yaw_jitter_deg: float = dataclasses.field(
        default=15.0, metadata={"plausible": (0.0, 45.0)}
    )
    """Per-instance uniform jitter of the wind direction around +y [deg]."""
    height: float = 1.0
    """Height of the top edge [m]."""
    settle_time: float = 1.0
    """Gravity-only settling before the wind starts [s]."""
    ramp_time: float = 0.25
    """Wind ramp-in duration [s]."""
    flatness_noise: float = 1e-3
    """Out-of-plane initial perturbation [m]: lets the cloth wrinkle out of plane, as real
    cloth does, instead of staying on an unstable planar equilibrium."""

    name = "wind"
    static_settle = True
    """Finish settling with a static solve (no contact or friction involved)."""

    def __post_init__(self):
        _check_level(self.resolution_level)
        _check_positive("scenario.size", self.size)
        _check_positive("scenario.ramp_time", self.ramp_time)
        if self.settle_time < 0:
            raise ValueError(f"scenario.settle_time must be >= 0, got {self.settle_time}")
        if self.pose not in WIND_POSES:
            raise ValueError(f"scenario.pose must be one of {WIND_POSES}, got {self.pose!r}")
        speeds = tuple(float(s) for s in self.wind_speeds)
        object.__setattr__(self, "wind_speeds", speeds)  # configs pass lists
        if not speeds or any(not s > 0 for s in speeds) or list(speeds) != sorted(speeds):
            raise ValueError(f"scenario.wind_speeds must be positive and increasing, got {speeds}")

    def mesh(self, dtype: torch.dtype = torch.float64) -> TriMesh:
        """Cloth hanging in the x-z plane, warp along x, weft downwards."""
        n = RESOLUTION_LEVELS[self.resolution_level]
        origin = (-self.size / 2, 0.0, self.height)
        return _grid_in_plane(n, self.size, origin, (1.0, 0.0, 0.0), (0.0, 0.0, -1.0), dtype)

    def pin_indices(self) -> torch.Tensor:
        """Top corners, three clips or the top edge (of the v = 0 row of the grid)."""
        n = RESOLUTION_LEVELS[self.resolution_level]
        if self.pose == "corners":
            return torch.tensor([0, n - 1])
        if self.pose == "clips":
            return torch.tensor([0, (n - 1) // 2, n - 1])
        return torch.arange(n)

    def build(
        self,
        material: ClothMaterial,
        *,
        seeds: list[int],
        wind_levels: list[int],
        effects: PhysicsEffects | None = None,
        kind: ClothModelKind | str = ClothModelKind.DISCRETE_SHELL,
        dtype: torch.dtype = torch.float64,
        device: torch.device | str = "cpu",
    ) -> tuple[SimModel, SimState, WindDriver]:
        """Model, rest state and driver for B instances (one seed and wind level each)."""
        effects = effects or PhysicsEffects()
        batch = material.batch_size
        if len(seeds) != batch or len(wind_levels) != batch:
            raise ValueError(
                f"seeds ({len(seeds)}) and wind_levels ({len(wind_levels)}) need one entry per "
                f"material instance ({batch})"
            )
        for level in wind_levels:
            if not 0 <= int(level) < len(self.wind_speeds):
                raise ValueError(
                    f"wind_level must be in [0, {len(self.wind_speeds) - 1}], got {level!r}"
                )
        mesh = self.mesh(dtype).to(device)
        pins = self.pin_indices().to(device)
        material = _vary_density(material, seeds, effects)
        model = build_cloth_model(mesh, material, pins, kind=kind, effects=effects)
        yaw = []
        for seed in seeds:
            rng = np.random.default_rng([int(seed), 1])
            yaw.append(math.radians(rng.uniform(-1, 1) * self.wind_yaw_jitter_deg))
        speed = torch.tensor([self.wind_speeds[int(w)] for w in wind_levels], dtype=dtype)
        yaw_t = torch.tensor(yaw, dtype=dtype)
        mean = torch.stack([speed * torch.sin(yaw_t), speed * torch.cos(yaw_t), 0 * speed], -1)
        mean = mean.to(device)
        if effects.gusty_wind:
            wind = WindField.gusty(
                mean,
                [int(s) for s in seeds],
                amplitude=effects.gust_amplitude,
                modes=effects.gust_modes,
            )
        else:
            wind = WindField(mean)
        pos = mesh.vert_pos[None].repeat(batch, 1, 1)
        noise = _out_of_plane_noise(seeds, mesh.vert_count, self.flatness_noise, (0.0, 1.0, 0.0))
        pos = pos + noise.to(pos)
        pos[:, pins] = mesh.vert_pos[pins]
        state = SimState(pos, torch.zeros_like(pos), torch.zeros(batch, dtype=dtype, device=device))
        driver = WindDriver(pos[:, pins].clone(), wind, self.settle_time, self.ramp_time)
        return model, state, driver


@dataclasses.dataclass(frozen=True)
class ArmDriver:
    """Controls of the arm scene: two capsules, the forearm rotating about the elbow."""

    shoulder: torch.Tensor
    """[m], shape (3,)."""
    elbow: torch.Tensor
    """[m], shape (3,)."""
    forearm_length: float
    upper_radius: float
    fore_radius: float
    bend_angle: torch.Tensor
    """Final elbow flexion per instance [rad], shape (B,)."""
    settle_time: float
    bend_time: float
    strokes: int = 1
    """Alternating flex / extend strokes (1 = flex once and hold)."""

    def _wrist(self, angle: torch.Tensor) -> torch.Tensor:
        direction = torch.stack([torch.cos(angle), 0 * angle, torch.sin(angle)], -1)
        return self.elbow + self.forearm_length * direction

    def control(self, time: float, pos: torch.Tensor) -> SimControl:
        """Capsules and their end-point velocities at ``time`` [s]."""
        fraction, fraction_rate = stroke_profile(
            (time - self.settle_time) / self.bend_time, self.strokes
        )
        angle = self.bend_angle * fraction
        rate = self.bend_angle * fraction_rate / self.bend_time
        batch = self.bend_angle.shape[0]
        wrist = self._wrist(angle)
        tangent = torch.stack([-torch.sin(angle), 0 * angle, torch.cos(angle)], -1)
        wrist_vel = self.forearm_length * rate[:, None] * tangent
        shoulder = self.shoulder.expand(batch, 3)
        elbow = self.elbow.expand(batch, 3)
        radius_u = torch.full((batch, 1), self.upper_radius).to(wrist)
        radius_f = torch.full((batch, 1), self.fore_radius).to(wrist)
        capsules = torch.stack(
            [torch.cat([shoulder, elbow, radius_u], -1), torch.cat([elbow, wrist, radius_f], -1)], 1
        )
        zeros = torch.zeros_like(wrist)
        vel = torch.stack([torch.cat([zeros, zeros], -1), torch.cat([zeros, wrist_vel], -1)], 1)
        return SimControl(pin_pos=pos.new_zeros(batch, 0, 3), capsules=capsules, capsule_vel=vel)


@dataclasses.dataclass(frozen=True)
class ScenarioArmBend:
    """Cloth draped over a capsule arm that bends at the elbow by a fixed angle."""

    resolution_level: int = 3
    size: float = 0.5
    """Side of the square cloth [m]."""
    arm_height: float = 1.0
    upper_arm_length: float = 0.30
    forearm_length: float = 0.28
    upper_radius: float = 0.045
    fore_radius: float = 0.04
    bend_angle_deg: float = 90.0
    bend_time: float = 1.0
    """Duration of the flexion (and of each later stroke) [s]."""
    strokes: int = 1
    """Strokes of the elbow, alternately flexing and extending (1 = flex once and hold).
    With one stroke the cloth comes to rest on the bent arm after bend_time, and later clips
    see little motion; more strokes keep every clip of a recording in motion."""
    drop_clearance: float = 0.01
    """Initial gap between cloth and arm top [m]."""
    offset_jitter: float = 0.03
    """Per-instance uniform jitter of the cloth's initial x/y placement [m]."""
    settle_time: float = 1.0
    friction: float = 0.5

    name = "arm"
    static_settle = False
    """Friction holds the drape, which a static solve would ignore: settle dynamically."""

    def __post_init__(self):
        _check_level(self.resolution_level)
        for name in (
            "size",
            "upper_arm_length",
            "forearm_length",
            "upper_radius",
            "fore_radius",
            "bend_time",
        ):
            _check_positive(f"scenario.{name}", getattr(self, name))
        if not 0 < self.bend_angle_deg <= 150:
            raise ValueError(
                f"scenario.bend_angle_deg must be in (0, 150], got {self.bend_angle_deg}"
            )
        if self.settle_time < 0:
            raise ValueError(f"scenario.settle_time must be >= 0, got {self.settle_time}")
        if isinstance(self.strokes, bool) or not isinstance(self.strokes, int) or self.strokes < 1:
            raise ValueError(f"scenario.strokes must be an integer >= 1, got {self.strokes!r}")

    def mesh(self, dtype: torch.dtype = torch.float64) -> TriMesh:
        """Horizontal cloth centred over the elbow, warp along x."""
        n = RESOLUTION_LEVELS[self.resolution_level]
        z = self.arm_height + self.upper_radius + self.drop_clearance
        origin = (-self.size / 2, -self.size / 2, z)
        return _grid_in_plane(n, self.size, origin, (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), dtype)

    def build(
        self,
        material: ClothMaterial,
        *,
        seeds: list[int],
        wind_levels: list[int] | None = None,
        effects: PhysicsEffects | None = None,
        kind: ClothModelKind | str = ClothModelKind.DISCRETE_SHELL,
        dtype: torch.dtype = torch.float64,
        device: torch.device | str = "cpu",
    ) -> tuple[SimModel, SimState, ArmDriver]:
        """Model, initial state and driver for B instances (``wind_levels`` is ignored)."""
        effects = effects or PhysicsEffects()
        batch = material.batch_size
        if len(seeds) != batch:
            raise ValueError(
                f"seeds ({len(seeds)}) needs one entry per material instance ({batch})"
            )
        mesh = self.mesh(dtype).to(device)
        model = build_cloth_model(
            mesh,
            _vary_density(material, seeds, effects),
            torch.zeros(0, dtype=torch.int64, device=device),
            kind=kind,
            effects=effects,
            capsule_contact=True,
            friction=self.friction,
        )
        offsets = []
        for seed in seeds:
            rng = np.random.default_rng([int(seed), 2])
            offsets.append([*rng.uniform(-1, 1, size=2) * self.offset_jitter, 0.0])
        offset = torch.tensor(offsets, dtype=dtype, device=device)
        pos = mesh.vert_pos[None] + offset[:, None, :]
        state = SimState(pos, torch.zeros_like(pos), torch.zeros(batch, dtype=dtype, device=device))
        elbow = torch.tensor([0.0, 0.0, self.arm_height], dtype=dtype, device=device)
        shoulder = elbow - torch.tensor(
            [self.upper_arm_length, 0.0, 0.0], dtype=dtype, device=device
        )
        angle = torch.full((batch,), math.radians(self.bend_angle_deg), dtype=dtype, device=device)
        driver = ArmDriver(
            shoulder,
            elbow,
            self.forearm_length,
            self.upper_radius,
            self.fore_radius,
            angle,
            self.settle_time,
            self.bend_time,
            self.strokes,
        )
        return model, state, driver
