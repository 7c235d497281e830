"""Initial garment registration (*thesis* §6.4.3): rest placement, skinning, push-out.

1. **Rest placement.** The flat panels are wrapped around the rest-pose (T-pose) mannequin:
   every panel row becomes an arc of a loop (an ellipse with the body's aspect at that
   height, or a circle around a limb) whose circumference is the garment's own width there,
   so the garment starts roughly at its size with its seams nearly closed. Which loop each
   panel joins is the template's *garment skeleton* (:func:`rest_placement`).
2. **Skinning** (Eq. 6.4): ``x_i(θ) = sum_j v_ij M_j(θ) x0_i`` with the mannequin's bone
   matrices ``M_j`` and weights ``v_ij`` that fall off with the distance from the vertex to
   the surface of each bone's primitives (:func:`skinning_weights`). In the rest pose every
   ``M_j`` is the identity, so skinning is the identity there.
3. **Interpenetration removal** (the *thesis* uses as-rigid-as-possible deformation): a few
   rounds of pushing vertices out of the capsules and relaxing edge lengths towards their rest
   lengths (position-based projection, which keeps the garment close to rigid), ending with a
   push-out, so no vertex is left inside the body (:func:`remove_interpenetrations`).
"""

from __future__ import annotations

import math

import numpy as np

from .body import JOINTS, Mannequin, capsule_distance
from .patterns import GarmentType, Pattern

__all__ = [
    "CLEARANCE",
    "linear_blend",
    "push_out",
    "register",
    "remove_interpenetrations",
    "rest_placement",
    "skinning_weights",
]

CLEARANCE = 0.006
"""Distance kept between garment vertices and the body surface after registration [m]."""


# ---------------------------------------------------------------------------- rest placement


def _ellipse_table(aspect: float, samples: int = 512) -> tuple[np.ndarray, np.ndarray]:
    """Angle and normalised arc length of the unit-width ellipse ``(cos, aspect sin)``."""
    phi = np.linspace(0.0, 2 * math.pi, samples + 1)
    pts = np.stack([np.cos(phi), aspect * np.sin(phi)], -1)
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(seg)])
    return phi, arc / arc[-1]


def _loop_points(s: np.ndarray, circumference: np.ndarray, aspect: np.ndarray) -> np.ndarray:
    """Points at arc fraction ``s`` of ellipses centred at 0, shape (N, 2).

    ``s = 0`` lies at -x (the wearer's right), 0.25 at -y (front), 0.5 at +x, 0.75 at +y.
    ``aspect`` is depth / width; the ellipse's perimeter is ``circumference`` [m].
    """
    out = np.empty((len(s), 2))
    for k, (sk, ck, ak) in enumerate(zip(s, circumference, aspect, strict=True)):
        phi, arc = _ellipse_table(float(ak), 256)
        angle = np.interp(sk % 1.0, arc, phi)
        # Ramanujan's perimeter of the ellipse with semi-axes (a, aspect a).
        unit = math.pi * (3 * (1 + ak) - math.sqrt((3 + ak) * (1 + 3 * ak)))
        a = ck / unit
        out[k] = (-a * math.cos(angle), -a * ak * math.sin(angle))
    return out


def _panel_rows(pattern: Pattern, panel: str):
    """Grid ids (nv+1, nu+1), row widths (nv+1,) [m] and i/nu fractions of a panel."""
    offset, nu, nv = pattern.topology.panel_grid[panel]
    ids = offset + np.arange((nu + 1) * (nv + 1)).reshape(nv + 1, nu + 1)
    rows = pattern.coords[ids]
    widths = np.linalg.norm(np.diff(rows, axis=1), axis=-1).sum(-1)
    return ids, widths, np.linspace(0.0, 1.0, nu + 1)


def _body_aspect(body: Mannequin, z: np.ndarray) -> np.ndarray:
    sec = body.torso_sections
    zc = np.clip(z, sec[0, 0], sec[-1, 0])
    return np.interp(zc, sec[:, 0], sec[:, 2]) / np.interp(zc, sec[:, 0], sec[:, 1])


def _torso_wrap(pattern, body, panels: dict[str, tuple[float, float]], z_of, rows=None):
    """Wrap panels around the torso: ``panels[name] = (s at i=0, s at i=nu)``."""
    out = {}
    grids = {n: _panel_rows(pattern, n) for n in panels}
    nv = next(iter(grids.values()))[0].shape[0]
    rows = range(nv) if rows is None else rows
    for j in rows:
        circ = sum(grids[n][1][j] for n in panels)
        for name, (s0, s1) in panels.items():
            ids, _, frac = grids[name]
            z = z_of(name, ids[j])
            s = s0 + (s1 - s0) * frac
            xy = _loop_points(s, np.full(len(s), circ), _body_aspect(body, z)) + body.offset[:2]
            out.update({int(v): (x, y, zz) for v, (x, y), zz in zip(ids[j], xy, z, strict=True)})
    return out


def _limb_wrap(pattern, panels: dict[str, tuple[float, float]], centre_of, rows, axis_frame):
    """Wrap panel rows around a limb: circles in the plane of ``axis_frame`` (e1, e2)."""
    out = {}
    grids = {n: _panel_rows(pattern, n) for n in panels}
    e1, e2 = axis_frame
    for j in rows:
        circ = sum(grids[n][1][j] for n in panels)
        for name, (s0, s1) in panels.items():
            ids, _, frac = grids[name]
            s = s0 + (s1 - s0) * frac
            xy = _loop_points(s, np.full(len(s), circ), np.ones(len(s)))
            centre = centre_of(name, j)
            for v, (a, b) in zip(ids[j], xy, strict=True):
                out[int(v)] = tuple(centre + a * e1 + b * e2)
    return out


def rest_placement(pattern: Pattern, body: Mannequin) -> np.ndarray:
    """The garment wrapped around the rest-pose body (see the module docstring) [m], (V, 3)."""
    garment = pattern.garment
    g = pattern.params
    x = pattern.coords
    placed: dict[int, tuple] = {}
    if garment is GarmentType.SKIRT:
        waist_z = body.levels["waist"]
        yoke_side = float(np.hypot(0.15, 0.5 * (g["r1"] * g["alpha"] - g["l1"])))
        topo = pattern.topology

        def z_skirt(name, ids):
            _, _, nv = topo.panel_grid[name]
            j = (ids[0] - topo.panel_grid[name][0]) // (topo.panel_grid[name][1] + 1)
            if name.startswith("yoke"):
                return np.full(len(ids), waist_z - yoke_side * (nv - j) / nv)
            return np.full(len(ids), waist_z - yoke_side - g["r2"] * (nv - j) / nv)

        placed.update(
            _torso_wrap(pattern, body, {"yoke_front": (0.0, 0.5), "yoke_back": (0.5, 1.0)}, z_skirt)
        )
        placed.update(
            _torso_wrap(
                pattern, body, {"flare_front": (0.0, 0.5), "flare_back": (0.5, 1.0)}, z_skirt
            )
        )
    elif garment is GarmentType.PANTS:
        waist_z = body.levels["waist"] - 0.03
        low = pattern.topology.counts["out_low"]
        nv = low + pattern.topology.counts["out_high"]

        def z_pants(name, ids):
            return waist_z - g["h1"] + x[ids, 1]

        placed.update(
            _torso_wrap(
                pattern,
                body,
                {
                    "front_r": (0.0, 0.25),
                    "front_l": (0.5, 0.25),
                    "back_r": (1.0, 0.75),
                    "back_l": (0.5, 0.75),
                },
                z_pants,
                rows=range(low + 1, nv + 1),
            )
        )
        hips = {s: body.rest_joints[JOINTS.index(f"hip_{s}")] for s in ("r", "l")}
        for side, front, back in (("r", (0.0, 0.5), (1.0, 0.5)), ("l", (0.5, 0.0), (0.5, 1.0))):
            ids_f = _panel_rows(pattern, f"front_{side}")[0]

            def centre(name, j, side=side, ids_f=ids_f):
                z = waist_z - g["h1"] + x[ids_f[j, 0], 1]
                return np.array([hips[side][0], hips[side][1], z])

            placed.update(
                _limb_wrap(
                    pattern,
                    {f"front_{side}": front, f"back_{side}": back},
                    centre,
                    range(low + 1),
                    (np.array([1.0, 0, 0]), np.array([0, 1.0, 0])),
                )
            )
    else:  # t-shirt
        neck_z = body.levels["neck_point"]
        armhole = g["h2"] - 0.04 - g["h1"]

        def z_shirt(name, ids):
            return neck_z - g["h2"] + x[ids, 1]

        body_rows = _torso_wrap(pattern, body, {"front": (0.0, 0.5), "back": (0.5, 1.0)}, z_shirt)
        for v, (px, py, pz) in body_rows.items():
            # Above the underarm the front and back close over the shoulders.
            rise = np.clip((x[v, 1] - g["h1"]) / armhole, 0.0, 1.0)
            squeeze = 1.0 - 0.75 * rise * rise
            half = g["w2"] / 2
            px = px if rise <= 0 else np.sign(px) * min(abs(px) + rise * 0.3 * half, half * 1.1)
            placed[v] = (px, py * squeeze, pz)
        for side, sign in (("r", -1.0), ("l", 1.0)):
            shoulder = body.rest_joints[JOINTS.index(f"shoulder_{side}")]
            name = f"sleeve_{side}"
            _, _, nv = pattern.topology.panel_grid[name]

            def centre(name, j, nv=nv, shoulder=shoulder, sign=sign):
                along = g["w2"] / 2 + 0.01 + g["l1"] * (nv - j) / nv
                return np.array([body.offset[0] + sign * along, shoulder[1], shoulder[2]])

            # Circle in the y-z plane: s = 0 at the bottom (-z), 0.25 in front (-y), 0.5 on top.
            frame = (np.array([0.0, 0.0, 1.0]), np.array([0.0, 1.0, 0.0]))
            placed.update(_limb_wrap(pattern, {name: (0.0, 1.0)}, centre, range(nv + 1), frame))
    out = np.array([placed[v] for v in range(pattern.topology.vert_count)], dtype=np.float64)
    return out


# --------------------------------------------------------------------------------- skinning


def skinning_weights(
    points: np.ndarray, body: Mannequin, *, falloff: float = 0.02, power: float = 4.0, keep: int = 2
) -> np.ndarray:
    """Bone weights of rest-pose points, shape (V, 15), rows summing to 1.

    ``w_j ∝ (d_j + falloff)^-power`` with ``d_j`` the distance [m] from the point to the
    surface of bone j's primitives (0 inside); only the ``keep`` largest are kept.
    """
    caps = body.capsules(np.zeros((1, len(JOINTS), 3)))[0]
    dist, _ = capsule_distance(np.asarray(points, np.float64), caps)
    dist = np.maximum(dist, 0.0)
    per_bone = np.full((len(points), len(JOINTS)), np.inf)
    for c, j in enumerate(body.primitive_joints):
        per_bone[:, j] = np.minimum(per_bone[:, j], dist[:, c])
    w = np.where(np.isfinite(per_bone), (per_bone + falloff) ** -power, 0.0)
    if keep < w.shape[1]:
        cut = -np.sort(-w, axis=1)[:, keep - 1 : keep]
        w = np.where(w >= cut, w, 0.0)
    return w / w.sum(axis=1, keepdims=True)


def linear_blend(points: np.ndarray, weights: np.ndarray, bones: np.ndarray) -> np.ndarray:
    """Eq. 6.4: ``x_i = sum_j v_ij M_j x0_i``; points (V, 3), weights (V, J), bones (B, J, 4, 4).

    Returns posed points [m], shape (B, V, 3).
    """
    blended = np.einsum("vj,bjkl->bvkl", weights, bones)  # (B, V, 4, 4)
    return np.einsum("bvkl,vl->bvk", blended[..., :3, :3], points) + blended[..., :3, 3]


# ------------------------------------------------------------------------ interpenetrations


def push_out(
    pos: np.ndarray, capsules: np.ndarray, clearance: float, passes: int = 4
) -> np.ndarray:
    """Move every vertex inside a capsule (plus clearance) to its surface, (V, 3)."""
    out = pos.copy()
    for _ in range(passes):  # a point pushed out of one capsule may land in a neighbour
        dist, closest = capsule_distance(out, capsules)
        depth = clearance - dist
        worst = np.argmax(depth, axis=1)
        rows = np.arange(len(out))
        d = depth[rows, worst]
        inside = d > 0
        if not inside.any():
            break
        axis_pt = closest[rows, worst]
        direction = out - axis_pt
        norm = np.linalg.norm(direction, axis=1, keepdims=True)
        # A point on the axis itself goes out sideways (away from the body's midline).
        fallback = np.where(np.abs(out[:, :1]) > 1e-9, np.sign(out[:, :1]), 1.0) * [[1, 0, 0]]
        direction = np.where(norm > 1e-12, direction / np.maximum(norm, 1e-12), fallback)
        out[inside] += d[inside, None] * direction[inside]
    return out


def remove_interpenetrations(
    pos: np.ndarray,
    capsules: np.ndarray,
    edges: np.ndarray,
    rest_length: np.ndarray,
    *,
    clearance: float = CLEARANCE,
    iterations: int = 30,
) -> np.ndarray:
    """Positions with no vertex inside the body, edges kept near their rest lengths.

    Args:
        pos: garment vertices [m], shape (V, 3).
        capsules: body primitives ``[p0, p1, radius]`` [m], shape (C, 7).
        edges: mesh edges, int64, shape (S, 2).
        rest_length: their lengths before skinning [m], shape (S,).
        clearance: distance kept from the body surface [m].
        iterations: rounds of push-out and edge relaxation.

    Returns:
        New positions [m], shape (V, 3); every vertex at least ``clearance`` (up to
        round-off, where capsules overlap: at least 0) outside every capsule.
    """
    x = np.array(pos, dtype=np.float64, copy=True)
    count = np.bincount(edges.ravel(), minlength=len(x)).astype(np.float64)[:, None]
    for _ in range(iterations):
        x = push_out(x, capsules, clearance)
        d = x[edges[:, 1]] - x[edges[:, 0]]
        length = np.linalg.norm(d, axis=1)
        corr = 0.5 * ((length - rest_length) / np.maximum(length, 1e-12))[:, None] * d
        delta = np.zeros_like(x)
        np.add.at(delta, edges[:, 0], corr)
        np.add.at(delta, edges[:, 1], -corr)
        x = x + 0.8 * delta / np.maximum(count, 1.0)
    return push_out(x, capsules, clearance, passes=16)


def register(
    pattern: Pattern, body: Mannequin, angles: np.ndarray, *, edges: np.ndarray
) -> np.ndarray:
    """Registered garment (rest placement, skinning, push-out) for poses (B, 15, 3), (B, V, 3)."""
    rest = rest_placement(pattern, body)
    weights = skinning_weights(rest, body)
    posed = linear_blend(rest, weights, body.bone_transforms(angles))
    caps = body.capsules(angles)
    rest_length = np.linalg.norm(rest[edges[:, 1]] - rest[edges[:, 0]], axis=1)
    return np.stack(
        [
            remove_interpenetrations(p, c, edges, rest_length)
            for p, c in zip(posed, caps, strict=True)
        ]
    )
