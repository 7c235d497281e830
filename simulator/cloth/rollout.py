"""Run a scenario: settle, then record frames at a fixed rate, with divergence checks."""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Callable

import numpy as np
import torch

from common.errors import InputError
from simulator.cloth.effects import PhysicsEffects
from simulator.cloth.material import ClothMaterial
from simulator.forces import AirDamping
from simulator.integrators import IntegratorBackwardEuler, SimulationDiverged, solve_static
from simulator.kernels import BACKENDS, resolve_backend
from simulator.sequence import MeshSequence
from simulator.solvers.newton import NewtonSettings

__all__ = [
    "RECORDING_BYTES_PER_COORD",
    "SimSettings",
    "check_recording_memory",
    "replay_capsules",
    "simulate",
    "with_capsules",
]

RECORDING_BYTES_PER_COORD = 12
"""Memory of a recorded vertex coordinate [bytes]: float64 while simulating, float32 after."""


def check_recording_memory(
    record_time: float, fps: float, instances: int, verts: int, *, field: str = "record_time"
) -> int:
    """Refuse a recording whose frames would take more than half of this machine's memory.

    A rollout keeps every recorded frame in memory; ``record_time=1e7`` would otherwise be
    accepted and fail hours later. Returns the frame count.
    """
    frames = round(record_time * fps) + 1
    need = frames * instances * verts * 3 * RECORDING_BYTES_PER_COORD
    total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    if need > total / 2:
        most = (total / 2 / (instances * verts * 3 * RECORDING_BYTES_PER_COORD) - 1) / fps
        raise InputError(
            f"{field} must be at most {most:.0f} s here: {record_time:g} s at {fps:g} "
            f"frames/s keeps {frames} frames of {instances} x {verts} vertices in memory "
            f"({need / 2**30:.1f} GiB, more than half of this machine's {total / 2**30:.0f} GiB)"
        )
    return frames


@dataclasses.dataclass(frozen=True)
class SimSettings:
    """Time stepping and solver settings of a rollout."""

    max_dt: float = 0.005
    """Largest time step [s]; the actual step divides the frame interval evenly."""
    newton: NewtonSettings = dataclasses.field(default_factory=NewtonSettings)
    max_speed: float = 50.0
    """Velocities beyond this [m/s] count as divergence."""
    settle_damping: float = 2.0
    """Extra air damping during settling only [kg/(m²·s)]; brings the cloth to rest."""
    settle_max_dt: float | None = None
    """Largest step while settling [s] (``None``: ``max_dt``). Settling is heavily damped and,
    in scenes with a static solve, only has to come near the rest state, so it can take
    larger steps than the recorded motion."""
    cloth_model: str = "discrete_shell"
    backend: str = "auto"
    """``auto`` (compiled kernels on CPU, torch on CUDA), ``torch`` or ``kernels``
    (:mod:`simulator.kernels`); overrides ``newton.backend``."""
    dtype: str = "float64"
    device: str = "auto"
    """``auto`` picks CUDA when present."""

    def __post_init__(self):
        if not self.max_dt > 0:
            raise ValueError(f"sim.max_dt must be > 0 s, got {self.max_dt}")
        if not self.settle_damping >= 0:
            raise ValueError(f"sim.settle_damping must be >= 0, got {self.settle_damping}")
        if self.settle_max_dt is not None and not self.settle_max_dt > 0:
            raise ValueError(f"sim.settle_max_dt must be > 0 s or null, got {self.settle_max_dt}")
        if not self.max_speed > 0:
            raise ValueError(f"sim.max_speed must be > 0 m/s, got {self.max_speed}")
        if self.backend not in BACKENDS:
            raise ValueError(f"sim.backend must be one of {list(BACKENDS)}, got {self.backend!r}")
        if self.dtype not in ("float32", "float64"):
            raise ValueError(f"sim.dtype must be 'float32' or 'float64', got {self.dtype!r}")

    def torch_dtype(self) -> torch.dtype:
        """The float dtype."""
        return getattr(torch, self.dtype)

    def resolved_newton(self) -> NewtonSettings:
        """The Newton settings with ``backend`` resolved for the device."""
        backend = resolve_backend(self.backend, self.torch_device())
        return dataclasses.replace(self.newton, backend=backend)

    def torch_device(self) -> torch.device:
        """The device, resolving ``auto``."""
        if self.device == "auto":
            return torch.device("cuda" if torch.cuda.is_available() else "cpu")
        return torch.device(self.device)


_SETTLE_POLISH = NewtonSettings(max_iters=30, tol_dx=1e-7, cg_rtol=1e-5, cg_max_iters=1000)
"""Static solve that finishes settling (scenes with ``static_settle``): exact rest."""


def _substeps(fps: float, max_dt: float) -> int:
    return max(1, math.ceil(1.0 / (fps * max_dt) - 1e-9))


def simulate(
    scenario,
    material: ClothMaterial,
    *,
    seeds: list[int],
    wind_levels: list[int] | None = None,
    fps: float = 30.0,
    record_time: float = 2.0,
    effects: PhysicsEffects | None = None,
    settings: SimSettings | None = None,
    labels: list[int] | None = None,
    progress: bool = False,
    on_step: Callable[[int, int], None] | None = None,
) -> MeshSequence:
    """Simulate B instances and return the recorded frames.

    Settling runs ``scenario.settle_time`` seconds of damped dynamics (extra air
    damping ``settings.settle_damping``); scenes with ``static_settle`` then
    solve for static equilibrium so recording starts exactly at rest. The first
    recorded frame is that rest state; then one frame every ``1 / fps`` seconds
    for ``record_time`` seconds.

    ``progress`` shows a progress bar over the steps; ``on_step(step, total)`` is called
    after every step instead, for callers that report progress themselves (dataset workers).

    Raises:
        SimulationDiverged: on NaN/inf or a speed above ``settings.max_speed``,
            naming the instance and step; nothing is returned or written.
    """
    settings = settings or SimSettings()
    effects = effects or PhysicsEffects()
    if not fps > 0:
        raise ValueError(f"fps must be > 0, got {fps}")
    if not record_time > 0:
        raise ValueError(f"record_time must be > 0 s, got {record_time}")
    dtype, device = settings.torch_dtype(), settings.torch_device()
    batch = material.batch_size
    wind_levels = list(wind_levels) if wind_levels is not None else [0] * batch
    model, state, driver = scenario.build(
        material,
        seeds=list(seeds),
        wind_levels=wind_levels,
        effects=effects,
        kind=settings.cloth_model,
        dtype=dtype,
        device=device,
    )
    substeps = _substeps(fps, settings.max_dt)
    dt = 1.0 / (fps * substeps)
    settle_dt_max = settings.settle_max_dt or settings.max_dt
    settle_steps = math.ceil(scenario.settle_time / settle_dt_max - 1e-9)
    settle_dt = scenario.settle_time / settle_steps if settle_steps else dt
    frame_count = round(record_time * fps) + 1
    total = settle_steps + (frame_count - 1) * substeps
    newton = settings.resolved_newton()
    integrator = IntegratorBackwardEuler(newton)
    settle_model = dataclasses.replace(
        model, forces=(*model.forces, AirDamping(coefficient=settings.settle_damping))
    )
    frames = [] if settle_steps else [state.pos.float().cpu()]
    capsules = [] if settle_steps else [driver.control(0.0, state.pos).capsules]
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=total, desc=f"simulate {scenario.name} x{batch}", unit="step")
    newton_iters = torch.zeros(batch, dtype=torch.int64, device=device)
    cg_iters = torch.zeros_like(newton_iters)
    for step in range(1, total + 1):
        settling = step <= settle_steps
        if settling:
            time, step_dt = step * settle_dt, settle_dt
        else:
            time, step_dt = scenario.settle_time + (step - settle_steps) * dt, dt
        control = driver.control(time, state.pos)
        state, stats = integrator.step(settle_model if settling else model, state, control, step_dt)
        newton_iters += stats.newton_iters
        cg_iters += stats.cg_iters
        _check_finite(state, settings.max_speed, step, time)
        if step == settle_steps and scenario.static_settle:
            state = _static_polish(model, state, control, newton.backend)
        if step >= settle_steps and (step - settle_steps) % substeps == 0:
            frames.append(state.pos.float().cpu())
            capsules.append(control.capsules)
        if bar is not None:
            bar.update(1)
        if on_step is not None:
            on_step(step, total)
    if bar is not None:
        bar.close()
    pos = torch.stack(frames, dim=1)  # (B, K, V, 3)
    mesh = model.mesh
    meta = {
        "scene": scenario.name,
        "scenario": dataclasses.asdict(scenario),
        "effects": dataclasses.asdict(effects),
        "sim": {
            "dt": dt,
            "substeps": substeps,
            "settle_dt": settle_dt,
            "max_dt": settings.max_dt,
            "cloth_model": settings.cloth_model,
            "dtype": settings.dtype,
            "newton": dataclasses.asdict(newton),
        },
        "fps": fps,
        "record_start_time": scenario.settle_time,
        "settle_time": scenario.settle_time,
        "mean_newton_iters_per_step": (newton_iters.double() / total).tolist(),
        "mean_cg_iters_per_step": (cg_iters.double() / total).tolist(),
    }
    return MeshSequence(
        pos=pos.numpy(),
        tri_indices=mesh.tri_indices.cpu().numpy(),
        uv=mesh.uv.float().cpu().numpy(),
        fps=float(fps),
        seeds=[int(s) for s in seeds],
        labels=[int(x) for x in labels] if labels is not None else [-1] * batch,
        wind_levels=[int(w) for w in wind_levels],
        meta=meta,
        capsules=_stack_capsules(capsules),
    )


def _stack_capsules(frames: list) -> np.ndarray | None:
    """Per-frame (B, C, 7) capsule tensors -> float32 (B, K, C, 7); ``None`` without any."""
    if not frames or frames[0] is None or frames[0].shape[1] == 0:
        return None
    return torch.stack([c.float().cpu() for c in frames], dim=1).numpy()


def replay_capsules(seq: MeshSequence) -> np.ndarray | None:
    """The arm's capsules at each recorded frame, replayed from the scene's own driver.

    For sequences written before :func:`simulate` recorded them. Frame k is recorded at
    ``record_start_time + k * substeps * dt``; float32, shape (B, K, C, 7); ``None`` for
    scenes without an arm.
    """
    if seq.meta.get("scene") != "arm":
        return None
    from simulator.cloth.scenes import ScenarioArmBend

    scenario = ScenarioArmBend(**seq.meta["scenario"])
    batch = seq.pos.shape[0]
    material = ClothMaterial.from_classes([0] * batch)
    _, state, driver = scenario.build(material, seeds=list(range(batch)))
    sim = seq.meta["sim"]
    dt, substeps = float(sim["dt"]), int(sim["substeps"])
    start = seq.meta.get("record_start_time")
    if start is None:  # sequences written before record_start_time existed
        start = round(float(seq.meta["settle_time"]) / dt) * dt
    frames = [
        driver.control(float(start) + k * substeps * dt, state.pos).capsules
        for k in range(seq.frame_count)
    ]
    return _stack_capsules(frames)


def with_capsules(seq: MeshSequence) -> MeshSequence:
    """``seq`` with its obstacles filled in when it was written without them (older files)."""
    if seq.capsules is not None or seq.meta.get("scene") != "arm":
        return seq
    return dataclasses.replace(seq, capsules=replay_capsules(seq))


def _static_polish(model, state, control, backend: str):
    """Finish settling with a float64 static solve (float32 cannot reach its tolerance)."""
    f64 = torch.float64
    settings = dataclasses.replace(_SETTLE_POLISH, backend=backend)
    rest, _ = solve_static(
        model.to(dtype=f64), state.to(dtype=f64), control.to(dtype=f64), settings=settings
    )
    return rest.to(dtype=state.pos.dtype)


def _check_finite(state, max_speed: float, step: int, time: float) -> None:
    speed = torch.linalg.vector_norm(state.vel, dim=-1).amax(dim=-1)
    bad = ~torch.isfinite(state.pos).flatten(1).all(dim=1) | ~(speed <= max_speed)
    if bool(bad.any()):
        which = bad.nonzero().flatten().tolist()
        first = which[0]
        raise SimulationDiverged(
            f"simulation diverged: instance {first} (of {which}) at step {step} "
            f"(t = {time:.4f} s): max speed {speed[first].item():.3g} m/s exceeds "
            f"{max_speed} m/s or state is not finite"
        )
