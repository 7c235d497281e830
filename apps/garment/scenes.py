"""Synthetic evaluation scenes (*thesis* Fig. 6.11) and the scene camera, lights and renderer.

A scene is a fixed body (the default :class:`~.body.BodyShape`) in a pose wearing garments
of known sizing G and material C, draped to static equilibrium and rendered from a fixed
camera under one of two lightings, ``midday`` (white light from high in front) and
``sunset`` (warm, low light from the side). The evaluation set (:data:`SCENES`) has the
*thesis*'s ten: poses a, b, c with a t-shirt and pants, and a skirt of low and high bending
stiffness, each under both lightings.

Rendering goes through :class:`render.ClothRenderer` (imported when first needed): the body's
capsules in skin colour, every garment a plain colour. The visible mask of each garment is
found by rendering the scene once more with that garment's colour changed: the pixels that
change are exactly where it is seen (renders are deterministic).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from simulator.garment.body import Mannequin, Pose
from simulator.garment.patterns import GarmentType

__all__ = [
    "GARMENT_COLORS",
    "LIGHTINGS",
    "POSES",
    "REGIONS",
    "SCENES",
    "SceneGarment",
    "SceneSpec",
    "pixel_size",
    "primitive_regions",
    "render_scene",
    "scene_camera",
    "scene_light",
]

DEFAULT_IMAGE_SIZE = 320
"""Width and height of scene images [px] (6.4 mm per pixel at the body)."""
CAMERA_DISTANCE = 4.3
"""Distance of the camera from the body's vertical axis [m]."""

GARMENT_COLORS: dict[str, tuple[int, int, int]] = {
    "tshirt": (196, 62, 52),
    "pants": (58, 78, 150),
    "skirt": (64, 150, 96),
}
"""sRGB colour of each garment type in the synthetic scenes."""

REGIONS: dict[str, dict[str, tuple[str, ...]]] = {
    "skirt": {"skirt": ("torso", "thigh", "lower_thigh", "shin")},
    "pants": {"seat": ("torso",), "thighs": ("thigh", "lower_thigh"), "shins": ("shin",)},
    "tshirt": {"body": ("torso", "shoulders"), "sleeves": ("upper_arm",)},
}
"""Curvature regions of each garment: region name -> body primitives (by name prefix) it
gathers (*thesis* §6.4.2 defines regions by contact with the body's joints)."""


def primitive_regions(body: Mannequin, garment: str) -> np.ndarray:
    """Region id of each body primitive for ``garment`` (-1: no region), int (C,)."""
    table = REGIONS[GarmentType(garment).value]
    out = np.full(len(body.primitives), -1, dtype=np.int64)
    for c, prim in enumerate(body.primitives):
        for r, prefixes in enumerate(table.values()):
            if any(prim.name == p or prim.name.startswith(p + "_") for p in prefixes):
                out[c] = r
    return out


def vertex_regions(pos: np.ndarray, capsules: np.ndarray, regions: np.ndarray) -> np.ndarray:
    """Region of each vertex: the nearest body primitive's that has one, int (V,)."""
    from simulator.garment.body import capsule_distance

    dist, _ = capsule_distance(np.asarray(pos, np.float64), capsules)
    dist = np.where(regions[None] >= 0, dist, np.inf)
    return regions[np.argmin(dist, axis=1)]


def scene_camera(size: int = DEFAULT_IMAGE_SIZE):
    """The fixed camera: in front of the body (at -y), framing a standing adult."""
    from render.camera import CameraSpec

    return CameraSpec(
        position=(0.0, -CAMERA_DISTANCE, 1.0),
        look_at=(0.0, 0.0, 0.9),
        up=(0.0, 0.0, 1.0),
        yfov_deg=26.0,
        width=size,
        height=size,
    )


def pixel_size(camera, depth: float = CAMERA_DISTANCE) -> float:
    """Metres per pixel at ``depth`` [m] from the camera."""
    focal = 0.5 * camera.height / np.tan(np.radians(camera.yfov_deg) / 2)
    return float(depth / focal)


LIGHTINGS = ("midday", "sunset")


def scene_light(name: str):
    """The lighting of a scene: ``midday`` or ``sunset`` (world-frame key light + ambient)."""
    from render.lights import LightFrame, LightSpec

    if name == "midday":
        return LightSpec(
            direction=(0.25, 0.55, -0.8),
            frame=LightFrame.WORLD,
            intensity=3.2,
            color=(1.0, 0.98, 0.95),
            ambient_intensity=0.35,
            ambient_color=(0.9, 0.95, 1.0),
        )
    if name == "sunset":
        return LightSpec(
            direction=(-0.85, 0.45, -0.28),
            frame=LightFrame.WORLD,
            intensity=2.6,
            color=(1.0, 0.68, 0.42),
            ambient_intensity=0.28,
            ambient_color=(0.75, 0.7, 0.85),
        )
    raise ValueError(f"lighting must be one of {', '.join(LIGHTINGS)}; got {name!r}")


def _texture(colors: list[tuple[int, int, int]], size: int = 64) -> np.ndarray:
    """A texture with one vertical stripe of plain colour per garment, uint8 (S*n, S*n, 3)."""
    n = len(colors)
    tex = np.zeros((size * n, size * n, 3), np.uint8)
    for k, c in enumerate(colors):
        tex[:, k * size : (k + 1) * size] = c
    return tex


def render_scene(
    camera,
    lights,
    capsules: np.ndarray,
    garments: list[tuple[np.ndarray, np.ndarray, tuple[int, int, int]]],
    *,
    background: tuple[int, int, int] = (226, 226, 222),
    masks: bool = True,
    renderer=None,
    body_inset: float = 0.003,
) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
    """Render a body and its garments.

    Args:
        camera: a :class:`render.CameraSpec`.
        lights: a :class:`render.LightSpec`.
        capsules: the posed body ``[p0, p1, r]`` [m], shape (C, 7).
        garments: per garment ``(pos (V, 3) [m], tri (F, 3), sRGB colour)``.
        background: plain background colour.
        masks: also find each garment's visible pixels (one extra render per garment).
        renderer: a :class:`render.ClothRenderer` to reuse (its camera and lights are used).
        body_inset: the capsules are drawn this much thinner [m], inside the clearance the
            drape keeps (so no primitive shows through the cloth between its vertices).

    Returns:
        ``(image uint8 (H, W, 3), person mask bool (H, W), [garment mask bool (H, W)])``.
    """
    from render.renderer import ClothRenderer

    own = renderer is None
    if own:
        renderer = ClothRenderer(camera, lights)
    try:
        # One mesh; garment k samples stripe k of the texture (the renderer maps the uv
        # extent onto the texture: u = k lands on stripe k's column).
        pos, tri, uv, offset = [], [], [], 0
        n = len(garments)
        for k, (p, t, _) in enumerate(garments):
            pos.append(np.asarray(p, np.float64))
            tri.append(np.asarray(t) + offset)
            # Spread inside the stripe: constant coordinates would sample the coarsest mipmap.
            span = np.asarray(p, np.float64)[:, [0, 2]]
            span = (span - span.min(0)) / max(float(np.ptp(span)), 1e-9)
            uv.append(np.stack([k + 0.2 + 0.6 * span[:, 0], 0.2 + 0.6 * span[:, 1]], -1))
            offset += len(p)
        all_pos, all_uv, all_tri = np.concatenate(pos), np.concatenate(uv), np.concatenate(tri)
        bg = np.empty((camera.height, camera.width, 3), np.uint8)
        bg[:] = background
        rng = np.random.default_rng(0)
        colors = [c for _, _, c in garments]
        drawn = np.array(capsules, dtype=np.float64, copy=True)
        drawn[:, 6] = np.maximum(drawn[:, 6] - body_inset, 0.5 * drawn[:, 6])

        def draw(cols):
            return renderer.render_clip(
                all_pos[None],
                all_tri,
                all_uv,
                _texture(cols),
                bg,
                capsules=drawn[None],
                rng=rng,
                coverage=True,
            )

        frames, alpha = draw(colors)
        image = frames[0]
        person = alpha[0] > 127
        found = []
        if masks:
            for k in range(n):
                other = list(colors)
                other[k] = tuple(255 - v for v in colors[k])
                frames_k, _ = draw(other)
                diff = np.abs(frames_k[0].astype(np.int16) - image.astype(np.int16)).max(-1)
                found.append(diff > 24)
        return image, person, found
    finally:
        if own:
            renderer.close()


# ---------------------------------------------------------------------------------- scenes

POSES: dict[str, Pose] = {
    "a": Pose.from_dict(
        {
            "shoulder_r": [0, -68, 0],
            "shoulder_l": [0, 68, 0],
            "elbow_r": [0, -12, 6],
            "elbow_l": [0, 12, -6],
        }
    ),
    "b": Pose.from_dict(
        {
            "shoulder_r": [0, -70, 0],
            "shoulder_l": [0, 70, 0],
            "elbow_r": [0, -10, 0],
            "elbow_l": [0, 10, 0],
            "hip_r": [-12, 9, 0],
            "hip_l": [8, -9, 0],
            "knee_r": [18, 0, 0],
            "knee_l": [6, 0, 0],
        }
    ),
    "c": Pose.from_dict(
        {
            "shoulder_r": [0, -45, 8],
            "shoulder_l": [0, 40, -8],
            "elbow_r": [0, -40, 0],
            "elbow_l": [0, 35, 0],
        }
    ),
}
"""The three evaluation poses (*thesis* Fig. 6.11 a-c; joint angles in degrees)."""


@dataclasses.dataclass(frozen=True)
class SceneGarment:
    """One garment of a scene with its ground truth."""

    garment: str
    params: dict[str, float]
    """Sizing G."""
    material: dict[str, float]
    """Material C: ``bend`` and ``stretch`` multipliers."""


@dataclasses.dataclass(frozen=True)
class SceneSpec:
    """One synthetic evaluation scene."""

    name: str
    pose: str
    """Key of :data:`POSES`."""
    lighting: str
    garments: tuple[SceneGarment, ...]

    def pose_angles(self) -> np.ndarray:
        """Joint angles [deg], shape (15, 3)."""
        return POSES[self.pose].angles


_TSHIRT = SceneGarment(
    "tshirt",
    {"r": 0.09, "w1": 0.16, "w2": 0.50, "h1": 0.33, "h2": 0.64, "l1": 0.22},
    {"bend": 8.0, "stretch": 1.5},
)
_PANTS = SceneGarment(
    "pants",
    {"w1": 0.78, "w2": 1.06, "w3": 0.44, "w4": 0.38, "h1": 0.95, "h2": 0.34, "h3": 0.27},
    {"bend": 40.0, "stretch": 3.0},
)
_SKIRT_G = {"l1": 0.37, "r1": 0.75, "r2": 0.42, "alpha": 0.78}
_SKIRT_POSE = "a"

SCENES: tuple[SceneSpec, ...] = (
    *(
        SceneSpec(f"{pose}_{light}", pose, light, (_TSHIRT, _PANTS))
        for pose in ("a", "b", "c")
        for light in LIGHTINGS
    ),
    *(
        SceneSpec(
            f"skirt_{kind}_{light}",
            _SKIRT_POSE,
            light,
            (SceneGarment("skirt", _SKIRT_G, {"bend": bend, "stretch": stretch}),),
        )
        for kind, bend, stretch in (("low", 3.0, 1.0), ("high", 60.0, 2.0))
        for light in LIGHTINGS
    ),
)
"""The ten evaluation scenes of *thesis* Tables 6.1-6.3."""

LAYER_ORDER = ("pants", "skirt", "tshirt")
"""Garments are draped inner layer first."""
LAYER_INFLATE = 0.015
"""An outer garment drapes over the body's primitives that an inner one covers made this much
thicker [m] (the inner garment as an obstacle, without cloth-cloth contact)."""
COVERS: dict[str, tuple[str, ...]] = {"pants": ("torso", "thigh", "lower_thigh")}
"""Body primitives (name prefixes) an inner garment covers for the layers over it."""


def drape_scene(
    scene: SceneSpec, body: Mannequin, edge_length: float, settings=None
) -> dict[str, tuple]:
    """Drape a scene's garments, inner first; ``{garment: (pattern, DrapeResult)}``."""
    from simulator.garment.drape import (
        DrapeSettings,
        GarmentBatch,
        drape,
        garment_material,
        register_batch,
    )
    from simulator.garment.patterns import PatternTopology, build_pattern

    settings = settings or DrapeSettings(max_steps=200)
    angles = scene.pose_angles()[None]
    caps = body.capsules(angles)
    out: dict[str, tuple] = {}
    covered: set[str] = set()
    order = sorted(scene.garments, key=lambda g: LAYER_ORDER.index(g.garment))
    for sg in order:
        topo = PatternTopology.build(sg.garment, edge_length)
        pattern = build_pattern(sg.garment, sg.params, topology=topo)
        x0 = register_batch(topo, pattern.coords[None], [pattern.params], body, angles)
        obstacle = layer_obstacle(body, caps, covered)
        mat = garment_material([sg.material["bend"]], [sg.material["stretch"]])
        batch = GarmentBatch.build(topo, pattern.coords[None], mat, obstacle, settings, pos_hint=x0)
        out[sg.garment] = (pattern, drape(batch, x0, settings))
        covered |= set(COVERS.get(sg.garment, ()))
    return out


def layer_obstacle(body: Mannequin, capsules: np.ndarray, covered) -> np.ndarray:
    """Capsules (B, C, 7) as an outer garment meets them: thicker where an inner one lies.

    ``covered``: name prefixes of the primitives an inner garment covers; those are made
    :data:`LAYER_INFLATE` thicker.
    """
    obstacle = capsules.copy()
    for c, prim in enumerate(body.primitives):
        if any(prim.name.startswith(p) for p in covered):
            obstacle[:, c, 6] += LAYER_INFLATE
    return obstacle
