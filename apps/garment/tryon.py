"""Virtual try-on (*thesis* §6.6.2, Fig. 6.10): a recovered garment on another body, in wind.

The garment keeps its pattern G and its material C (the *thesis* keeps the material to
preserve the design; ``resize=True`` scales the girth parameters by the new body's girths, as
a tailor grading the pattern would). It is registered on the new body's pose and shape
(rest placement, skinning, push-out), sewn and draped to rest (:func:`.drape.drape`), then
simulated dynamically (backward Euler, friction, aerodynamic drag) in a gusty wind that ramps
in over ``ramp`` seconds; the frames are recorded as a :class:`simulator.sequence.MeshSequence`
and rendered.

``python -m apps.garment.tryon pattern=<run>/pattern.json body.height=1.6 pose=c``
(``configs/garment_tryon.yaml``) writes ``tryon.png`` (the dressed body, front and three
quarter), ``wind.mp4``, ``sequence.npz``, ``garment.obj`` and ``body.obj``.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Callable, Mapping
from pathlib import Path

import numpy as np
import torch

from common.commands import hydra_command
from common.errors import InputError
from simulator.cloth.material import ClothMaterial
from simulator.cloth.wind import WindField
from simulator.forces import AerodynamicDrag
from simulator.garment.body import BodyShape, Mannequin, Pose
from simulator.garment.drape import (
    DrapeSettings,
    GarmentBatch,
    check_material,
    drape,
    garment_material,
    register_batch,
)
from simulator.garment.patterns import (
    GarmentType,
    Pattern,
    PatternTopology,
    build_pattern,
    param_specs,
)
from simulator.integrators import IntegratorBackwardEuler
from simulator.model import SimState
from simulator.sequence import MeshSequence

__all__ = [
    "CLONE_LEVELS",
    "GIRTH_PARAMS",
    "TryOn",
    "animate",
    "clone_skirt",
    "load_pattern_json",
    "resize_params",
    "try_on",
    "wind",
]

GIRTH_PARAMS: dict[str, dict[str, str]] = {
    "skirt": {"l1": "waist", "r1": "hip"},
    "pants": {"w1": "waist", "w2": "hip", "w3": "hip", "w4": "hip"},
    "tshirt": {"w2": "chest", "w1": "chest"},
}
"""Sizing parameters graded with a body girth when resizing (parameter -> girth)."""


def load_pattern_json(path: str | Path, field: str = "pattern") -> tuple[str, dict, dict]:
    """Garment type, G and C from a ``pattern.json`` a recovery wrote (checked)."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as err:
        raise InputError(f"{field}: cannot read {path} as JSON ({err})") from None
    if not isinstance(data, Mapping) or "garment" not in data or "params" not in data:
        raise InputError(f"{field}: {path} is not a pattern.json (needs garment and params)")
    garment = data["garment"]
    if garment not in [g.value for g in GarmentType]:
        raise InputError(
            f"{field}: garment must be one of {', '.join(g.value for g in GarmentType)}; "
            f"got {garment!r}"
        )
    raw = data["params"]
    params = {k: (v["value"] if isinstance(v, Mapping) else v) for k, v in raw.items()}
    material = {k: v for k, v in (data.get("material") or {}).items() if k in ("bend", "stretch")}
    from simulator.garment.patterns import check_params

    return (
        garment,
        check_params(garment, params, f"{field}.params"),
        check_material(material, f"{field}.material"),
    )


def resize_params(garment: str, params: dict, source: BodyShape, target: BodyShape) -> dict:
    """Grade the girth parameters by the target body's girths over the source body's."""
    specs = {p.name: p for p in param_specs(garment)}
    out = dict(params)
    for name, girth in GIRTH_PARAMS[garment].items():
        ratio = getattr(target, girth) / getattr(source, girth)
        out[name] = float(np.clip(params[name] * ratio, specs[name].low, specs[name].high))
    if garment == "skirt":
        # r1 * alpha is the hip arc: keep alpha (the flare) and grade the radius.
        hip = out["r1"] * out["alpha"]
        out["r1"] = float(np.clip(hip, 0.40, 0.95) / out["alpha"])
    return out


@dataclasses.dataclass(frozen=True)
class TryOn:
    """A garment dressed on a body, at rest."""

    pattern: Pattern
    material: dict[str, float]
    body: Mannequin
    pose: Pose
    pos: np.ndarray
    """The draped garment [m], shape (V, 3)."""
    converged: bool


def try_on(
    garment: str,
    params: dict,
    material: dict,
    body: Mannequin,
    pose: Pose,
    *,
    edge_length: float = 0.04,
    settings: DrapeSettings | None = None,
) -> TryOn:
    """Register and drape the garment (G, C unchanged) on ``body`` in ``pose``."""
    settings = settings or DrapeSettings(max_steps=200)
    topology = PatternTopology.build(garment, edge_length)
    pattern = build_pattern(garment, params, topology=topology)
    angles = pose.angles[None]
    x0 = register_batch(topology, pattern.coords[None], [pattern.params], body, angles)
    mat = garment_material([material["bend"]], [material["stretch"]])
    batch = GarmentBatch.build(
        topology, pattern.coords[None], mat, body.capsules(angles), settings, pos_hint=x0
    )
    result = drape(batch, x0, settings)
    return TryOn(
        pattern, dict(material), body, pose, result.pos[0].numpy(), bool(result.converged[0])
    )


def animate(
    topology: PatternTopology,
    coords: np.ndarray,
    material: ClothMaterial,
    body: Mannequin,
    pose: Pose,
    start: np.ndarray,
    *,
    speed: float = 3.0,
    direction_deg: float = 30.0,
    seconds: float = 2.0,
    fps: float = 25.0,
    substeps: int = 4,
    ramp: float = 0.5,
    gust: float = 0.4,
    seed: int = 0,
    on_frame: Callable[[int, int], None] | None = None,
) -> np.ndarray:
    """Simulate B garments at rest on a body in wind; frames (B, K, V, 3) float32 [m].

    Args:
        topology: the garments' pattern topology.
        coords: panel coordinates per instance [m], shape (B, V, 2).
        material: B fabrics.
        body: the mannequin.
        pose: its pose (the same for every instance).
        start: the garments at rest [m], shape (B, V, 3).
        speed: mean wind speed [m/s].
        direction_deg: wind heading in the ground plane [deg], 0 = towards +x (the wearer's
            left), 90 = towards +y (from the camera's side into the scene).
        seconds: recorded time [s]; frame 0 is the rest state.
        fps: recorded frames per second.
        substeps: backward-Euler steps per frame.
        ramp: the wind ramps in linearly over this time [s].
        gust: gust amplitude relative to the mean speed (0: steady wind).
        seed: gust modes.
        on_frame: called with (frame, frames) after every frame (progress).
    """
    if not (math.isfinite(speed) and 0.0 <= speed <= 30.0):
        raise InputError(f"wind.speed must lie in [0, 30] m/s, got {speed!r}")
    batch_size = len(coords)
    angles = np.repeat(pose.angles[None], batch_size, 0)
    caps = body.capsules(angles)
    settings = DrapeSettings(newton_iters=4)
    batch = GarmentBatch.build(topology, coords, material, caps, settings, pos_hint=start)
    model = dataclasses.replace(batch.model, forces=(*batch.model.forces, AerodynamicDrag()))
    heading = math.radians(direction_deg)
    mean = torch.tensor(
        [[speed * math.cos(heading), speed * math.sin(heading), 0.0]] * batch_size,
        dtype=torch.float64,
    )
    seeds = [seed + b for b in range(batch_size)]
    field = WindField.gusty(mean, seeds, amplitude=gust, modes=4) if gust > 0 else WindField(mean)
    pos = torch.as_tensor(np.asarray(start), dtype=torch.float64)
    state = SimState(pos, torch.zeros_like(pos), torch.zeros(batch_size, dtype=torch.float64))
    integrator = IntegratorBackwardEuler(settings.newton())
    base = batch.control()
    frames = max(round(seconds * fps), 1) + 1
    dt = 1.0 / (fps * substeps)
    out = [state.pos.numpy().astype(np.float32)]
    for k in range(1, frames):
        for _ in range(substeps):
            t = float(state.time[0]) + dt
            level = min(t / ramp, 1.0) if ramp > 0 else 1.0
            control = dataclasses.replace(base, wind_vel=field.velocity(state.pos, t, level))
            state, _ = integrator.step(model, state, control, dt)
            if not torch.isfinite(state.pos).all():
                raise FloatingPointError(f"wind animation diverged at frame {k}")
        out.append(state.pos.numpy().astype(np.float32))
        if on_frame is not None:
            on_frame(k, frames)
    return np.stack(out, axis=1)


def wind(dressed: TryOn, *, seed: int = 0, fps: float = 25.0, **kwargs) -> MeshSequence:
    """Animate a dressed garment in wind (:func:`animate`'s keywords); a :class:`MeshSequence`."""
    topology = dressed.pattern.topology
    mat = garment_material([dressed.material["bend"]], [dressed.material["stretch"]])
    frames = animate(
        topology,
        dressed.pattern.coords[None],
        mat,
        dressed.body,
        dressed.pose,
        dressed.pos[None],
        seed=seed,
        fps=fps,
        **kwargs,
    )
    caps = dressed.body.capsules(dressed.pose.angles[None]).astype(np.float32)
    return MeshSequence(
        pos=frames,
        tri_indices=topology.tri_indices,
        uv=dressed.pattern.atlas_uv().astype(np.float32),
        fps=float(fps),
        seeds=[seed],
        labels=[-1],
        wind_levels=[0],
        meta={
            "scene": "garment_wind",
            "garment": dressed.pattern.garment.value,
            "params": dressed.pattern.params,
            "material": dressed.material,
            "wind": {k: v for k, v in kwargs.items() if k != "on_frame"},
        },
        capsules=np.repeat(caps[:, None], frames.shape[1], axis=1),
    )


CLONE_LEVELS = {1: 0.08, 2: 0.06, 3: 0.045}
"""Mesh resolution level of material cloning -> the skirt's edge length [m]."""


def clone_skirt(
    material: ClothMaterial,
    *,
    level: int = 1,
    seconds: float = 2.0,
    fps: float = 25.0,
    size: int = 160,
    speed: float = 2.5,
    seed: int = 0,
    on_frame: Callable[[int, int], None] | None = None,
) -> tuple[MeshSequence, np.ndarray]:
    """Material cloning onto a skirt (*thesis* Fig. 7.9): B fabrics, one skirt each.

    The default skirt is draped on the mannequin in pose a, then blown by a gusty wind; every
    instance sees the same body, pattern and wind, so only the fabric differs.

    Returns:
        ``(sequence, frames)``: the recorded :class:`MeshSequence` (B instances) and the
        renders, uint8 (B, K, size, size, 3) (a camera framing the skirt, midday light).
    """
    from render.camera import CameraSpec

    from .scenes import GARMENT_COLORS, POSES, render_scene, scene_light

    if level not in CLONE_LEVELS:
        raise InputError(f"level must be one of {sorted(CLONE_LEVELS)}, got {level!r}")
    body = Mannequin.build()
    pose = POSES["a"]
    topology = PatternTopology.build("skirt", CLONE_LEVELS[level])
    pattern = build_pattern("skirt", topology=topology)
    batch_size = material.batch_size
    coords = np.repeat(pattern.coords[None], batch_size, 0)
    angles = np.repeat(pose.angles[None], batch_size, 0)
    x0 = register_batch(topology, coords[:1], [pattern.params], body, angles[:1])
    x0 = np.repeat(x0, batch_size, 0)
    settings = DrapeSettings(max_steps=150)
    batch = GarmentBatch.build(
        topology, coords, material, body.capsules(angles), settings, pos_hint=x0
    )
    rest = drape(batch, x0, settings).pos.numpy()
    frames = animate(
        topology,
        coords,
        material,
        body,
        pose,
        rest,
        speed=speed,
        seconds=seconds,
        fps=fps,
        seed=seed,
        on_frame=on_frame,
    )
    waist = body.levels["waist"]
    camera = CameraSpec(
        position=(0.35, -2.3, waist - 0.1),
        look_at=(0.0, 0.0, waist - 0.3),
        yfov_deg=30.0,
        width=size,
        height=size,
    )
    caps = body.capsules(pose.angles[None])[0]
    from render.renderer import ClothRenderer

    images = np.empty((batch_size, frames.shape[1], size, size, 3), np.uint8)
    with ClothRenderer(camera, scene_light("midday")) as renderer:
        for b in range(batch_size):
            for k in range(frames.shape[1]):
                images[b, k], _, _ = render_scene(
                    camera,
                    None,
                    caps,
                    [(frames[b, k], topology.tri_indices, GARMENT_COLORS["skirt"])],
                    masks=False,
                    renderer=renderer,
                )
    sequence = MeshSequence(
        pos=frames,
        tri_indices=topology.tri_indices,
        uv=pattern.atlas_uv().astype(np.float32),
        fps=float(fps),
        seeds=[seed] * batch_size,
        labels=[-1] * batch_size,
        wind_levels=[0] * batch_size,
        meta={
            "scene": "garment_skirt",
            "params": pattern.params,
            "wind_speed": speed,
            "level": level,
        },
        capsules=np.repeat(caps.astype(np.float32)[None, None], batch_size, 0).repeat(
            frames.shape[1], axis=1
        ),
    )
    return sequence, images


# ------------------------------------------------------------------------------ command

TRYON_OUTPUTS = ("tryon.png", "wind.mp4", "sequence.npz")


def _checked(cfg) -> dict:
    """Every field of the try-on command, validated (one-line :class:`InputError`)."""
    from omegaconf import OmegaConf

    from common.checks import check_bool, check_choice, check_float, check_int, check_threads

    from .scenes import POSES

    threads = check_threads(cfg.get("threads", 1), "threads")
    garment, params, material = load_pattern_json(str(cfg.pattern), "pattern")
    body_values = OmegaConf.to_container(cfg.body, resolve=True)
    unknown = sorted(set(body_values) - {"height", "chest", "waist", "hip"})
    if unknown:
        raise InputError(f"body: unknown {unknown}; allowed: height, chest, waist, hip")
    shape = BodyShape(**body_values)
    pose_value = OmegaConf.to_container(cfg.pose) if OmegaConf.is_config(cfg.pose) else cfg.pose
    if isinstance(pose_value, str):
        pose = POSES[check_choice(pose_value, "pose", sorted(POSES))]
    elif isinstance(pose_value, Mapping):
        pose = Pose.from_dict(pose_value)
    else:
        raise InputError(
            f"pose must be one of a, b, c or a mapping joint: [x, y, z]; got {pose_value!r}"
        )
    edge = check_float(cfg.edge_length, "edge_length", 0.02, 0.1)
    w = cfg.wind
    wind_args = {
        "speed": check_float(w.speed, "wind.speed", 0.0, 30.0),
        "direction_deg": check_float(w.direction_deg, "wind.direction_deg", -360.0, 360.0),
        "gust": check_float(w.gust, "wind.gust", 0.0, 2.0),
        "seconds": check_float(w.seconds, "wind.seconds", 0.0, 30.0, low_open=True),
        "fps": check_float(w.fps, "wind.fps", 1.0, 120.0),
    }
    return {
        "threads": threads,
        "garment": garment,
        "params": params,
        "material": material,
        "shape": shape,
        "pose": pose,
        "resize": check_bool(cfg.resize, "resize"),
        "edge": edge,
        "wind": wind_args,
        "size": check_int(cfg.size, "size", 64, 2048),
        "export": check_choice(cfg.export, "export", ("obj", "ply")),
        "out_dir": Path(str(cfg.out_dir)),
    }


def run(cfg) -> TryOn:
    """Dress the new body, animate it, write the outputs (staged, then moved into place)."""
    import os
    import shutil
    import tempfile

    import cv2
    import trimesh

    from simulator.sequence import atomic_write_bytes
    from simulator.threads import use_process_threads

    from .scenes import GARMENT_COLORS, render_scene, scene_camera, scene_light

    f = _checked(cfg)
    use_process_threads(f["threads"], name="threads")
    params = f["params"]
    if f["resize"]:
        params = resize_params(f["garment"], params, BodyShape(), f["shape"])
    body = Mannequin.build(f["shape"])
    dressed = try_on(f["garment"], params, f["material"], body, f["pose"], edge_length=f["edge"])
    from tqdm import tqdm

    bar = tqdm(desc="wind", unit="frame")

    def on_frame(done, total):
        bar.total = total
        bar.update(done - bar.n)

    try:
        seq = wind(
            dressed,
            fps=f["wind"]["fps"],
            on_frame=on_frame,
            **{k: v for k, v in f["wind"].items() if k != "fps"},
        )
    finally:
        bar.close()
    size = f["size"]
    camera = scene_camera(size)
    from render.camera import CameraSpec
    from render.renderer import ClothRenderer

    side = CameraSpec(
        position=(3.0, -3.0, 1.3), look_at=(0.0, 0.0, 0.9), yfov_deg=26.0, width=size, height=size
    )
    caps = body.capsules(f["pose"].angles[None])[0]
    color = GARMENT_COLORS[f["garment"]]
    tri = dressed.pattern.topology.tri_indices
    views = [
        render_scene(cam, scene_light("midday"), caps, [(dressed.pos, tri, color)], masks=False)[0]
        for cam in (camera, side)
    ]
    with ClothRenderer(camera, scene_light("midday")) as renderer:
        frames = np.stack(
            [
                render_scene(camera, None, caps, [(p, tri, color)], masks=False, renderer=renderer)[
                    0
                ]
                for p in seq.pos[0]
            ]
        )
    out_dir = f["out_dir"]
    out_dir.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=".tryon-", dir=out_dir))
    export = f["export"]
    names = [*TRYON_OUTPUTS, f"garment.{export}", f"body.{export}"]
    try:
        _, data = cv2.imencode(".png", cv2.cvtColor(np.concatenate(views, 1), cv2.COLOR_RGB2BGR))
        atomic_write_bytes(staging / "tryon.png", data.tobytes())
        _write_mp4(staging / "wind.mp4", frames, f["wind"]["fps"])
        seq.save(staging / "sequence.npz")
        trimesh.Trimesh(dressed.pos, tri, process=False).export(staging / f"garment.{export}")
        body.trimesh(f["pose"]).export(staging / f"body.{export}")
        for name in names:
            os.replace(staging / name, out_dir / name)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return dressed


def _write_mp4(path: Path, frames: np.ndarray, fps: float) -> None:
    """RGB uint8 frames (K, H, W, 3) as an mp4 (mp4v)."""
    import cv2

    height, width = frames.shape[1:3]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (width, height))
    if not writer.isOpened():
        raise RuntimeError("OpenCV cannot write mp4 (mp4v) here")
    for frame in frames:
        writer.write(np.ascontiguousarray(frame[..., ::-1]))
    writer.release()


main = hydra_command(run, config_name="garment_tryon", config_path="../../configs")
"""The command line: ``python -m apps.garment.tryon pattern=... pose=c``."""


if __name__ == "__main__":
    main()
