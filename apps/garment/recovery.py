"""Garment recovery from one image: body fit, Alg. 3 (sizing G and material C), Alg. 4 (pose).

Steps (*thesis* §6.4-6.6; where this differs from the *thesis* it says why):

1. **Person and skin.** The person is cut from the background (given, or GrabCut), skin is
   told from clothes by a colour model learnt on the head (the top of the person).
2. **Body** (:func:`fit_body`): a swarm fits the mannequin's visible joint angles, height and
   placement to the silhouettes: the body must stay inside the person and cover the skin
   (*thesis*: user-marked joints plus a statistical body; here no user input).
3. **Light** (:func:`estimate_light`): a Lambertian fit of the skin's shading on the fitted
   body's normals gives the key light's direction and its ratio to the ambient light.
4. **Garment targets** (:class:`GarmentTarget`): the garment mask (given, or GrabCut seeded
   by the fitted body), the silhouette (Eq. 6.11) and the regional wrinkle density P.
5. **Alg. 3**: rounds alternating a material swarm (C: bend and stretch multipliers) and a
   sizing swarm (G), each particle one instance of one batched drape, warm-started from the
   best drape so far. The sizing objective is the silhouette distance (Eq. 6.10). The
   material objective is Eq. 6.5, the regional curvature K against the target ``I(P)`` of
   Eq. 6.6, where the map ``I`` from wrinkle density to curvature is the linear fit to the
   (rendered P, simulated K) pairs of the swarm's own drapes, rendered under the estimated
   light (the *thesis*'s fixed end points ``I(1) = 1e-4``, ``I(50) = 1e5`` fit no real
   camera or light); the silhouette term of Eq. 6.12 is added because the stretch multiplier
   changes the garment's length more than its wrinkles.
6. **Alg. 4**: rounds of a pose swarm (the fitted angles plus bounded changes, Eq. 6.14: the
   curvature term and the body-silhouette term, so the pose stays true to the image) and a
   material swarm (Eq. 6.15).

Particles are evaluated as one batch (B = swarm size); the incumbent best is always one of the
particles, so no round makes the result worse.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Sequence

import numpy as np
import torch

from common.errors import InputError
from simulator.calibrate.pso import ParticleSwarm
from simulator.garment.body import JOINTS, BodyShape, Mannequin, Pose, joint_angle_errors
from simulator.garment.curvature import regional_curvature
from simulator.garment.drape import (
    MATERIAL_SPECS,
    DrapeSettings,
    GarmentBatch,
    drape,
    garment_material,
    register_batch,
)
from simulator.garment.patterns import (
    GarmentType,
    Pattern,
    PatternTopology,
    check_params,
    default_params,
    from_search,
    search_box,
    to_search,
)
from simulator.garment.resample import resample_positions
from simulator.garment.skinning import push_out

from .image import (
    SilhouetteTarget,
    capsule_mask,
    mesh_mask,
    parse_garment,
    parse_person,
    region_map,
    wrinkle_density,
)
from .scenes import (
    COVERS,
    LAYER_ORDER,
    REGIONS,
    layer_obstacle,
    pixel_size,
    primitive_regions,
    vertex_regions,
)

__all__ = [
    "BODY_SEARCH",
    "BodyFit",
    "GarmentTarget",
    "LightEstimate",
    "RecoveryResult",
    "RecoverySettings",
    "accuracy",
    "check_under",
    "estimate_light",
    "fit_body",
    "inner_layers",
    "recover_garment",
    "skin_mask",
]

BODY_SEARCH: tuple[tuple[str, int, float, float], ...] = (
    ("shoulder_r", 1, -95.0, 5.0),
    ("shoulder_r", 2, -25.0, 25.0),
    ("shoulder_l", 1, -5.0, 95.0),
    ("shoulder_l", 2, -25.0, 25.0),
    ("elbow_r", 1, -70.0, 10.0),
    ("elbow_r", 2, -25.0, 25.0),
    ("elbow_l", 1, -10.0, 70.0),
    ("elbow_l", 2, -25.0, 25.0),
    ("hip_r", 0, -30.0, 20.0),
    ("hip_r", 1, -8.0, 20.0),
    ("hip_l", 0, -30.0, 20.0),
    ("hip_l", 1, -20.0, 8.0),
    ("knee_r", 0, 0.0, 40.0),
    ("knee_l", 0, 0.0, 40.0),
)
"""Joint angles the body fit searches: (joint, axis, low, high) [deg]; the others stay 0."""

OUTER_GARMENTS = frozenset({"tshirt"})
"""Garments worn over the others (the rest are inner layers)."""

PRIOR_WEIGHT = 0.03
"""Weight of the body fit's prior on out-of-plane angles, per (30 deg)²."""

GARMENT_PRIMITIVES = {
    "skirt": ("torso", "thigh", "lower_thigh"),
    "pants": ("torso", "thigh", "lower_thigh", "shin"),
    "tshirt": ("torso", "shoulders", "upper_arm"),
}
"""Body primitives (name prefixes) a garment is expected to cover: seeds its parsing."""


@dataclasses.dataclass(frozen=True)
class RecoverySettings:
    """Swarm sizes, iteration counts, resolution and drape settings of a recovery."""

    edge_length: float = 0.05
    """Target edge length of the garment mesh [m]."""
    material_edge_length: float | None = None
    """Edge length of the drapes whose wrinkles the material and pose steps compare [m];
    None: ``edge_length``. Wrinkles need a finer mesh than the silhouette does."""
    swarm_size: int = 12
    """Particles per garment swarm (*thesis*: 40); each is one instance of a batched drape."""
    rounds: int = 3
    """Alternations of Alg. 3 (*thesis*: about four)."""
    sizing_iters: int = 4
    material_iters: int = 2
    joint_rounds: int = 1
    """Alternations of Alg. 4."""
    pose_iters: int = 2
    pose_range_deg: float = 8.0
    """Largest change of a fitted joint angle in Alg. 4 [deg]."""
    body_swarm: int = 40
    body_iters: int = 250
    silhouette_weight: float = 0.02
    """Weight of the silhouette term (per px) in the material and pose objectives."""
    drape_steps: int = 30
    """Step cap of a warm-started drape (a particle's evaluation)."""
    drape_speed_tol: float = 0.02
    """Stopping test of a particle's drape [m/s] (:class:`DrapeSettings.speed_tol`)."""
    first_drape_steps: int = 200
    """Step cap of the first drape, from the registered garment."""
    seed: int = 0

    def __post_init__(self):
        for name in ("swarm_size", "body_swarm"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 2:
                raise InputError(f"recovery.{name} must be an integer >= 2, got {value!r}")
        for name in (
            "rounds",
            "sizing_iters",
            "material_iters",
            "pose_iters",
            "body_iters",
            "drape_steps",
            "first_drape_steps",
            "joint_rounds",
        ):
            value = getattr(self, name)
            low = 0 if name == "joint_rounds" else 1
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise InputError(f"recovery.{name} must be an integer >= {low}, got {value!r}")
        for name in ("edge_length", "material_edge_length"):
            value = getattr(self, name)
            if value is None and name == "material_edge_length":
                continue
            if (
                isinstance(value, bool)
                or not isinstance(value, (int, float))
                or not (math.isfinite(value) and 0.02 <= value <= 0.1)
            ):
                raise InputError(f"recovery.{name} must lie in [0.02, 0.1] m, got {value!r}")

    def planned_iterations(self) -> int:
        """Swarm iterations of the whole recovery (for the progress bar)."""
        alg3 = self.rounds * (self.material_iters + self.sizing_iters)
        alg4 = self.joint_rounds * (self.pose_iters + self.material_iters)
        return alg3 + alg4


# ------------------------------------------------------------------------------ body fit


def skin_mask(image: np.ndarray, person: np.ndarray, *, head_fraction: float = 0.07):
    """Skin pixels of the person: a Gaussian chroma model learnt on the head, bool (H, W)."""
    import cv2

    rows = np.nonzero(person.any(axis=1))[0]
    if len(rows) == 0:
        return np.zeros_like(person)
    top, height = rows[0], rows[-1] - rows[0] + 1
    head = person.copy()
    head[top + max(int(head_fraction * height), 3) :] = False
    lab = cv2.cvtColor(np.asarray(image, np.uint8), cv2.COLOR_RGB2LAB).astype(np.float64)
    samples = lab[head][:, 1:]
    if len(samples) < 10:
        return np.zeros_like(person)
    mean = samples.mean(0)
    cov = np.cov(samples.T) + np.eye(2) * 4.0
    diff = lab[..., 1:] - mean
    d2 = np.einsum("...i,ij,...j->...", diff, np.linalg.inv(cov), diff)
    return person & (d2 < 9.0)


@dataclasses.dataclass(frozen=True)
class BodyFit:
    """The fitted body."""

    shape: BodyShape
    pose: Pose
    offset: np.ndarray
    """Placement of the mannequin [m], shape (3,)."""
    loss: float

    def mannequin(self) -> Mannequin:
        """The mannequin of this fit."""
        return Mannequin.build(self.shape, self.offset)


def _body_from_x(x: np.ndarray, base: BodyShape) -> tuple[BodyShape, np.ndarray, np.ndarray]:
    shape = dataclasses.replace(base, height=float(x[0]))
    offset = np.array([x[1], 0.0, x[2]])
    angles = np.zeros((len(JOINTS), 3))
    for k, (joint, axis, _, _) in enumerate(BODY_SEARCH):
        angles[JOINTS.index(joint), axis] = x[3 + k]
    return shape, offset, angles


def body_loss(
    person: np.ndarray,
    skin: np.ndarray,
    camera,
    base: BodyShape,
    garments: list[np.ndarray] | None = None,
) -> Callable[[np.ndarray], np.ndarray]:
    """The loss of :func:`fit_body`: search vectors (N, 3 + len(BODY_SEARCH)) -> (N,)."""
    import cv2

    shape_hw = person.shape
    if garments:
        # The person outside the garments is bare body: the body must cover all of it, and
        # under the garments it may lie anywhere (clothes are wider than the body).
        skin = person & ~np.logical_or.reduce([np.asarray(g, bool) for g in garments])
    empty_weight = 0.0 if garments else 0.1
    area = max(np.count_nonzero(person), 1)
    out_of_plane = np.array(
        [
            1.0 / 30.0
            if (j.startswith(("shoulder", "elbow")) and a == 2)
            or (j.startswith(("hip", "knee")) and a == 0)
            else 0.0
            for j, a, _, _ in BODY_SEARCH
        ]
    )
    # Distances [px] to the person: body pixels outside it cost by how far out they are, so a
    # thin limb off its place has a basin to roll into, not a plateau.
    outside_person = cv2.distanceTransform((~person).astype(np.uint8), cv2.DIST_L2, 3)
    bodies: dict[float, Mannequin] = {}

    def loss(xs: np.ndarray) -> np.ndarray:
        out = np.empty(len(xs))
        for i, x in enumerate(xs):
            shape, offset, angles = _body_from_x(x, base)
            key = round(float(x[0]), 4)
            body = bodies.get(key)
            if body is None:
                body = bodies[key] = Mannequin.build(shape)
            caps = body.capsules(angles[None])[0]
            caps[:, :3] += offset
            caps[:, 3:6] += offset
            mask = capsule_mask(camera, caps, shape_hw)
            outside = float(outside_person[mask].sum())
            missed = skin & ~mask
            uncovered = 0.0
            if missed.any():
                to_body = cv2.distanceTransform((~mask).astype(np.uint8), cv2.DIST_L2, 3)
                uncovered = float(to_body[missed].sum())
            empty = empty_weight * np.count_nonzero(person & ~mask)
            # Angles the frontal view hardly shows are held near a standing pose.
            prior = float(((x[3:] * out_of_plane) ** 2).sum())
            out[i] = (outside + uncovered + empty) / area + PRIOR_WEIGHT * prior
        if len(bodies) > 256:
            bodies.clear()
        return out

    return loss


def fit_body(
    person: np.ndarray,
    skin: np.ndarray,
    camera,
    settings: RecoverySettings,
    *,
    base: BodyShape | None = None,
    garments: list[np.ndarray] | None = None,
    on_iteration: Callable[[], None] | None = None,
) -> BodyFit:
    """Fit height, placement and the :data:`BODY_SEARCH` angles to the silhouettes.

    The loss sums, over the body pixels outside the person, their distance to it [px], and
    over the bare pixels the body leaves uncovered, their distance to the body [px], all over
    the person's area in pixels, plus a weak prior (:data:`PRIOR_WEIGHT` per (30 deg)²) on the
    angles that turn limbs towards or away from the camera, which a frontal silhouette hardly
    shows. The bare pixels are the person outside the ``garments`` masks when they are given
    (under a garment the body may lie anywhere inside the person), else the ``skin`` mask, and
    then a tenth of a unit per person pixel the body leaves empty is added. A global swarm,
    swarms per limb and a compass search minimise it.
    """
    base = base or BodyShape()
    lo = np.array([1.45, -0.15, -0.05] + [b[2] for b in BODY_SEARCH])
    hi = np.array([2.00, 0.15, 0.05] + [b[3] for b in BODY_SEARCH])
    loss = body_loss(person, skin, camera, base, garments)

    # The swarm starts around an upright A-pose of standard height.
    start = np.array([1.70, 0.0, 0.0] + [0.0] * len(BODY_SEARCH))
    for k, (joint, axis, _, _) in enumerate(BODY_SEARCH):
        if joint.startswith("shoulder") and axis == 1:
            start[3 + k] = -60.0 if joint.endswith("_r") else 60.0
    # A global swarm over everything, then small swarms over one limb (or the placement) at a
    # time: the silhouette loss is nearly separable per limb, and 4-dimensional swarms settle
    # where one 17-dimensional swarm still wanders.
    glob = max(settings.body_iters // 2, 1)
    swarm = _swarm(lo, hi, settings.body_swarm, settings.seed, start, spread=0.2)
    for _ in range(glob):
        swarm.tell(loss(swarm.ask()))
        if on_iteration is not None:
            on_iteration()
    best_x, best_f = swarm.best_x, float(swarm.best_f)
    groups = [[0, 1, 2]]
    for prefix in ("shoulder_r", "shoulder_l", "hip_r", "hip_l"):
        limb = {
            "shoulder_r": ("shoulder_r", "elbow_r"),
            "shoulder_l": ("shoulder_l", "elbow_l"),
            "hip_r": ("hip_r", "knee_r"),
            "hip_l": ("hip_l", "knee_l"),
        }[prefix]
        groups.append([3 + k for k, b in enumerate(BODY_SEARCH) if b[0] in limb])
    per_group = max((settings.body_iters - glob) // (2 * len(groups)), 1)
    for sweep in range(2):
        for g, dims in enumerate(groups):
            sub_lo, sub_hi = lo[dims], hi[dims]

            def sub_loss(ys, dims=dims, base_x=best_x):
                xs = np.repeat(base_x[None], len(ys), 0)
                xs[:, dims] = ys
                return loss(xs)

            sub = _swarm(
                sub_lo, sub_hi, 16, settings.seed + 17 * sweep + g, best_x[dims], spread=0.08
            )
            for _ in range(per_group):
                sub.tell(sub_loss(sub.ask()))
            if sub.best_f < best_f:
                best_x = best_x.copy()
                best_x[dims] = sub.best_x
                best_f = float(sub.best_f)
            if on_iteration is not None:
                for _ in range(per_group):
                    on_iteration()
    # The swarms stop within a few degrees; a compass search walks the rest of the way down.
    step = np.array([0.01, 0.005, 0.005] + [2.0] * len(BODY_SEARCH))
    best_x, best_f = _compass(loss, best_x, best_f, lo, hi, step, levels=5)
    shape, offset, angles = _body_from_x(best_x, base)
    return BodyFit(shape, Pose(angles), offset, best_f)


def _compass(loss, x, f, lo, hi, step, *, levels: int, max_passes: int = 6):
    """Coordinate pattern search from ``x`` with loss ``f``.

    Per dimension try ``±step`` and keep an improvement; halve the steps when a pass finds
    none; ``levels`` step sizes in all.
    """
    x = np.asarray(x, np.float64).copy()
    for _ in range(levels):
        for _ in range(max_passes):
            improved = False
            for d in range(len(x)):
                cand = np.repeat(x[None], 2, 0)
                cand[0, d] = min(x[d] + step[d], hi[d])
                cand[1, d] = max(x[d] - step[d], lo[d])
                values = loss(cand)
                k = int(np.argmin(values))
                if values[k] < f:
                    x, f, improved = cand[k], float(values[k]), True
            if not improved:
                break
        step = step / 2
    return x, f


# ---------------------------------------------------------------------------------- light


@dataclasses.dataclass(frozen=True)
class LightEstimate:
    """Key light direction (world, pointing into the scene) and ambient-to-key ratio."""

    direction: np.ndarray
    """Unit vector the key light travels along, shape (3,)."""
    ambient_ratio: float
    """Ambient radiance over the key light's diffuse radiance at normal incidence."""
    residual: float
    """RMS residual of the fit (linear intensity)."""

    def light_spec(self, intensity: float = 3.0):
        """A :class:`render.LightSpec` reproducing this light (pyrender's diffuse is 1/pi)."""
        from render.lights import LightFrame, LightSpec

        ambient = intensity * 0.96 / math.pi * self.ambient_ratio
        return LightSpec(
            direction=tuple(self.direction),
            frame=LightFrame.WORLD,
            intensity=intensity,
            ambient_intensity=float(min(max(ambient, 0.0), 10.0)),
        )


def _ray_capsule_normals(camera, pixels: np.ndarray, caps: np.ndarray) -> np.ndarray:
    """Surface normal of the nearest capsule hit by each pixel's ray, (N, 3); NaN on a miss."""
    pose = camera.pose()
    focal = 0.5 * camera.height / math.tan(math.radians(camera.yfov_deg) / 2)
    x = (pixels[:, 0] - 0.5 * camera.width) / focal
    y = -(pixels[:, 1] - 0.5 * camera.height) / focal
    d_cam = np.stack([x, y, -np.ones_like(x)], -1)
    d = d_cam @ pose[:3, :3].T
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o = pose[:3, 3]
    best_t = np.full(len(d), np.inf)
    best_n = np.full((len(d), 3), np.nan)
    for p0, p1, r in zip(caps[:, :3], caps[:, 3:6], caps[:, 6], strict=True):
        axis = p1 - p0
        length = float(np.linalg.norm(axis))
        cands = []
        for c in (p0, p1):  # end spheres
            oc = o - c
            b = d @ oc
            disc = b * b - (oc @ oc - r * r)
            t = np.where(disc >= 0, -b - np.sqrt(np.maximum(disc, 0)), np.inf)
            cands.append((t, None, c))
        if length > 1e-9:
            a = axis / length
            oc = o - p0
            d_perp = d - (d @ a)[:, None] * a
            oc_perp = oc - (oc @ a) * a
            qa = (d_perp * d_perp).sum(1)
            qb = d_perp @ oc_perp
            qc = oc_perp @ oc_perp - r * r
            disc = qb * qb - qa * qc
            t = np.where(
                disc >= 0, (-qb - np.sqrt(np.maximum(disc, 0))) / np.maximum(qa, 1e-12), np.inf
            )
            s = (oc @ a) + t * (d @ a)
            t = np.where((s >= 0) & (s <= length), t, np.inf)
            cands.append((t, a, p0))
        for t, a, base in cands:
            hit = (t > 0) & (t < best_t)
            if not hit.any():
                continue
            point = o + t[hit, None] * d[hit]
            if a is None:
                n = point - base
            else:
                n = point - (base + ((point - base) @ a)[:, None] * a)
            best_t[hit] = t[hit]
            best_n[hit] = n / np.linalg.norm(n, axis=1, keepdims=True)
    return best_n


def _cap_directions(centre: np.ndarray, radius: float, count: int) -> np.ndarray:
    """Unit vectors spread evenly over a spherical cap, shape (count, 3).

    A Fibonacci spiral over the cap of angular ``radius`` [rad] around ``centre``
    (``radius = pi``: the whole sphere).
    """
    i = np.arange(count) + 0.5
    phi = np.arccos(1 - (1 - math.cos(radius)) * i / count)
    theta = math.pi * (1 + 5**0.5) * i
    local = np.stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)], -1)
    z = centre / np.linalg.norm(centre)
    x = np.cross(z, [1.0, 0.0, 0.0] if abs(z[0]) < 0.9 else [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    return local @ np.stack([x, np.cross(z, x), z])


def estimate_light(image: np.ndarray, skin: np.ndarray, body: BodyFit, camera) -> LightEstimate:
    """Lambertian fit ``Y = k max(0, n . -l) + a`` of the skin's linear luminance.

    The normals come from the fitted body's capsules (ray casting). The luminance is that of
    the linearised channels (the renderer's output gamma is 2.2 per channel), from skin pixels
    one pixel inside the skin's outline (outline pixels are blended with what lies behind).
    Directions: least squares for ``(k, a)`` on a grid over the sphere (about 8 deg apart),
    then on two finer grids around the best one (to about 0.3 deg): the ambient ratio
    follows the direction, and a grid step's error in it changes the wrinkle density of the
    re-rendered particles by tens of percent.
    """
    import cv2

    caps = body.mannequin().capsules(body.pose.angles[None])[0]
    inner = cv2.erode(np.asarray(skin, np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    ys, xs = np.nonzero(inner if np.count_nonzero(inner) >= 30 else skin)
    if len(ys) < 30:
        return LightEstimate(np.array([0.0, 0.6, -0.8]) / 1.0, 0.4, float("nan"))
    step = max(1, len(ys) // 4000)
    ys, xs = ys[::step], xs[::step]
    normals = _ray_capsule_normals(camera, np.stack([xs + 0.5, ys + 0.5], -1), caps)
    ok = np.isfinite(normals).all(1)
    rgb = (np.asarray(image, np.float64)[ys, xs] / 255.0) ** 2.2
    lum = (rgb @ np.array([0.2126, 0.7152, 0.0722]))[ok]
    n = normals[ok]

    def fit(dirs, best):
        for light in dirs:
            shade = np.maximum(n @ -light, 0.0)
            design = np.stack([shade, np.ones_like(shade)], -1)
            coef, *_ = np.linalg.lstsq(design, lum, rcond=None)
            if coef[0] <= 0:
                continue
            res = float(np.sqrt(np.mean((design @ coef - lum) ** 2)))
            if res < best[0]:
                best = (res, light, coef[0], coef[1])
        return best

    best = fit(_cap_directions(np.array([0.0, 0.0, 1.0]), math.pi, 600), (np.inf, None, 0.0, 0.0))
    if best[1] is None:
        return LightEstimate(np.array([0.0, 0.6, -0.8]), 0.4, float("nan"))
    for radius in (math.radians(9.0), math.radians(1.5)):
        best = fit(_cap_directions(best[1], radius, 150), best)
    res, light, k, a = best
    return LightEstimate(np.asarray(light), float(max(a, 0.0) / max(k, 1e-9)), res)


# ----------------------------------------------------------------------------- targets


@dataclasses.dataclass(frozen=True)
class GarmentTarget:
    """What the image says about one garment."""

    garment: GarmentType
    mask: np.ndarray
    """The garment's visible pixels, bool (H, W)."""
    dont_care: np.ndarray
    """Pixels where the garment could be hidden (skin in front; for an inner layer also the
    other clothes), bool (H, W)."""
    silhouette: SilhouetteTarget
    density: np.ndarray
    """Wrinkle density per region [1/m], shape (R,)."""
    region_area: np.ndarray
    """Pixels per region, shape (R,)."""
    body: SilhouetteTarget
    """The person's silhouette: what Alg. 4's body term compares the posed body to."""


def expected_mask(body: BodyFit, garment: str, camera, shape_hw) -> np.ndarray:
    """Where the fitted body's primitives that ``garment`` covers project, bool (H, W)."""
    mann = body.mannequin()
    caps = mann.capsules(body.pose.angles[None])[0]
    keep = [
        c
        for c, p in enumerate(mann.primitives)
        if any(p.name == q or p.name.startswith(q + "_") for q in GARMENT_PRIMITIVES[garment])
    ]
    return capsule_mask(camera, caps[keep], shape_hw)


def garment_target(
    image: np.ndarray,
    garment: GarmentType,
    person: np.ndarray,
    skin: np.ndarray,
    body: BodyFit,
    camera,
    mask: np.ndarray | None = None,
) -> GarmentTarget:
    """The garment's mask (given or parsed), silhouette and regional wrinkle density."""
    if mask is None:
        expected = expected_mask(body, garment.value, camera, person.shape) & ~skin
        mask = parse_garment(image, person, expected)
    mask = np.asarray(mask, dtype=bool)
    if np.count_nonzero(mask) < 50:
        raise InputError(
            f"mask: the {garment.value} covers {np.count_nonzero(mask)} pixels, too few to "
            "recover it (need at least 50); give a garment mask or a larger image"
        )
    # Where the garment could be hidden: behind skin (an arm in front of a shirt), and, for an
    # inner layer, behind the other clothes; an outer layer is never behind other clothes,
    # so a candidate that covers them there is wrong.
    dont_care = (person & skin & ~mask) if garment.value in OUTER_GARMENTS else (person & ~mask)
    mann = body.mannequin()
    caps = mann.capsules(body.pose.angles[None])[0]
    regions = region_map(camera, caps, primitive_regions(mann, garment.value), mask)
    density, area = wrinkle_density(
        image, mask, regions, len(REGIONS[garment.value]), pixel_size(camera)
    )
    return GarmentTarget(
        garment,
        mask,
        dont_care,
        SilhouetteTarget.from_mask(mask),
        density,
        area,
        SilhouetteTarget.from_mask(person),
    )


# ---------------------------------------------------------------------------- recovery


def accuracy(estimate: dict[str, float], truth: dict[str, float]) -> float:
    """*Thesis* accuracy: mean over parameters of ``1 - |estimate - truth| / truth``."""
    return float(np.mean([1.0 - abs(estimate[k] - truth[k]) / abs(truth[k]) for k in truth]))


@dataclasses.dataclass
class RecoveryResult:
    """Everything a recovery found (see :func:`recover_garment`)."""

    garment: GarmentType
    pattern: Pattern
    material: dict[str, float]
    body: BodyFit
    pose: Pose
    """The pose after Alg. 4 (the body fit's, refined)."""
    pos: np.ndarray
    """The draped garment [m], shape (V, 3)."""
    curvature: np.ndarray
    """Regional mean curvature K of the draped garment [1/m], shape (R,)."""
    curvature_target: np.ndarray
    """``I(P)`` of the image's wrinkle densities (Eq. 6.6) [1/m], shape (R,)."""
    wrinkle_map: tuple[float, float]
    """The fitted map ``K = a + b P``: (a [1/m], b [dimensionless])."""
    density: np.ndarray
    """The image's wrinkle densities P [1/m], shape (R,)."""
    light: LightEstimate
    history: list[dict]
    """Best objective after every swarm iteration: ``{stage, round, iteration, objective}``."""
    timings: dict[str, float]
    """Seconds spent per part: body, parsing, simulation, rendering, bookkeeping."""


class _Evaluator:
    """Batched drapes and the objectives of one garment recovery."""

    def __init__(
        self,
        topology,
        target: GarmentTarget,
        body: BodyFit,
        camera,
        light,
        settings: RecoverySettings,
        timings: dict,
        should_stop,
        covered: tuple[str, ...] = (),
    ):
        self.topology = topology
        self.covered = covered
        self.target = target
        self.body = body
        self.mannequin = body.mannequin()
        self.camera = camera
        self.light = light
        self.settings = settings
        self.timings = timings
        self.should_stop = should_stop
        self.regions = primitive_regions(self.mannequin, target.garment.value)
        self.region_count = len(REGIONS[target.garment.value])
        self.pairs: list[tuple[np.ndarray, np.ndarray]] = []  # (P, K) of rendered drapes
        self._renderer = None
        self.image_regions = region_map(
            camera,
            self.mannequin.capsules(body.pose.angles[None])[0],
            self.regions,
            target.mask,
        )

    def close(self):
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def drape(self, coords, bend, stretch, angles, start, steps) -> tuple:
        """Drape a batch; returns (positions (B, V, 3), capsules (B, C, 7), DrapeResult).

        The garment meets the body thickened where the layers under it cover it; the
        capsules returned are the body's own (they assign the regions).
        """
        t = time.perf_counter()
        caps = self.mannequin.capsules(angles)
        settings = DrapeSettings(
            max_steps=steps, speed_tol=self.settings.drape_speed_tol, capsule_margin=0.12
        )
        batch = GarmentBatch.build(
            self.topology,
            coords,
            garment_material(bend, stretch),
            layer_obstacle(self.mannequin, caps, self.covered),
            settings,
            pos_hint=start,
        )
        result = drape(batch, start, settings, should_stop=self.should_stop)
        self.timings["simulation"] += time.perf_counter() - t
        return result.pos.numpy(), caps, result

    def silhouette(self, pos: np.ndarray) -> np.ndarray:
        """Eq. 6.10 distance [px] of each instance's projected garment, shape (B,)."""
        shape = self.target.mask.shape
        out = np.empty(len(pos))
        for b, p in enumerate(pos):
            px, _ = self.camera.project(p)
            mask = mesh_mask(px, self.topology.tri_indices, shape) & ~self.target.dont_care
            out[b] = self.target.silhouette.distance(mask)
        return out

    def curvature(self, pos: np.ndarray, caps: np.ndarray) -> np.ndarray:
        """Regional mean curvature of each instance [1/m], shape (B, R)."""
        tri = torch.as_tensor(self.topology.tri_indices)
        edges = torch.as_tensor(_hinges(self.topology))
        out = []
        for p, c in zip(pos, caps, strict=True):
            reg = vertex_regions(p, c, self.regions)
            out.append(
                regional_curvature(torch.as_tensor(p)[None], tri, edges, reg, self.region_count)[0]
            )
        return torch.stack(out).numpy()

    def densities(self, pos: np.ndarray, caps: np.ndarray) -> np.ndarray:
        """Wrinkle density of each instance rendered under the estimated light, (B, R)."""
        from render.renderer import ClothRenderer

        from .scenes import GARMENT_COLORS, render_scene

        t = time.perf_counter()
        if self._renderer is None:
            self._renderer = ClothRenderer(self.camera, self.light.light_spec())
        out = np.zeros((len(pos), self.region_count))
        color = GARMENT_COLORS[self.target.garment.value]
        for b, (p, c) in enumerate(zip(pos, caps, strict=True)):
            # The garment's pixels are found in the render as the image's mask is (what
            # changes with its colour), not by projecting triangles: the projected union
            # reaches about a pixel further, onto pixels blended with the background, whose
            # step reads as a ridge along the whole outline (measured: +55 % density on the
            # true drape).
            img, _, (visible,) = render_scene(
                self.camera,
                None,
                c,
                [(p, self.topology.tri_indices, color)],
                renderer=self._renderer,
            )
            mask = visible & ~self.target.dont_care
            regions = region_map(self.camera, c, self.regions, mask)
            out[b], _ = wrinkle_density(
                img, mask, regions, self.region_count, pixel_size(self.camera)
            )
        self.timings["rendering"] += time.perf_counter() - t
        return out

    def wrinkle_map(self) -> tuple[float, float]:
        """Least-squares ``K = a + b P`` over every (P, K) pair rendered so far (Eq. 6.6)."""
        if len(self.pairs) < 2:
            return 0.0, 1.0
        p = np.concatenate([a for a, _ in self.pairs])
        k = np.concatenate([b for _, b in self.pairs])
        if np.ptp(p) < 1e-9:
            return float(k.mean()), 0.0
        b, a = np.polyfit(p, k, 1)
        return float(a), float(b)

    def curvature_target(self) -> np.ndarray:
        """``I(P)`` of the image's densities [1/m], shape (R,)."""
        a, b = self.wrinkle_map()
        return a + b * self.target.density

    def curvature_objective(self, pos, caps) -> tuple[np.ndarray, np.ndarray]:
        """Eq. 6.5 per instance and the regional curvatures K (B, R).

        With ``I`` linear (Eq. 6.6) and fitted on the swarm's own (P, K) pairs, the distance
        ``|K - I(P_image)|`` is the map's slope times ``|P - P_image|`` up to the fit's
        residual; the objective is that density difference (area-weighted over the regions,
        relative to the image's densities), which stays defined while the fit is degenerate.
        """
        k = self.curvature(pos, caps)
        dens = self.densities(pos, caps)
        seen = self.target.region_area > 0
        for d, kk in zip(dens, k, strict=True):
            self.pairs.append((d[seen], kk[seen]))
        weight = self.target.region_area / max(self.target.region_area.sum(), 1.0)
        scale = np.maximum(self.target.density, 1.0)
        err = ((dens - self.target.density[None]) / scale[None]) ** 2
        return (err * weight[None]).sum(1), k


_HINGES: dict[int, tuple] = {}


def _hinges(topology: PatternTopology) -> np.ndarray:
    """Interior hinges ``[o0, o1, v1, v2]`` of a topology (cached), int64 (E, 4)."""
    key = id(topology)
    hit = _HINGES.get(key)
    if hit is not None and hit[0] is topology:
        return hit[1]
    from simulator.mesh import TriMesh

    coords = topology.coords(default_params(topology.garment))
    flat = np.concatenate([coords, np.zeros((len(coords), 1))], 1)
    edges = TriMesh.from_arrays(flat, topology.tri_indices, coords).edge_indices.numpy()
    _HINGES[key] = (topology, edges)
    return edges


def _swarm(lo, hi, size, seed, incumbent, spread: float | None = 0.15) -> ParticleSwarm:
    """A :class:`ParticleSwarm` started around ``incumbent`` instead of uniformly in the box.

    One particle sits on the incumbent, the others are scattered normally by ``spread`` of
    each range: every stage after the first refines what the previous one found, and a
    uniform start in 10-20 dimensions leaves the incumbent a needle that no particle comes
    near within a few iterations. ``spread=None`` spreads the others over the whole box
    (stratified per dimension), for a stage whose incumbent is only a guess.
    """
    swarm = ParticleSwarm(lo, hi, swarm_size=size, seed=seed, informants=min(3, size - 1))
    centre = np.clip((np.asarray(incumbent, np.float64) - lo) / (hi - lo), 0.0, 1.0)
    rng = np.random.default_rng([seed, 7])
    if spread is None:
        strata = (np.arange(size)[:, None] + rng.uniform(size=(size, len(centre)))) / size
        x = np.stack([rng.permutation(col) for col in strata.T], -1)
        spread = 0.15
    else:
        x = np.clip(centre + spread * rng.normal(size=(size, len(centre))), 0.0, 1.0)
    x[0] = centre
    swarm.x = x
    swarm.v = rng.uniform(-0.5 * spread, 0.5 * spread, x.shape)
    swarm.p = x.copy()
    return swarm


def inner_layers(garment: GarmentType | str) -> list[str]:
    """The garments that can be worn under ``garment`` as layers its drape meets."""
    rank = LAYER_ORDER.index(GarmentType(garment).value)
    return [g for g in LAYER_ORDER if g in COVERS and LAYER_ORDER.index(g) < rank]


def check_under(garment: GarmentType | str, under: Sequence[str]) -> tuple[str, ...]:
    """The garments worn under ``garment``, each checked to be an inner layer of it.

    Anything else ends with one line naming ``under`` and the garments allowed.
    """
    garment = GarmentType(garment)
    allowed = inner_layers(garment)
    for g in under:
        if g not in allowed:
            raise InputError(
                f"under: {g!r} cannot be worn under a {garment.value}; allowed: {allowed}"
            )
    return tuple(dict.fromkeys(under))


def recover_garment(
    image: np.ndarray,
    garment: GarmentType | str,
    camera,
    settings: RecoverySettings | None = None,
    *,
    mask: np.ndarray | None = None,
    person: np.ndarray | None = None,
    body_fit: BodyFit | None = None,
    under: Sequence[str] = (),
    progress: Callable[[str], None] | None = None,
    should_stop: Callable[[], bool] | None = None,
) -> RecoveryResult:
    """Recover one garment's G and C (and refine the pose) from an RGB image (H, W, 3).

    Args:
        image: the photograph, uint8 RGB.
        garment: which template to fit.
        camera: the camera that took it (:class:`render.CameraSpec`; scale is absorbed by the
            body fit's height and placement).
        settings: swarm sizes and iteration counts.
        mask: the garment's pixels, bool (H, W); parsed from the image when missing.
        person: the person's pixels; GrabCut when missing.
        body_fit: a body already fitted to this image (several garments share one).
        under: garments worn under this one (:func:`check_under`); the drapes meet the body
            thickened where they cover it, as the evaluation scenes drape an outer layer.
        progress: called with a stage name after every swarm iteration.
        should_stop: polled between drape steps; true ends the recovery early (Ctrl-C).
    """
    settings = settings or RecoverySettings()
    garment = GarmentType(garment)
    covered = tuple(p for g in check_under(garment, under) for p in COVERS[g])
    timings = dict.fromkeys(("body", "parsing", "simulation", "rendering", "bookkeeping"), 0.0)
    tick = time.perf_counter()
    image = np.asarray(image, np.uint8)
    if person is None:
        person = parse_person(image)
    skin = skin_mask(image, person)
    timings["parsing"] += time.perf_counter() - tick
    tick = time.perf_counter()
    if body_fit is None:
        body_fit = fit_body(
            person, skin, camera, settings, on_iteration=lambda: progress and progress("body")
        )
    light = estimate_light(image, skin, body_fit, camera)
    timings["body"] += time.perf_counter() - tick
    tick = time.perf_counter()
    target = garment_target(image, garment, person, skin, body_fit, camera, mask)
    timings["parsing"] += time.perf_counter() - tick

    topology = PatternTopology.build(garment, settings.edge_length)
    ev = _Evaluator(
        topology, target, body_fit, camera, light, settings, timings, should_stop, covered
    )
    # The material and pose steps compare wrinkles, on their own (finer) mesh when set.
    fine = settings.material_edge_length
    if fine is None or fine == settings.edge_length:
        ev_m = ev
    else:
        ev_m = _Evaluator(
            PatternTopology.build(garment, fine),
            target,
            body_fit,
            camera,
            light,
            settings,
            timings,
            should_stop,
            covered,
        )
    history: list[dict] = []
    rng_seed = settings.seed
    s = settings.swarm_size
    try:
        # Start: default sizing, softest material (thesis), the fitted pose.
        g_best = default_params(garment)
        c_best = {"bend": MATERIAL_SPECS[0].low, "stretch": 1.0}
        angles = body_fit.pose.angles.copy()

        def carry(x: np.ndarray, src: _Evaluator, dst: _Evaluator) -> np.ndarray:
            """A drape of ``src``'s mesh as a start on ``dst``'s (same G, pose)."""
            if src is dst:
                return x
            tick = time.perf_counter()
            moved = resample_positions(
                src.topology,
                src.topology.coords(g_best),
                x,
                dst.topology,
                dst.topology.coords(g_best),
            )
            caps = ev.mannequin.capsules(angles[None])[0]
            out = push_out(moved, caps, 0.004, passes=8)
            timings["simulation"] += time.perf_counter() - tick
            return out

        def drape_one(e: _Evaluator, start: np.ndarray, steps: int):
            coords = e.topology.coords(g_best)
            return e.drape(
                coords[None],
                [c_best["bend"]],
                [c_best["stretch"]],
                angles[None],
                start[None],
                steps,
            )

        coords0 = topology.coords(g_best)
        tick = time.perf_counter()
        start = register_batch(topology, coords0[None], [g_best], ev.mannequin, angles[None])
        timings["simulation"] += time.perf_counter() - tick
        pos, _, _ = drape_one(ev, start[0], settings.first_drape_steps)
        x_s = pos[0]  # the incumbent drape on the sizing mesh
        f_best = {"sizing": float(ev.silhouette(pos)[0])}
        if ev_m is not ev:
            pos, _, _ = drape_one(ev_m, carry(x_s, ev, ev_m), settings.first_drape_steps)
        x_m = pos[0]  # ... and on the material mesh
        caps = ev.mannequin.capsules(angles[None])
        cur_obj, k_best = ev_m.curvature_objective(pos, caps)
        sil = ev_m.silhouette(pos)[0]
        f_best["material"] = float(cur_obj[0] + settings.silhouette_weight * sil)
        k_best = k_best[0]

        _, lo_g, hi_g = search_box(garment)
        lo_c = np.log10([p.low for p in MATERIAL_SPECS])
        hi_c = np.log10([p.high for p in MATERIAL_SPECS])

        def material_round(stage: str, rnd: int):
            nonlocal c_best, x_s, x_m, f_best, k_best
            # The first material swarm searches the whole box: its incumbent (the softest
            # fabric) is only a guess, and a swarm scattered around it never reached a stiff
            # fabric (measured: bend 2.9 recovered for 60 on skirt_high_midday, --quick).
            swarm = _swarm(
                lo_c,
                hi_c,
                s,
                rng_seed + 1000 * rnd + 1,
                np.log10([c_best["bend"], c_best["stretch"]]),
                spread=None if stage == "material" and rnd == 0 else 0.15,
            )
            coords = np.repeat(ev_m.topology.coords(g_best)[None], s, 0)
            for it in range(settings.material_iters):
                xs = swarm.ask()
                bend, stretch = 10 ** xs[:, 0], 10 ** xs[:, 1]
                pos, caps, res = ev_m.drape(
                    coords,
                    bend,
                    stretch,
                    np.repeat(angles[None], s, 0),
                    np.repeat(x_m[None], s, 0),
                    settings.drape_steps,
                )
                t = time.perf_counter()
                sil = ev_m.silhouette(pos)
                obj, k = ev_m.curvature_objective(pos, caps)
                f = obj + settings.silhouette_weight * sil
                f = np.where(res.failed, np.inf, f)
                # Targets move as the map I is refitted: re-score the incumbent's entry too.
                swarm.tell(f)
                i = int(np.argmin(f))
                if f[i] <= f_best["material"] or it == 0:
                    c_best = {"bend": float(bend[i]), "stretch": float(stretch[i])}
                    x_m, k_best, f_best["material"] = pos[i], k[i], float(f[i])
                    f_best["sizing"] = float(sil[i])
                history.append(
                    {"stage": stage, "round": rnd, "iteration": it, "objective": f_best["material"]}
                )
                timings["bookkeeping"] += time.perf_counter() - t
                if progress:
                    progress(stage)
            if ev_m is ev:
                x_s = x_m
            elif stage == "material":
                # The next sizing step's incumbent, re-draped on its mesh with the new material.
                pos, _, _ = drape_one(ev, carry(x_m, ev_m, ev), settings.drape_steps)
                x_s, f_best["sizing"] = pos[0], float(ev.silhouette(pos)[0])

        def sizing_round(rnd: int):
            nonlocal g_best, x_s, x_m, f_best
            swarm = _swarm(lo_g, hi_g, s, rng_seed + 1000 * rnd + 2, to_search(garment, g_best))
            for it in range(settings.sizing_iters):
                xs = swarm.ask()
                params = [from_search(garment, x) for x in xs]
                coords = np.stack([topology.coords(p) for p in params])
                pos, _, res = ev.drape(
                    coords,
                    [c_best["bend"]] * s,
                    [c_best["stretch"]] * s,
                    np.repeat(angles[None], s, 0),
                    np.repeat(x_s[None], s, 0),
                    settings.drape_steps,
                )
                t = time.perf_counter()
                f = np.where(res.failed, np.inf, ev.silhouette(pos))
                swarm.tell(f)
                i = int(np.argmin(f))
                if f[i] <= f_best["sizing"]:
                    g_best, x_s, f_best["sizing"] = params[i], pos[i], float(f[i])
                history.append(
                    {
                        "stage": "sizing",
                        "round": rnd,
                        "iteration": it,
                        "objective": f_best["sizing"],
                    }
                )
                timings["bookkeeping"] += time.perf_counter() - t
                if progress:
                    progress("sizing")
            # The material mesh starts its next round from the new sizing's drape.
            x_m = carry(x_s, ev, ev_m)

        for rnd in range(settings.rounds):
            material_round("material", rnd)
            sizing_round(rnd)
            if should_stop is not None and should_stop():
                break

        # Alg. 4: pose, then material, with the sizing fixed (on the material mesh).
        fitted = body_fit.pose.angles
        keys = [(JOINTS.index(j), a) for j, a, _, _ in BODY_SEARCH]
        # The body term compares the body with the person's silhouette. (The garment's mask
        # plus its don't-care pixels is the person only for an inner layer: for a t-shirt
        # over pants it left the legs out, and every pose paid for the legs as outside.)
        body_sil = target.body
        for rnd in range(settings.joint_rounds):
            r = settings.pose_range_deg
            lo_p, hi_p = -np.full(len(keys), r), np.full(len(keys), r)
            current = np.array([angles[j, a] - fitted[j, a] for j, a in keys])
            swarm = _swarm(lo_p, hi_p, s, rng_seed + 1000 * rnd + 3, current)
            coords = np.repeat(ev_m.topology.coords(g_best)[None], s, 0)
            f_pose = np.inf
            for it in range(settings.pose_iters):
                xs = swarm.ask()
                cand = np.repeat(fitted[None], s, 0)
                for k, (j, a) in enumerate(keys):
                    cand[:, j, a] += xs[:, k]
                start = _repose(x_m, ev_m.mannequin, angles, cand)
                pos, caps, res = ev_m.drape(
                    coords,
                    [c_best["bend"]] * s,
                    [c_best["stretch"]] * s,
                    cand,
                    start,
                    settings.drape_steps,
                )
                t = time.perf_counter()
                obj, k = ev_m.curvature_objective(pos, caps)
                body_term = np.array(
                    [body_sil.distance(capsule_mask(camera, c, target.mask.shape)) for c in caps]
                )
                f = np.where(res.failed, np.inf, obj + settings.silhouette_weight * body_term)
                swarm.tell(f)
                i = int(np.argmin(f))
                if f[i] < f_pose:
                    f_pose = float(f[i])
                    angles, x_m, k_best = cand[i].copy(), pos[i], k[i]
                history.append(
                    {"stage": "pose", "round": rnd, "iteration": it, "objective": f_pose}
                )
                timings["bookkeeping"] += time.perf_counter() - t
                if progress:
                    progress("pose")
            f_best["material"] = np.inf  # the pose changed: re-decide the material
            material_round("joint_material", rnd)
    finally:
        ev.close()
        ev_m.close()

    final = ev_m.topology
    pattern = Pattern(final, check_params(garment, g_best), final.coords(g_best))
    a, b = ev_m.wrinkle_map()
    return RecoveryResult(
        garment=garment,
        pattern=pattern,
        material=c_best,
        body=body_fit,
        pose=Pose(angles),
        pos=x_m,
        curvature=np.asarray(k_best),
        curvature_target=ev_m.curvature_target(),
        wrinkle_map=(a, b),
        density=target.density,
        light=light,
        history=history,
        timings=timings,
    )


def _repose(pos: np.ndarray, body: Mannequin, angles: np.ndarray, targets: np.ndarray):
    """Carry a draped garment from ``angles`` to each of ``targets`` (B, 15, 3) by skinning.

    Relative bone transforms ``M_j(target) M_j(angles)^-1`` with weights from the draped
    shape, then the push-out of :func:`.skinning.remove_interpenetrations` (few rounds).
    """
    from simulator.garment.skinning import linear_blend, push_out, skinning_weights

    bones_now = body.bone_transforms(angles[None])[0]
    # Weights are computed in the rest pose: undo the current pose first.
    undo = np.linalg.inv(bones_now)[None]
    rest_pos = linear_blend(pos, _weights_posed(pos, body, angles), undo)[0]
    weights = skinning_weights(rest_pos, body)
    posed = linear_blend(rest_pos, weights, body.bone_transforms(targets))
    caps = body.capsules(targets)
    return np.stack([push_out(p, c, 0.004, passes=8) for p, c in zip(posed, caps, strict=True)])


def _weights_posed(pos: np.ndarray, body: Mannequin, angles: np.ndarray) -> np.ndarray:
    """Skinning weights of a posed garment: nearest posed bones (as in the rest pose)."""
    from simulator.garment.body import capsule_distance

    caps = body.capsules(angles[None])[0]
    dist, _ = capsule_distance(pos, caps)
    dist = np.maximum(dist, 0.0)
    per_bone = np.full((len(pos), len(JOINTS)), np.inf)
    for c, j in enumerate(body.primitive_joints):
        per_bone[:, j] = np.minimum(per_bone[:, j], dist[:, c])
    w = np.where(np.isfinite(per_bone), (per_bone + 0.02) ** -4.0, 0.0)
    cut = -np.sort(-w, axis=1)[:, 1:2]
    w = np.where(w >= cut, w, 0.0)
    return w / w.sum(axis=1, keepdims=True)


def pose_errors(estimate: Pose, truth: Pose) -> dict[str, float]:
    """Per-joint angle errors [deg] (:func:`.body.joint_angle_errors`)."""
    return joint_angle_errors(estimate, truth)
