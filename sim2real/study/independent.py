"""Pseudo-real footage from an independent engine: MuJoCo flex cloth, MuJoCo's own renderer.

``python -m sim2real.study.independent --out DIR [--fabrics 30] [--winds 3] [--seed 0]
[--size 112] [--frames N] [--fps 15] [--codec h264|mjpeg|png] [--wind-drag
isotropic|plate]`` writes a folder in the layout of real footage
(:class:`datasets.real_video.RealVideoDataset`, ``docs/datasets.md`` "Real footage"; Bouman
et al. 2013: fabrics x winds), made by neither our simulator nor our renderer, so that the
sim-to-real diagnosis can be checked on footage whose differences from our scene are known but
were not made by our own switches:

- one video per fabric x wind (``vNNN.mp4`` / ``vNNN.avi``, or a folder of PNG frames with
  ``--codec png``), fabric-major (fabric 0 at W1, W2, W3, then fabric 1, ...);
- ``labels.csv`` with ``video, stiffness, density, wind, fps`` and, as extra columns that the
  reader carries along (it refuses none), ``fabric`` (the reader's automatic group column: the
  three winds of one fabric are one group), ``stretch_stiffness`` [N/m] and
  ``bend_stiffness`` [N·m], and the cloth's measured 3D motion (what a motion-capture rig
  would record beside real footage): ``vertex_speed`` [m/s], ``out_of_plane_rms`` [m] and
  ``edge_strain_rms`` (:func:`edge_strain_rms`). ``stiffness`` has the meaning and unit of
  the sealed sets' (:mod:`.seal`): the bend multiplier ``k``, i.e. the bending stiffness
  relative to the basis fabric ``camel-ponte-roma``'s (``bend_stiffness = k * mean(basis
  bending samples)``, as :func:`simulator.cloth.material.class_summary` defines it),
  dimensionless; ``density`` is the areal density [kg/m²];
- ``DIR.engine.json`` beside the folder: every difference from our scene (below), the codec
  actually used, the frame rate, the scene constants and each video's ground truth.

The 30 fabrics are log-uniform draws (stretch, bend and density independently, each fabric
from the seed and its index alone, so ``--fabrics 3`` gives the first three of ``--fabrics
30``) over the ranges of the ten measured Wang et al. (2011) fabrics: stretch 82-2112 N/m
(mean warp/weft tension stiffness over the six rows), bend 1.9e-5 to 1.7e-4 N·m (mean of the
15 samples), density 0.113-0.324 kg/m².

Differences from our wind scene (:class:`simulator.cloth.scenes.ScenarioWind`, the sealed
sets' renderer), all on purpose:

- **Engine and material law.** MuJoCo's 2D flex (:mod:`sim2real.study.mujoco_flex`'s mapping): an
  isotropic Saint Venant-Kirchhoff membrane with ``E t`` = stretch stiffness and Poisson 0.3,
  and hinge bending ``D = E t^3 / (12 (1 - nu^2))`` = bend stiffness, stepped by MuJoCo's
  ``discrete`` integrator. Ours: Wang et al.'s anisotropic, strain-stiffening membrane and
  measured direction- and curvature-dependent dihedral bending, backward Euler with Newton.
- **Wind.** MuJoCo's global fluid model on the vertex bodies: isotropic quadratic drag of each
  vertex's share of the cloth area against the air velocity, blind to the cloth's normal
  (ours: normal pressure drag along each vertex's area-weighted normal, optional lift). A
  fan: mean speeds W1-W3 = 0.6, 1.5, 2.8 m/s (spanning our 0.75, 1.5, 2.5), its axis yawed
  uniformly within ±10° per video, spinning up exponentially (time constant 0.15 s; ours: a
  0.25 s smoothstep) and gusting: along-wind speed ``W (1 + 0.2 g_u(t))`` and a cross-wind
  ``0.1 W g_v(t)``, where ``g`` are independent smooth random processes (white noise through
  two first-order low-pass filters of 0.3 s, unit variance) drawn per video. Ours is
  constant (its gusts are a switch that is off in the nominal scene). ``--wind-drag plate``
  replaces the fluid model by flat-plate drag per triangle (:class:`PlateDrag`: normal
  pressure ``C_n`` 1.17 plus skin friction ``C_f`` 0.02, explicit forces on the vertices),
  which, like ours, sees the cloth's orientation but differs in its coefficients, friction
  and time integration.
- **Pinning.** Three points of the top edge (both corners and its middle, as three clips on
  a rod); ours: the two top corners.
- **Mass.** MuJoCo's flexcomp gives every vertex the same mass (``density * area /
  vertices``) and the three pinned vertices' mass is lost; ours lumps each triangle's mass to
  its corners (edge and corner vertices lighter).
- **Shape and settling.** 21 x 21 vertices (ours: the training level's mesh); starts with a
  smooth random waviness (2 mm RMS, wavelengths 0.15-0.5 m; ours: uniform ±1 mm per vertex),
  then settles for 1 s under gravity with vertex damping, which is then switched off.
- **Renderer and look.** ``mujoco.Renderer`` (OpenGL rasteriser, 4x multisampling, shadow
  maps), not pyrender. The cloth carries a MuJoCo builtin texture (checker, flat or gradient,
  with random speckles) in colours drawn per fabric; the backdrop is a 3D floor plane with a
  builtin checker and a gradient skybox (ours: a textured cloth composited over 2D
  procedural room images); one directional light with shadows on the floor plus a headlight,
  drawn per fabric; the camera stands downwind and above like ``CameraSpec.wind`` but on the
  other side of the cloth's centre line (mirrored azimuth, 32° field of view).
- **Camera and timing.** The codec (``h264`` is asked for; this OpenCV build may lack an
  H.264 encoder, then ``mp4v`` and then ``MJPG`` are used, and the JSON says which), the
  frame rate (``--fps``; the reader resamples to 15). As our sealed sets, frame 0 is the rest
  state at the fan's start and the first 0.4 s are dropped (``lead_in``), then ``--frames``
  frames are written (default: 4 clips of 10 frames at the training frame rate of 15 fps).

What the engine shows (measured on the default 90 videos): with drag blind to the normal, a
cloth in steady wind settles to a still, nearly flat sheet (no flutter), so the motion comes
from the gusts; how fast the cloth moves is set by the wind and density, not by the
stiffnesses (Spearman of mean vertex speed with bending: |rho| < 0.05 at every wind), while
stiffer fabrics wrinkle and deform less (out-of-plane RMS vs bending: rho -0.3 to -0.55).
With ``--wind-drag plate`` (same seed) the cloth billows: out-of-plane RMS 3.1 / 9.3 / 10.1
mm at W1-W3 (isotropic: 0.8 / 1.8 / 2.3 mm), tied to bending (rho -0.49 / -0.85 / -0.64),
while the mean vertex speed still follows wind and density, not bending (|rho| < 0.1).
Steps: MuJoCo 4 integrates flex elasticity implicitly only with the ``discrete`` integrator
(``implicit``/``implicitfast`` are refused; explicit ``Euler`` blew up at 0.5 ms); with it
the stiffest fabric is stable even at 1/60 s, and at 1/150 s the mean vertex motion is that
of 1/500 s within 1 %.

Deterministic: the same arguments give the same frames (PNG: the same bytes; the mp4v
encoder of this build, too). The folder is written through a staging folder and moved into
place at the end; Ctrl-C leaves nothing.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import hashlib
import json
import math
import os
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from common.checks import check_choice, check_float, check_int
from common.commands import report_user_errors
from common.errors import InputError
from common.files import atomic_write_bytes, staged_folder
from common.paths import check_output_dir

from .mujoco_flex import AIR_DENSITY_KG_M3, AIR_VISCOSITY_PA_S, elastic_params

__all__ = [
    "CODECS",
    "WIND_DRAGS",
    "EngineFabric",
    "EngineScene",
    "FabricLook",
    "default_frame_count",
    "draw_fabric",
    "draw_look",
    "edge_strain_rms",
    "import_mujoco",
    "measured_ranges",
    "out_of_plane_rms",
    "render_available",
    "scene_mjcf",
    "simulate_positions",
    "wind_history",
    "write_independent_set",
]

CODECS = ("h264", "mjpeg", "png")
WIND_DRAGS = ("isotropic", "plate")
"""Air drag laws of the engine's scene (:attr:`EngineScene.wind_drag`)."""
TRAINING_FPS = 15.0
"""The training clips' frame rate [1/s] (``datasets.spec.SizePreset.fps``)."""
CLIP_LEN = 10
"""Frames per clip, as the diagnosis cuts real footage (``clip_len``)."""
CLIPS_PER_VIDEO = 4
"""Clips the default video holds (the sealed sets' ``--clips-per-video``; quick budget: 3)."""
WIND_LEVELS = {1: (1,), 2: (0, 2), 3: (0, 1, 2)}
"""Wind levels (W1 = 0) filmed for ``--winds`` 1, 2 or 3."""
_FABRIC_STREAM = 64
_LOOK_STREAM = 65
_WIND_STREAM = 66
_SHAPE_STREAM = 67
_VIDEO_SUFFIXES = {"avc1": ".mp4", "mp4v": ".mp4", "MJPG": ".avi"}
_CODEC_FALLBACKS = {"h264": ("avc1", "mp4v", "MJPG"), "mjpeg": ("MJPG",)}


@dataclasses.dataclass(frozen=True)
class EngineScene:
    """Constants of the independent engine's scene (SI units, world z up, wind along +y)."""

    vert_per_side: int = 21
    """Vertices along each side (odd, so that the top edge has a middle vertex)."""
    size: float = 0.5
    """Side of the square cloth [m] (ours: 0.5)."""
    height: float = 1.0
    """Height of the top edge [m] (ours: 1.0)."""
    poisson: float = 0.3
    """Poisson's ratio of the flex membrane."""
    wind_speeds: tuple[float, ...] = (0.6, 1.5, 2.8)
    """Mean fan speeds W1 < W2 < W3 [m/s] (ours: 0.75, 1.5, 2.5)."""
    fan_yaw_deg: float = 10.0
    """Half-width of the uniform draw of the fan axis's yaw about +y [deg]."""
    fan_spinup: float = 0.15
    """Time constant of the fan's exponential spin-up [s]."""
    gust_intensity: float = 0.2
    """Standard deviation of the along-wind speed relative to the mean."""
    crosswind_intensity: float = 0.1
    """Standard deviation of the horizontal cross-wind relative to the mean speed."""
    gust_time: float = 0.3
    """Time constant of each of the gust process's two low-pass filters [s]."""
    settle_time: float = 1.0
    """Damped settling under gravity before the fan starts [s]."""
    settle_dt: float = 1.0 / 60.0
    """Time step while settling [s]."""
    settle_damping_time: float = 0.05
    """Vertex damping while settling, as mass / damping [s]."""
    max_dt: float = 1.0 / 150.0
    """Largest time step while recording [s] (10 steps per frame at 15 fps)."""
    waviness: float = 2e-3
    """RMS of the initial out-of-plane waviness [m]."""
    lead_in: float = 0.4
    """Recorded time dropped after the fan starts [s] (the sealed sets' ``lead_in``)."""
    camera_pos: tuple[float, float, float] = (-0.26, 1.70, 2.02)
    """Camera position [m] (``CameraSpec.wind``: (0.22, 1.66, 2.06))."""
    camera_look_at: tuple[float, float, float] = (-0.04, 0.20, 0.80)
    """Point the camera looks at [m] (``CameraSpec.wind``: (-0.04, 0.20, 0.81))."""
    camera_fovy_deg: float = 32.0
    """Vertical field of view [deg] (``CameraSpec.wind``: 30)."""
    wind_drag: str = "isotropic"
    """Air drag law: ``isotropic`` (MuJoCo's fluid model, blind to the cloth's normal) or
    ``plate`` (flat-plate drag per triangle: normal pressure plus skin friction)."""
    plate_normal_cd: float = 1.17
    """Normal-pressure coefficient of the ``plate`` law (a flat plate broadside, Hoerner)."""
    plate_friction_cd: float = 0.02
    """Skin-friction coefficient of the ``plate`` law on the tangential air velocity."""

    def pin_grid(self) -> tuple[tuple[int, int], ...]:
        """Flexcomp grid indices (column, row) of the pinned vertices: corners and middle."""
        n, top = self.vert_per_side, self.vert_per_side - 1
        return ((0, top), (n // 2, top), (n - 1, top))

    def record_steps(self, fps: float) -> tuple[int, float]:
        """Physics steps per frame and the step [s] at frame rate ``fps``."""
        steps = max(1, math.ceil(1.0 / (fps * self.max_dt) - 1e-9))
        return steps, 1.0 / (fps * steps)

    def lead_in_frames(self, fps: float) -> int:
        """Recorded frames dropped after the fan starts."""
        return round(self.lead_in * fps)


@dataclasses.dataclass(frozen=True)
class EngineFabric:
    """One fabric of the independent set (the ground truth of its videos)."""

    index: int
    stretch_stiffness: float
    """Membrane stiffness ``E t`` [N/m]."""
    bend_stiffness: float
    """Plate bending stiffness ``D`` [N·m]."""
    density: float
    """Areal density [kg/m²]."""
    stiffness: float
    """Bend multiplier: ``bend_stiffness`` over the basis fabric's mean bending (as
    ``labels.csv``'s ``stiffness`` of the sealed sets)."""


@dataclasses.dataclass(frozen=True)
class FabricLook:
    """Appearance of one fabric's recording session (cloth texture, backdrop, light)."""

    texture: str
    """MuJoCo builtin 2D texture of the cloth: ``checker``, ``flat`` or ``gradient``."""
    cloth_rgb1: tuple[float, float, float]
    cloth_rgb2: tuple[float, float, float]
    speckle_rgb: tuple[float, float, float]
    speckle: float
    """Fraction of texels replaced by ``speckle_rgb`` (MuJoCo's ``mark="random"``; a flat
    texture has 16 x 16 texels, so its speckles show as mottling, the others 256 x 256)."""
    repeat: int
    """Texture repeats across the cloth."""
    specular: float
    shininess: float
    floor_rgb1: tuple[float, float, float]
    floor_rgb2: tuple[float, float, float]
    floor_repeat: int
    sky_rgb1: tuple[float, float, float]
    sky_rgb2: tuple[float, float, float]
    light_dir: tuple[float, float, float]
    """Direction the key light travels in (world), unit, shape (3,)."""
    light_diffuse: float
    ambient: float


def measured_ranges() -> dict[str, tuple[float, float]]:
    """(low, high) of the ten measured fabrics' stretch [N/m], bend [N·m] and density [kg/m²].

    Summaries as :func:`simulator.cloth.material.class_summary` takes them: the mean
    warp/weft tension stiffness over the six stretching rows and the mean of the fifteen
    bending samples. Also the basis fabric's mean bending (``basis_bend``).
    """
    from simulator.cloth.material import BASIS_MATERIAL, load_wang_material, wang_material_names

    stretch, bend, density = [], [], []
    for name in wang_material_names():
        fabric = load_wang_material(name)
        stretch.append(float(0.5 * (fabric.stretching[:, 0] + fabric.stretching[:, 2]).mean()))
        bend.append(float(fabric.bending.mean()))
        density.append(float(fabric.density))
    basis = float(load_wang_material(BASIS_MATERIAL).bending.mean())
    return {
        "stretch_stiffness": (min(stretch), max(stretch)),
        "bend_stiffness": (min(bend), max(bend)),
        "density": (min(density), max(density)),
        "basis_bend": (basis, basis),
    }


def draw_fabric(seed: int, index: int, ranges: dict | None = None) -> EngineFabric:
    """Fabric ``index`` of the set of ``seed``: log-uniform in each measured range."""
    ranges = ranges or measured_ranges()
    rng = np.random.default_rng([seed, _FABRIC_STREAM, index])
    values = {}
    for name in ("stretch_stiffness", "bend_stiffness", "density"):
        low, high = ranges[name]
        values[name] = float(f"{math.exp(rng.uniform(math.log(low), math.log(high))):.4g}")
    stiffness = float(f"{values['bend_stiffness'] / ranges['basis_bend'][0]:.6g}")
    return EngineFabric(index=index, stiffness=stiffness, **values)


def _colour(rng: np.random.Generator, low: float, high: float) -> tuple[float, float, float]:
    return tuple(round(float(c), 3) for c in rng.uniform(low, high, 3))  # type: ignore[return-value]


def draw_look(seed: int, index: int) -> FabricLook:
    """Appearance of fabric ``index``'s session, from the seed and index alone."""
    rng = np.random.default_rng([seed, _LOOK_STREAM, index])
    texture = ("checker", "flat", "gradient")[int(rng.choice(3, p=(0.5, 0.25, 0.25)))]
    cloth1 = _colour(rng, 0.15, 0.95)
    cloth2 = tuple(round(c * float(rng.uniform(0.25, 0.7)), 3) for c in cloth1)
    if texture == "checker" and rng.uniform() < 0.5:
        cloth2 = _colour(rng, 0.05, 0.95)
    grey = float(rng.uniform(0.25, 0.6))
    tint = rng.uniform(0.85, 1.15, 3)
    floor1 = tuple(round(float(min(1.0, grey * t)), 3) for t in tint)
    floor2 = tuple(round(c * 0.75, 3) for c in floor1)
    azimuth = math.radians(rng.uniform(-50.0, 50.0))
    elevation = math.radians(rng.uniform(40.0, 70.0))
    # travels from above and behind the camera (+y) towards the cloth
    light = (
        -math.cos(elevation) * math.sin(azimuth),
        -math.cos(elevation) * math.cos(azimuth),
        -math.sin(elevation),
    )
    return FabricLook(
        texture=texture,
        cloth_rgb1=cloth1,  # type: ignore[arg-type]
        cloth_rgb2=cloth2,  # type: ignore[arg-type]
        speckle_rgb=_colour(rng, 0.0, 1.0),
        speckle=round(float(rng.uniform(*((0.1, 0.3) if texture == "flat" else (0.0, 0.06)))), 4),
        repeat=int(rng.integers(2, 6)),
        specular=round(float(rng.uniform(0.0, 0.3)), 3),
        shininess=round(float(rng.uniform(0.05, 0.5)), 3),
        floor_rgb1=floor1,  # type: ignore[arg-type]
        floor_rgb2=floor2,  # type: ignore[arg-type]
        floor_repeat=int(rng.integers(4, 12)),
        sky_rgb1=_colour(rng, 0.55, 0.95),
        sky_rgb2=_colour(rng, 0.05, 0.35),
        light_dir=tuple(round(c, 4) for c in light),  # type: ignore[arg-type]
        light_diffuse=round(float(rng.uniform(0.5, 0.9)), 3),
        ambient=round(float(rng.uniform(0.15, 0.35)), 3),
    )


def _smooth_noise(rng: np.random.Generator, count: int, a: float) -> np.ndarray:
    """Unit-variance white noise through two first-order low-pass filters, shape (count,).

    Each filter is ``y <- a y + (1 - a) x`` with ``a = exp(-dt / tau)``; the first is fed a
    unit-variance AR(1) process, so the output's stationary variance is
    ``(1 + a^2) / (1 + a)^2``, divided out. Starts stationary after a burn-in of 5 tau.
    """
    burn = math.ceil(5.0 / max(1e-12, 1.0 - a))
    noise = rng.standard_normal(burn + count)
    scale = math.sqrt(1.0 - a * a)
    out = np.empty(burn + count)
    x = y = 0.0
    for i, e in enumerate(noise):
        x = a * x + scale * e
        y = a * y + (1.0 - a) * x
        out[i] = y
    return out[burn:] / math.sqrt((1.0 + a * a) / (1.0 + a) ** 2)


def wind_history(
    scene: EngineScene, level: int, rng: np.random.Generator, times: np.ndarray
) -> tuple[np.ndarray, dict]:
    """Air velocity [m/s] at ``times`` after the fan starts, shape (T, 3), and its draws.

    ``times`` must be evenly spaced (the physics steps).
    """
    mean = scene.wind_speeds[level]
    yaw = math.radians(rng.uniform(-1.0, 1.0) * scene.fan_yaw_deg)
    step = float(times[1] - times[0]) if len(times) > 1 else scene.max_dt
    a = math.exp(-step / scene.gust_time)
    along = _smooth_noise(rng, len(times), a)
    cross = _smooth_noise(rng, len(times), a)
    ramp = np.where(times > 0, 1.0 - np.exp(-np.maximum(times, 0.0) / scene.fan_spinup), 0.0)
    speed = mean * ramp * np.maximum(0.0, 1.0 + scene.gust_intensity * along)
    side = mean * ramp * scene.crosswind_intensity * cross
    axis = np.array([math.sin(yaw), math.cos(yaw), 0.0])
    normal = np.array([math.cos(yaw), -math.sin(yaw), 0.0])
    wind = speed[:, None] * axis + side[:, None] * normal
    return wind, {"mean_speed_m_s": mean, "fan_yaw_deg": round(math.degrees(yaw), 4)}


def _xyaxes(pos, look_at) -> str:
    """MuJoCo ``xyaxes`` of a camera at ``pos`` looking at ``look_at`` with z up."""
    forward = np.subtract(look_at, pos)
    forward = forward / np.linalg.norm(forward)
    right = np.cross(forward, (0.0, 0.0, 1.0))
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    return " ".join(f"{v:.6f}" for v in (*right, *up))


def _rgb(values) -> str:
    return " ".join(f"{v:.3f}" for v in values)


def scene_mjcf(
    scene: EngineScene, fabric: EngineFabric, look: FabricLook | None = None, size: int = 112
) -> str:
    """MJCF of one fabric's scene: the flex cloth, its fan (via ``opt.wind``), floor and sky."""
    young, thickness, elastic2d = elastic_params(
        fabric.stretch_stiffness, scene.poisson, fabric.bend_stiffness
    )
    n = scene.vert_per_side
    spacing = scene.size / (n - 1)
    mass = fabric.density * scene.size**2
    # fluid drag area per vertex body = (2 * inertiabox)^2 = its share of the cloth's area
    inertiabox = scene.size / (2.0 * n)
    centre_z = scene.height - 0.5 * scene.size
    # the plate law applies its own forces (PlateDrag): MuJoCo's fluid model is then off
    air = AIR_DENSITY_KG_M3 if scene.wind_drag == "isotropic" else 0.0
    pins = " ".join(f"{i} {j}" for i, j in scene.pin_grid())
    visual = ""
    if look is not None:
        # a flat cloth's speckles are coarse texels (mottled, visible at 112 px); the others'
        # patterns are sharp
        texels = 16 if look.texture == "flat" else 256
        visual = f"""
  <visual>
    <global offwidth="{size}" offheight="{size}"/>
    <quality shadowsize="1024" offsamples="4"/>
    <headlight ambient="{look.ambient} {look.ambient} {look.ambient}" diffuse="0.25 0.25 0.25"
               specular="0 0 0"/>
  </visual>
  <asset>
    <texture name="sky" type="skybox" builtin="gradient" rgb1="{_rgb(look.sky_rgb1)}"
             rgb2="{_rgb(look.sky_rgb2)}" width="128" height="128"/>
    <texture name="floor" type="2d" builtin="checker" rgb1="{_rgb(look.floor_rgb1)}"
             rgb2="{_rgb(look.floor_rgb2)}" width="256" height="256"/>
    <material name="floor" texture="floor" texrepeat="{look.floor_repeat} {look.floor_repeat}"
              reflectance="0.05"/>
    <texture name="cloth" type="2d" builtin="{look.texture}" rgb1="{_rgb(look.cloth_rgb1)}"
             rgb2="{_rgb(look.cloth_rgb2)}" mark="random" random="{look.speckle}"
             markrgb="{_rgb(look.speckle_rgb)}" width="{texels}" height="{texels}"/>
    <material name="cloth" texture="cloth" texrepeat="{look.repeat} {look.repeat}"
              specular="{look.specular}" shininess="{look.shininess}"/>
  </asset>"""
    world = ""
    cloth_material = ""
    if look is not None:
        world = f"""
    <light type="directional" castshadow="true" dir="{_rgb(look.light_dir)}"
           diffuse="{look.light_diffuse} {look.light_diffuse} {look.light_diffuse}"
           specular="0.1 0.1 0.1"/>
    <geom type="plane" size="6 6 0.1" material="floor" contype="0" conaffinity="0"/>
    <camera name="view" pos="{_rgb(scene.camera_pos)}" fovy="{scene.camera_fovy_deg}"
            xyaxes="{_xyaxes(scene.camera_pos, scene.camera_look_at)}"/>"""
        cloth_material = ' material="cloth"'
    return f"""<mujoco model="independent_cloth">
  <compiler usethread="false"/>
  <statistic extent="2" center="0 0 0.8"/>
  <option timestep="{scene.max_dt!r}" integrator="discrete" solver="Newton"
          gravity="0 0 -9.81" wind="0 0 0" density="{air!r}"
          viscosity="{AIR_VISCOSITY_PA_S!r}"/>{visual}
  <worldbody>{world}
    <flexcomp name="cloth" type="grid" dim="2" count="{n} {n} 1"
              spacing="{spacing!r} {spacing!r} {spacing!r}" pos="0 0 {centre_z!r}"
              euler="90 0 0" mass="{mass!r}" inertiabox="{inertiabox!r}"
              radius="{min(1e-3, 0.1 * spacing)!r}"{cloth_material}>
      <contact contype="0" conaffinity="0" selfcollide="none"/>
      <elasticity young="{young!r}" poisson="{scene.poisson!r}" thickness="{thickness!r}"
                  elastic2d="{elastic2d}"/>
      <pin grid="{pins}"/>
    </flexcomp>
  </worldbody>
</mujoco>
"""


def _patch_pyopengl_egl() -> None:
    """Give PyOpenGL 3.1.0 (pinned by pyrender) the ``EGLDeviceEXT`` MuJoCo's EGL backend uses.

    Without it ``import mujoco`` under ``MUJOCO_GL=egl`` raises ``AttributeError``. It is
    defined as pyrender defines it, an opaque pointer type.
    """
    with contextlib.suppress(ImportError, OSError, AttributeError):
        from OpenGL import EGL

        if not hasattr(EGL, "EGLDeviceEXT"):
            from OpenGL._opaque import opaque_pointer_cls

            EGL.EGLDeviceEXT = opaque_pointer_cls("EGLDeviceEXT")


def import_mujoco(*, render: bool = True):
    """``mujoco``; with ``render``, set up for offscreen EGL rendering if imported here first.

    MuJoCo picks its OpenGL backend (``MUJOCO_GL``) when it is first imported: ``render``
    sets ``egl`` unless the environment names another. Without ``render`` (simulation only)
    the environment is left as it is, so no OpenGL state is touched.

    Keep pyrender out of a process that renders with MuJoCo: once PyOpenGL 3.1.0 has loaded
    ``OpenGL.EGL``, its EGL extension querier (a text prefix compared with bytes) makes
    pyrender's import raise ``TypeError``; making the prefix bytes instead gets pyrender to
    query EGL state MuJoCo left, which crashed the process (measured). Hence the tests
    render in a child process.
    """
    if "mujoco" not in sys.modules:
        if render:
            os.environ.setdefault("MUJOCO_GL", "egl")
        if os.environ.get("MUJOCO_GL", "").strip().lower() == "egl":
            os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
            _patch_pyopengl_egl()
    import mujoco

    return mujoco


def render_available() -> str | None:
    """``None`` if MuJoCo imports and renders offscreen here, else the reason it does not."""
    try:
        mujoco = import_mujoco()
    except (ImportError, OSError, AttributeError) as error:
        return f"cannot import mujoco: {error!r}"
    try:
        model = mujoco.MjModel.from_xml_string(
            "<mujoco><worldbody><geom type='sphere' size='0.1'/></worldbody></mujoco>"
        )
        with mujoco.Renderer(model, 16, 16) as renderer:
            renderer.update_scene(mujoco.MjData(model))
            renderer.render()
    except Exception as error:  # any GL failure means: no offscreen rendering here
        return f"mujoco cannot render offscreen (MUJOCO_GL={os.environ.get('MUJOCO_GL')}): {error}"
    return None


def _waviness(scene: EngineScene, rng: np.random.Generator, rest: np.ndarray) -> np.ndarray:
    """Smooth out-of-plane offsets [m] of the rest vertices (x-z plane), shape (V,)."""
    field = np.zeros(len(rest))
    for _ in range(4):
        angle = rng.uniform(0.0, math.pi)
        wavenumber = 2.0 * math.pi / rng.uniform(0.15, 0.5)
        direction = np.array([math.cos(angle), math.sin(angle)])
        phase = rng.uniform(0.0, 2.0 * math.pi)
        field += rng.normal() * np.cos(wavenumber * rest[:, [0, 2]] @ direction + phase)
    rms = float(np.sqrt(np.mean(field**2)))
    return field * (scene.waviness / rms if rms > 0 else 0.0)


class PlateDrag:
    """Flat-plate air drag on the flex triangles, applied as external forces on the vertices.

    Each triangle of area ``A`` and unit normal ``n`` in air of relative velocity ``u`` (wind
    minus the mean of its corners' velocities) feels ``0.5 rho A (C_n (u.n)|u.n| n + C_f |u_t|
    u_t)``, ``u_t`` the tangential part, a third on each corner: unlike MuJoCo's fluid model it
    sees the cloth's orientation, so a sheet edge-on to the wind feels only skin friction.
    Positions and velocities come from ``qpos`` and ``qvel`` (the state the next step starts
    from), so the force is explicit in the step.
    """

    def __init__(self, mujoco, model, data, scene: EngineScene):
        """``data`` must hold the rest state (``qpos`` zero, after ``mj_forward``)."""
        self._rest = np.array(data.flexvert_xpos)
        self._triangles = np.asarray(model.flex_elem).reshape(-1, 3)
        bodies = np.asarray(model.flex_vertbodyid)
        self._free = np.flatnonzero(bodies > 0)
        self._bodies = bodies[self._free]
        qadr, dadr, axes = [], [], []
        for body in self._bodies:
            joints = np.flatnonzero(model.jnt_bodyid == body)
            qadr.append(model.jnt_qposadr[joints])
            dadr.append(model.jnt_dofadr[joints])
            axes.append(np.array(data.xaxis[joints]))
        self._qadr, self._dadr = np.array(qadr), np.array(dadr)
        self._axes = np.array(axes)  # (free vertices, 3 slide joints, xyz)
        self._half_rho = 0.5 * AIR_DENSITY_KG_M3
        self._cn, self._cf = scene.plate_normal_cd, scene.plate_friction_cd

    def vertex_forces(self, qpos: np.ndarray, qvel: np.ndarray, wind: np.ndarray) -> np.ndarray:
        """Force [N] on every flex vertex, shape (V, 3) (pinned vertices' share included)."""
        pos = self._rest.copy()
        pos[self._free] += np.einsum("fj,fjk->fk", qpos[self._qadr], self._axes)
        vel = np.zeros_like(pos)
        vel[self._free] = np.einsum("fj,fjk->fk", qvel[self._dadr], self._axes)
        a, b, c = (pos[self._triangles[:, i]] for i in range(3))
        area_vector = 0.5 * np.cross(b - a, c - a)
        area = np.linalg.norm(area_vector, axis=1)
        normal = area_vector / np.maximum(area, 1e-12)[:, None]
        air = wind - vel[self._triangles].mean(axis=1)
        along = np.einsum("tk,tk->t", air, normal)
        tangential = air - along[:, None] * normal
        force = (
            self._half_rho
            * area[:, None]
            * (
                self._cn * (along * np.abs(along))[:, None] * normal
                + self._cf * np.linalg.norm(tangential, axis=1)[:, None] * tangential
            )
        )
        out = np.zeros_like(pos)
        for i in range(3):
            np.add.at(out, self._triangles[:, i], force / 3.0)
        return out

    def apply(self, data, wind: np.ndarray) -> None:
        """Set the free vertices' external forces for the next step in air velocity ``wind``."""
        force = self.vertex_forces(np.asarray(data.qpos), np.asarray(data.qvel), wind)
        data.xfrc_applied[self._bodies, :3] = force[self._free]


def _rollout(
    mujoco,
    model,
    data,
    scene: EngineScene,
    level: int,
    seed_key: list[int],
    *,
    fps: float,
    frames: int,
) -> Iterator[int]:
    """Settle, start the fan and step; yields each written frame's index (0 = first written).

    ``data`` holds that frame's state at each yield; the wind is :func:`_video_wind`'s.
    """
    mujoco.mj_resetData(model, data)
    mujoco.mj_forward(model, data)
    rest = np.array(data.flexvert_xpos)
    plate = PlateDrag(mujoco, model, data, scene) if scene.wind_drag == "plate" else None
    offsets = _waviness(scene, np.random.default_rng([*seed_key, _SHAPE_STREAM]), rest)
    bodies = np.asarray(model.flex_vertbodyid)
    for vert, body in enumerate(bodies):
        if body <= 0:
            continue  # pinned: part of the world
        for joint in np.flatnonzero(model.jnt_bodyid == body):
            # each free vertex has three orthonormal slide joints; y = out of plane
            data.qpos[model.jnt_qposadr[joint]] += offsets[vert] * data.xaxis[joint][1]
    still = np.zeros(3)
    mass = model.body_mass[model.dof_bodyid]
    model.opt.timestep = scene.settle_dt
    model.dof_damping[:] = mass / scene.settle_damping_time
    model.opt.wind[:] = 0.0
    for _ in range(math.ceil(scene.settle_time / scene.settle_dt - 1e-9)):
        if plate is not None:
            plate.apply(data, still)
        mujoco.mj_step(model, data)
    model.dof_damping[:] = 0.0
    data.qvel[:] = 0.0
    steps, dt = scene.record_steps(fps)
    model.opt.timestep = dt
    lead = scene.lead_in_frames(fps)
    total = lead + frames
    wind, _ = _video_wind(scene, level, seed_key, fps, total)
    mujoco.mj_forward(model, data)
    if lead == 0:
        yield 0
    for frame in range(1, total):
        for sub in range(steps):
            model.opt.wind[:] = wind[(frame - 1) * steps + sub]
            if plate is not None:
                plate.apply(data, model.opt.wind)
            mujoco.mj_step(model, data)
        if frame >= lead:
            # mj_step leaves the positions it derived before integrating: bring the flex
            # vertices (and so the render) to the frame's time
            mujoco.mj_fwdPosition(model, data)
            yield frame - lead


def _video_wind(
    scene: EngineScene, level: int, seed_key: list[int], fps: float, total: int
) -> tuple[np.ndarray, dict]:
    """The wind of one video at each recording step, shape ((total - 1) * steps, 3)."""
    steps, dt = scene.record_steps(fps)
    times = np.arange(max(1, (total - 1) * steps)) * dt
    return wind_history(scene, level, np.random.default_rng([*seed_key, _WIND_STREAM]), times)


def _video_key(seed: int, fabric: int, level: int) -> list[int]:
    return [seed, fabric, level]


def simulate_positions(
    fabric: EngineFabric,
    level: int,
    *,
    seed: int = 0,
    fps: float = TRAINING_FPS,
    frames: int = CLIPS_PER_VIDEO * CLIP_LEN,
    scene: EngineScene | None = None,
) -> np.ndarray:
    """Vertex positions [m] of the written frames of one video, shape (K, V, 3) (no render)."""
    mujoco = import_mujoco(render=False)
    scene = scene or EngineScene()
    model = mujoco.MjModel.from_xml_string(scene_mjcf(scene, fabric))
    data = mujoco.MjData(model)
    key = _video_key(seed, fabric.index, level)
    out = [
        np.array(data.flexvert_xpos)
        for _ in _rollout(mujoco, model, data, scene, level, key, fps=fps, frames=frames)
    ]
    return np.stack(out)


def out_of_plane_rms(pos: np.ndarray) -> float:
    """Mean over frames of the RMS distance [m] of the vertices from their best-fit plane."""
    values = []
    for frame in pos:
        centred = frame - frame.mean(axis=0)
        values.append(np.linalg.svd(centred, compute_uv=False)[2] / math.sqrt(len(frame)))
    return float(np.mean(values))


def edge_strain_rms(pos: np.ndarray, edges: np.ndarray, rest: np.ndarray) -> float:
    """RMS over frames and edges of the edge strain ``l / l0 - 1`` [-].

    The in-plane stretch that the membrane stiffness resists: ``pos`` (frames, V, 3),
    ``edges`` (E, 2) vertex pairs (MuJoCo's ``flex_edge``), ``rest`` (E,) rest lengths.
    """
    lengths = np.linalg.norm(pos[:, edges[:, 0]] - pos[:, edges[:, 1]], axis=-1)
    return float(np.sqrt(np.mean((lengths / rest - 1.0) ** 2)))


def default_frame_count(fps: float) -> int:
    """Frames for :data:`CLIPS_PER_VIDEO` clips of :data:`CLIP_LEN` at the training rate."""
    return CLIPS_PER_VIDEO * CLIP_LEN * max(1, round(fps / TRAINING_FPS))


def _frames_for_one_clip(fps: float) -> int:
    return (CLIP_LEN - 1) * max(1, round(fps / TRAINING_FPS)) + 1


@contextlib.contextmanager
def _native_stderr_silenced() -> Iterator[None]:
    """Silence what compiled code writes to file descriptor 2 (FFmpeg's encoder probing)."""
    sys.stderr.flush()
    try:
        saved = os.dup(2)
    except OSError:  # no descriptor 2: nothing to silence
        yield
        return
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def _open_writer(cv2, path_stem: Path, fourcc: str, fps: float, size: int):
    path = path_stem.with_suffix(_VIDEO_SUFFIXES[fourcc])
    with _native_stderr_silenced():
        writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), fps, (size, size))
    if not writer.isOpened():
        writer.release()
        path.unlink(missing_ok=True)
        return None, path
    return writer, path


def _choose_codec(requested: str, folder: Path, fps: float, size: int) -> dict:
    """The codec this OpenCV build encodes: the first of the request's fallbacks that works."""
    import cv2

    if requested == "png":
        return {
            "requested": "png",
            "used": "png",
            "fourcc": None,
            "container": "PNG frames",
            "note": "one folder of lossless PNG frames per video",
        }
    tried = []
    for fourcc in _CODEC_FALLBACKS[requested]:
        writer, path = _open_writer(cv2, folder / ".codec-probe", fourcc, fps, size)
        if writer is not None:
            writer.write(np.zeros((size, size, 3), np.uint8))
            writer.release()
            readable = path.is_file() and path.stat().st_size > 0
            path.unlink(missing_ok=True)
            if readable:
                note = (
                    f"{requested} asked for; {', '.join(tried)} not available in this "
                    f"OpenCV build ({cv2.__version__}), {fourcc} used"
                    if tried
                    else f"{fourcc} as asked"
                )
                return {
                    "requested": requested,
                    "used": fourcc,
                    "fourcc": fourcc,
                    "container": _VIDEO_SUFFIXES[fourcc].lstrip("."),
                    "note": note,
                }
        tried.append(fourcc)
    raise InputError(
        f"--codec {requested}: this OpenCV build ({cv2.__version__}) encodes none of "
        f"{', '.join(tried)}; use --codec png"
    )


def _digest(paths: list[Path]) -> str:
    digest = hashlib.sha256()
    for path in paths:
        digest.update(path.name.encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()


def _record_video(
    mujoco,
    cv2,
    model,
    renderer,
    scene: EngineScene,
    fabric: EngineFabric,
    level: int,
    seed: int,
    *,
    fps: float,
    frames: int,
    stem: Path,
    codec: dict,
) -> dict:
    """Simulate and render one video into ``stem`` (+ suffix); returns its ground truth."""
    data = mujoco.MjData(model)
    key = _video_key(seed, fabric.index, level)
    positions = []
    writer = None
    if codec["fourcc"] is None:
        stem.mkdir()
        path = stem
    else:
        writer, path = _open_writer(cv2, stem, codec["fourcc"], fps, renderer.width)
        if writer is None:
            raise OSError(f"could not open a {codec['used']} video writer for {path}")
    written = []
    try:
        for index in _rollout(mujoco, model, data, scene, level, key, fps=fps, frames=frames):
            positions.append(np.array(data.flexvert_xpos))
            renderer.update_scene(data, camera="view")
            bgr = np.ascontiguousarray(renderer.render()[..., ::-1])
            if writer is None:
                file = path / f"frame_{index:04d}.png"
                if not cv2.imwrite(str(file), bgr):
                    raise OSError(f"could not write {file}")
                written.append(file)
            else:
                writer.write(bgr)
    finally:
        if writer is not None:
            writer.release()
    if writer is not None:
        written = [path]
    pos = np.stack(positions)
    _, drawn = _video_wind(scene, level, key, fps, scene.lead_in_frames(fps) + frames)
    if not np.isfinite(pos).all():
        raise RuntimeError(f"MuJoCo's cloth blew up in {path.name} (fabric {fabric.index})")
    speed = np.linalg.norm(np.diff(pos, axis=0), axis=-1).mean() * fps if len(pos) > 1 else 0.0
    return {
        "video": stem.name,
        "file": path.name,
        "fabric": fabric.index,
        "wind": f"W{level + 1}",
        **drawn,
        "stiffness": fabric.stiffness,
        "stretch_stiffness_n_per_m": fabric.stretch_stiffness,
        "bend_stiffness_nm": fabric.bend_stiffness,
        "density_kg_m2": fabric.density,
        "frames": len(pos),
        "mean_vertex_speed_m_s": round(float(speed), 6),
        "out_of_plane_rms_m": round(out_of_plane_rms(pos), 7),
        "edge_strain_rms": round(
            edge_strain_rms(pos, np.asarray(model.flex_edge), np.asarray(model.flexedge_length0)),
            8,
        ),
        "sha256": _digest(written),
    }


_WIND_DRAG_TEXT = {
    "isotropic": "MuJoCo global fluid model (inertia-box, rho 1.2 kg/m^3) on the vertex "
    "bodies: isotropic quadratic drag of each vertex's area share, blind to the cloth normal",
    "plate": "flat-plate drag per flex triangle, applied as external vertex forces (explicit "
    "in MuJoCo's step; its fluid model off): normal pressure C_n {scene.plate_normal_cd:g} "
    "on the normal air speed squared plus skin friction C_f {scene.plate_friction_cd:g} on the "
    "tangential air speed, a third on each corner",
}


def _differences(scene: EngineScene, codec: dict, fps: float) -> dict:
    """Every difference from our scene, as ``{topic: {"ours": ..., "here": ...}}``."""
    speeds = ", ".join(f"{s:g}" for s in scene.wind_speeds)
    return {
        "engine": {
            "ours": "simulator.cloth: batched backward Euler, Newton + CG (torch)",
            "here": "MuJoCo flexcomp (dim 2), integrator 'discrete', solver Newton, "
            f"{scene.vert_per_side} x {scene.vert_per_side} vertices",
        },
        "material_law": {
            "ours": "Wang et al. 2011 anisotropic strain-stiffening membrane (k0..k3 rows) and "
            "measured direction/curvature-dependent dihedral bending",
            "here": "isotropic Saint Venant-Kirchhoff shell (elastic2d='both'): E t = "
            f"stretch_stiffness, Poisson {scene.poisson}, hinge bending D = E t^3 / "
            "(12 (1 - nu^2)) = bend_stiffness (sim2real.study.mujoco_flex mapping)",
        },
        "wind_model": {
            "ours": "normal pressure drag (C_d 1) of each vertex's area-weighted normal "
            "(a third of its triangles) on the relative air velocity",
            "here": _WIND_DRAG_TEXT[scene.wind_drag].format(scene=scene),
        },
        "wind": {
            "ours": "constant, 0.75 / 1.5 / 2.5 m/s along +y with +-15 deg yaw jitter, "
            "0.25 s smoothstep ramp after 1 s settling",
            "here": f"a fan: mean {speeds} m/s, axis yaw uniform +-{scene.fan_yaw_deg:g} deg, "
            f"exponential spin-up tau {scene.fan_spinup:g} s after {scene.settle_time:g}"
            f" s settling; gusts: along-wind x (1 + {scene.gust_intensity:g} g_u), "
            f"cross-wind {scene.crosswind_intensity:g} x mean x g_v, g smooth unit-"
            f"variance noise (two first-order low-passes of {scene.gust_time:g} s)",
        },
        "pinning": {
            "ours": "the two top corners",
            "here": "three top-edge vertices: both corners and the middle",
        },
        "mass_distribution": {
            "ours": "density x vertex area (a third of each adjacent triangle): edge and "
            "corner vertices lighter",
            "here": "flexcomp: equal mass per vertex (density x area / vertices); the pinned "
            "vertices' share is lost",
        },
        "initial_shape": {
            "ours": "flat plus uniform +-1 mm per-vertex out-of-plane noise, damped settle "
            "+ static solve",
            "here": f"smooth random waviness {scene.waviness * 1e3:g} mm RMS (4 plane waves, "
            f"0.15-0.5 m), damped settle (vertex damping mass / "
            f"{scene.settle_damping_time:g} s, dt {scene.settle_dt:.4g} s), "
            "damping then off",
        },
        "renderer": {
            "ours": "pyrender (render.renderer.ClothRenderer)",
            "here": "mujoco.Renderer over EGL: OpenGL rasteriser, 4x MSAA, shadow map",
        },
        "texture": {
            "ours": "procedural textures of render.textures (grid / colour / random)",
            "here": "MuJoCo builtin 2D texture (checker 50 %, flat 25 %, gradient 25 %) with "
            "random speckles, colours and repeats drawn per fabric",
        },
        "backdrop": {
            "ours": "2D procedural backgrounds (render.backgrounds: gradient, room, shapes)",
            "here": "3D floor plane with a builtin checker (grey tints drawn per fabric) under "
            "a gradient skybox; the cloth casts a shadow on the floor",
        },
        "lighting": {
            "ours": "render.lights.LightSpec: camera-frame key light + ambient",
            "here": "one world directional light with shadows (azimuth +-50 deg, elevation "
            "40-70 deg, diffuse 0.5-0.9) plus MuJoCo's headlight (ambient 0.15-0.35)",
        },
        "camera": {
            "ours": "CameraSpec.wind: pos (0.22, 1.66, 2.06), look at (-0.04, 0.20, 0.81), "
            "fovy 30 deg",
            "here": f"pos {scene.camera_pos}, look at {scene.camera_look_at}, fovy "
            f"{scene.camera_fovy_deg:g} deg (mirrored azimuth)",
        },
        "codec": {"ours": "PNG frames (sealed sets) / uint8 shards", "here": codec["note"]},
        "frame_rate": {
            "ours": f"{TRAINING_FPS:g} fps",
            "here": f"{fps:g} fps, physics dt {scene.record_steps(fps)[1]:.5g} s "
            f"({scene.record_steps(fps)[0]} steps per frame)",
        },
        "lead_in": {
            "ours": "frame 0 = rest at the wind's start; 0.4 s dropped (sealed sets)",
            "here": f"frame 0 = rest at the fan's start; {scene.lead_in:g} s "
            f"({scene.lead_in_frames(fps)} frames) dropped",
        },
    }


def write_independent_set(
    out: str | Path,
    *,
    fabrics: int = 30,
    winds: int = 3,
    seed: int = 0,
    size: int = 112,
    frames: int | None = None,
    fps: float = TRAINING_FPS,
    codec: str = "h264",
    overwrite: bool = False,
    progress: bool = True,
    scene: EngineScene | None = None,
    on_video: Callable[[dict], None] | None = None,
) -> dict:
    """Write the independent-engine footage folder ``out`` and ``out.engine.json``.

    Args:
        out: The folder to write (refused if it exists, unless ``overwrite``).
        fabrics: Fabrics drawn (30 as in Bouman et al. 2013).
        winds: Wind levels filmed per fabric (1: W2; 2: W1, W3; 3: W1-W3).
        seed: Decides every draw (fabrics, looks, gusts, shapes).
        size: Side of the square frames [px].
        frames: Frames written per video (default: :func:`default_frame_count`).
        fps: Frame rate [1/s].
        codec: ``h264`` (falls back to mp4v, then MJPG), ``mjpeg`` or ``png``.
        overwrite: Replace an existing ``out``.
        progress: Show a progress bar with the ETA.
        scene: The engine's scene constants (default :class:`EngineScene`).
        on_video: Called with each video's ground truth once it is written.

    Returns:
        The engine description written to ``out.engine.json``.
    """
    fabrics = check_int(fabrics, "--fabrics", 1, 1000)
    winds = check_int(winds, "--winds", 1, 3)
    seed = check_int(seed, "--seed", 0, 2**32 - 1)
    size = check_int(size, "--size", 16, 1024)
    fps = check_float(fps, "--fps", 1.0, 240.0)
    needed = _frames_for_one_clip(fps)
    if frames is None:
        frames = default_frame_count(fps)
    frames = check_int(frames, "--frames", needed, 100_000)
    codec = check_choice(codec, "--codec", CODECS)
    out = check_output_dir(out, "--out")
    if out.exists() and not overwrite:
        raise InputError(f"--out: {out} exists; choose another folder or pass --overwrite")
    scene = scene or EngineScene()
    check_choice(scene.wind_drag, "--wind-drag", WIND_DRAGS)
    engine_path = out.with_name(out.name + ".engine.json")

    import cv2
    from tqdm import tqdm

    mujoco = import_mujoco()
    reason = render_available()
    if reason is not None:  # e.g. mujoco was imported earlier in this process without EGL
        raise RuntimeError(f"{reason}; run the command in a fresh process (MUJOCO_GL=egl)")
    cv2.setNumThreads(1)
    ranges = measured_ranges()
    levels = WIND_LEVELS[winds]
    videos = []
    rows = [
        "video,stiffness,density,wind,fps,fabric,stretch_stiffness,bend_stiffness,"
        "vertex_speed,out_of_plane_rms,edge_strain_rms"
    ]
    with staged_folder(out, replace=overwrite) as stage:
        chosen = _choose_codec(codec, stage, fps, size)
        bar = tqdm(
            total=fabrics * len(levels),
            desc="independent engine",
            unit="video",
            smoothing=0.0,
            disable=not progress,
        )
        try:
            for f in range(fabrics):
                fabric = draw_fabric(seed, f, ranges)
                look = draw_look(seed, f)
                model = mujoco.MjModel.from_xml_string(scene_mjcf(scene, fabric, look, size))
                with mujoco.Renderer(model, size, size) as renderer:
                    for level in levels:
                        name = f"v{len(videos):03d}"
                        truth = _record_video(
                            mujoco,
                            cv2,
                            model,
                            renderer,
                            scene,
                            fabric,
                            level,
                            seed,
                            fps=fps,
                            frames=frames,
                            stem=stage / name,
                            codec=chosen,
                        )
                        truth["look"] = dataclasses.asdict(look)
                        videos.append(truth)
                        rows.append(
                            f"{name},{fabric.stiffness:.6g},{fabric.density:.6g},W{level + 1},"
                            f"{fps:g},f{f:02d},{fabric.stretch_stiffness:.6g},"
                            f"{fabric.bend_stiffness:.6g},{truth['mean_vertex_speed_m_s']:.6g},"
                            f"{truth['out_of_plane_rms_m']:.6g},{truth['edge_strain_rms']:.6g}"
                        )
                        bar.update(1)
                        if on_video is not None:
                            on_video(truth)
        finally:
            bar.close()
        (stage / "labels.csv").write_text("\n".join(rows) + "\n")
    arguments = {
        "fabrics": fabrics,
        "winds": winds,
        "seed": seed,
        "size": size,
        "frames": frames,
        "fps": fps,
        "codec": codec,
        "wind_drag": scene.wind_drag,
    }
    engine = {
        "engine": "mujoco",
        "mujoco_version": mujoco.__version__,
        "opencv_version": cv2.__version__,
        "arguments": arguments,
        "codec": chosen,
        "frame_rate": fps,
        "frames_per_video": frames,
        "lead_in_frames": scene.lead_in_frames(fps),
        "labels": {
            "stiffness": "bend multiplier: bend_stiffness / mean bending of camel-ponte-roma "
            f"({ranges['basis_bend'][0]:.6g} N·m), as the sealed sets' stiffness",
            "density": "areal density [kg/m²]",
            "stretch_stiffness": "flex membrane E t [N/m]",
            "bend_stiffness": "flex hinge bending D [N·m]",
            "fabric": "group: the winds of one fabric",
        },
        "fabric_draw": {
            "rule": "log-uniform, independently per quantity, over the ten measured fabrics' "
            "range; fabric i from (seed, i) alone",
            "ranges": {k: list(v) for k, v in ranges.items() if k != "basis_bend"},
        },
        "differences": _differences(scene, chosen, fps),
        "scene": dataclasses.asdict(scene),
        "videos": videos,
    }
    atomic_write_bytes(engine_path, (json.dumps(engine, indent=2) + "\n").encode())
    return engine


@report_user_errors
def main(argv: list[str] | None = None) -> None:
    """Command line: write the independent-engine footage folder and its engine JSON."""
    parser = argparse.ArgumentParser(
        prog="python -m sim2real.study.independent", description=__doc__.split("\n")[0]
    )
    parser.add_argument("--out", required=True, help="folder to write (videos + labels.csv)")
    parser.add_argument("--fabrics", default="30", help="fabrics drawn (default 30)")
    parser.add_argument("--winds", default="3", help="wind levels per fabric, 1-3 (default 3)")
    parser.add_argument("--seed", default="0", help="decides every draw (default 0)")
    parser.add_argument("--size", default="112", help="square frame side [px] (default 112)")
    parser.add_argument(
        "--frames", default=None, help="frames per video (default: 4 clips of 10 at 15 fps: 40)"
    )
    parser.add_argument("--fps", default="15", help="frame rate (default 15)")
    parser.add_argument(
        "--codec",
        default="h264",
        help=f"one of {', '.join(CODECS)} (h264 falls back to mp4v, then MJPG; default h264)",
    )
    parser.add_argument(
        "--wind-drag",
        default="isotropic",
        help=f"air drag law, one of {', '.join(WIND_DRAGS)} (isotropic: MuJoCo's fluid model, "
        "blind to the cloth's normal; plate: flat-plate drag per triangle; default isotropic)",
    )
    parser.add_argument("--overwrite", action="store_true", help="replace an existing --out")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    args = parser.parse_args(argv)
    fps = check_float(args.fps, "--fps", 1.0, 240.0)
    drag = check_choice(args.wind_drag, "--wind-drag", WIND_DRAGS)
    engine = write_independent_set(
        args.out,
        fabrics=check_int(args.fabrics, "--fabrics", 1, 1000),
        winds=check_int(args.winds, "--winds", 1, 3),
        seed=check_int(args.seed, "--seed", 0),
        size=check_int(args.size, "--size", 16, 1024),
        frames=None if args.frames is None else check_int(args.frames, "--frames", 1),
        fps=fps,
        codec=args.codec,
        overwrite=args.overwrite,
        progress=not args.no_progress,
        scene=EngineScene(wind_drag=drag),
    )
    codec, frames = engine["codec"]["used"], engine["frames_per_video"]
    print(
        f"independent set: {args.out} ({len(engine['videos'])} videos, codec {codec}, "
        f"{frames} frames at {fps:g} fps)"
    )
    print(f"engine: {Path(args.out).with_name(Path(args.out).name + '.engine.json')}")


if __name__ == "__main__":
    main()
