"""A posable mannequin of capsules and spheres with the 15 joints of *thesis* Table 6.3.

No body-model download: the body is built from the project's own contact primitives. The
shape parameters (:class:`BodyShape`: height and three girths) set a skeleton with standard
anthropometric proportions (segment lengths as fractions of the height, Drillis & Contini)
and the radii of the primitives. The torso is a stack of horizontal capsules whose stadium
cross-sections carry the chest, waist and hip girths; limbs are capsules, the head and hands
spheres (capsules of zero length). Contact with cloth is the core's penalty capsule contact
(:class:`simulator.energies.EnergyContactCapsule`), with friction.

Pose θ (:class:`Pose`): three angles per joint [deg], rotations about the parent's x, y and z
axes applied in that order (the *thesis* confines rotations to the three primal axes), so a
joint's local rotation is ``Rx(a) Ry(b) Rz(c)``. The rest pose (all zero) is a T-pose: arms
horizontal, legs straight. World frame: z up, metres, the body faces -y (towards a camera
at -y); the wearer's right side is at -x.

Bone transforms for skinning (*thesis* Eq. 6.2/6.4) are the 4 x 4 matrices that carry a rest
point of a bone to its posed place: ``M_j = T_j(θ) T_j(0)^-1``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence

import numpy as np

from common.errors import InputError

__all__ = [
    "JOINTS",
    "JOINT_PARENTS",
    "POSE_LIMITS_DEG",
    "BodyShape",
    "Mannequin",
    "Pose",
    "capsule_distance",
    "joint_angle_errors",
]

JOINTS: tuple[str, ...] = (
    "pelvis",
    "neck",
    "head",
    "shoulder_r",
    "elbow_r",
    "wrist_r",
    "shoulder_l",
    "elbow_l",
    "wrist_l",
    "hip_r",
    "knee_r",
    "ankle_r",
    "hip_l",
    "knee_l",
    "ankle_l",
)
"""The 15 joints of *thesis* Table 6.3 (pelvis is the root)."""

JOINT_PARENTS: dict[str, str | None] = {
    "pelvis": None,
    "neck": "pelvis",
    "head": "neck",
    "shoulder_r": "pelvis",
    "elbow_r": "shoulder_r",
    "wrist_r": "elbow_r",
    "shoulder_l": "pelvis",
    "elbow_l": "shoulder_l",
    "wrist_l": "elbow_l",
    "hip_r": "pelvis",
    "knee_r": "hip_r",
    "ankle_r": "knee_r",
    "hip_l": "pelvis",
    "knee_l": "hip_l",
    "ankle_l": "knee_l",
}

POSE_LIMITS_DEG = 150.0
"""Largest absolute joint angle accepted [deg]."""


SHAPE_RANGES: dict[str, tuple[float, float]] = {
    "height": (1.45, 2.00),
    "chest": (0.75, 1.30),
    "waist": (0.58, 1.20),
    "hip": (0.78, 1.30),
}
"""Accepted range of each shape parameter [m]."""


@dataclasses.dataclass(frozen=True)
class BodyShape:
    """Shape parameters z of the mannequin (SI units)."""

    height: float = 1.70
    """Standing height [m], in [1.45, 2.00]."""
    chest: float = 0.92
    """Chest girth [m], in [0.75, 1.30]."""
    waist: float = 0.76
    """Waist girth [m], in [0.58, 1.20]."""
    hip: float = 0.96
    """Hip (seat) girth [m], in [0.78, 1.30]."""

    def __post_init__(self):
        for name, (lo, hi) in SHAPE_RANGES.items():
            value = getattr(self, name)
            ok = isinstance(value, int | float) and not isinstance(value, bool)
            if not ok or not math.isfinite(value) or not lo <= value <= hi:
                raise InputError(f"body.{name} must lie in [{lo}, {hi}] m, got {value!r}")
            object.__setattr__(self, name, float(value))

    def as_array(self) -> np.ndarray:
        """``[height, chest, waist, hip]`` [m], shape (4,)."""
        return np.array([self.height, self.chest, self.waist, self.hip])


@dataclasses.dataclass(frozen=True)
class Pose:
    """Joint angles θ [deg], shape (15, 3): per joint about the parent's x, y, z axes."""

    angles: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((len(JOINTS), 3)))

    def __post_init__(self):
        a = np.asarray(self.angles, dtype=np.float64)
        if a.shape != (len(JOINTS), 3) or not np.isfinite(a).all():
            raise InputError(f"pose angles must be finite with shape (15, 3), got {a.shape}")
        if np.abs(a).max() > POSE_LIMITS_DEG:
            j, k = np.unravel_index(np.argmax(np.abs(a)), a.shape)
            raise InputError(
                f"pose.{JOINTS[j]}[{k}] must lie in [-{POSE_LIMITS_DEG}, {POSE_LIMITS_DEG}] "
                f"deg, got {a[j, k]:g}"
            )
        object.__setattr__(self, "angles", a)

    @staticmethod
    def from_dict(values: Mapping[str, Sequence[float]] | None) -> Pose:
        """Pose from ``{joint: [x, y, z] deg}``; unnamed joints stay at zero."""
        angles = np.zeros((len(JOINTS), 3))
        for name, value in (values or {}).items():
            if name not in JOINTS:
                raise InputError(f"pose: unknown joint {name!r}; allowed: {', '.join(JOINTS)}")
            v = np.asarray(value, dtype=np.float64).reshape(-1)
            if v.shape != (3,):
                raise InputError(f"pose.{name} must be 3 angles [deg], got {value!r}")
            angles[JOINTS.index(name)] = v
        return Pose(angles)

    def to_dict(self) -> dict[str, list[float]]:
        """``{joint: [x, y, z] deg}`` of the non-zero joints."""
        return {
            j: [float(v) for v in self.angles[i]]
            for i, j in enumerate(JOINTS)
            if np.any(self.angles[i] != 0)
        }


def _rot(axis: int, deg: np.ndarray) -> np.ndarray:
    """Rotation matrices about a coordinate axis, angles (...,) [deg] -> (..., 3, 3)."""
    t = np.radians(deg)
    c, s = np.cos(t), np.sin(t)
    out = np.zeros((*np.shape(t), 3, 3))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    out[..., axis, axis] = 1.0
    out[..., i, i], out[..., j, j] = c, c
    out[..., i, j], out[..., j, i] = -s, s
    return out


def local_rotations(angles: np.ndarray) -> np.ndarray:
    """``Rx(a) Ry(b) Rz(c)`` of joint angles (..., 15, 3) [deg] -> (..., 15, 3, 3)."""
    return _rot(0, angles[..., 0]) @ _rot(1, angles[..., 1]) @ _rot(2, angles[..., 2])


def joint_angle_errors(estimate: Pose, truth: Pose) -> dict[str, float]:
    """Geodesic angle between estimated and true local joint rotations [deg], per joint."""
    r_est = local_rotations(estimate.angles)
    r_true = local_rotations(truth.angles)
    rel = np.einsum("jba,jbc->jac", r_true, r_est)
    cos = (np.trace(rel, axis1=1, axis2=2) - 1.0) / 2.0
    axis = np.stack(
        [rel[:, 2, 1] - rel[:, 1, 2], rel[:, 0, 2] - rel[:, 2, 0], rel[:, 1, 0] - rel[:, 0, 1]], -1
    )
    angle = np.degrees(np.arctan2(0.5 * np.linalg.norm(axis, axis=1), cos))
    return {j: float(angle[i]) for i, j in enumerate(JOINTS)}


def _stadium_size(girth: float, aspect: float) -> tuple[float, float]:
    """Width and depth [m] of a stadium of perimeter ``girth`` with depth/width ``aspect``."""
    width = girth / (math.pi * aspect + 2.0 - 2.0 * aspect)
    return width, aspect * width


@dataclasses.dataclass(frozen=True)
class _Primitive:
    joint: str
    """The bone (joint) the primitive moves with."""
    p0: np.ndarray
    p1: np.ndarray
    radius: float
    name: str


@dataclasses.dataclass(frozen=True)
class Mannequin:
    """The body: rest skeleton and primitives from a :class:`BodyShape`."""

    shape: BodyShape
    rest_joints: np.ndarray
    """Rest (T-pose) joint positions [m], shape (15, 3)."""
    primitives: tuple[_Primitive, ...]
    levels: dict[str, float]
    """Named heights of the rest body [m]: waist, hip, crotch, shoulder_top, neck_point, ..."""
    torso_sections: np.ndarray
    """Torso cross-sections ``[z, width, depth]`` [m] from bottom to top, shape (S, 3)."""
    offset: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(3))
    """Translation of the whole body from its standard place [m], shape (3,)."""

    @staticmethod
    def build(shape: BodyShape | None = None, offset=(0.0, 0.0, 0.0)) -> Mannequin:
        """Skeleton and primitives of a body shape, its feet near z = 0, moved by ``offset`` [m]."""
        shape = shape or BodyShape()
        shift = np.asarray(offset, dtype=np.float64).reshape(3)
        h = shape.height
        s = h / 1.70  # limb radii scale with size
        pelvis_z = 0.53 * h
        shoulder_x, shoulder_z = 0.112 * h, 0.808 * h
        hip_x = 0.052 * h
        joints = {
            "pelvis": (0.0, 0.0, pelvis_z),
            "neck": (0.0, 0.0, 0.835 * h),
            "head": (0.0, 0.0, 0.875 * h),
            "shoulder_r": (-shoulder_x, 0.0, shoulder_z),
            "elbow_r": (-shoulder_x - 0.186 * h, 0.0, shoulder_z),
            "wrist_r": (-shoulder_x - 0.332 * h, 0.0, shoulder_z),
            "hip_r": (-hip_x, 0.0, pelvis_z),
            "knee_r": (-hip_x, 0.0, 0.285 * h),
            "ankle_r": (-hip_x, 0.0, 0.039 * h),
        }
        for name in ("shoulder", "elbow", "wrist", "hip", "knee", "ankle"):
            x, y, z = joints[f"{name}_r"]
            joints[f"{name}_l"] = (-x, y, z)
        rest = np.array([joints[j] for j in JOINTS], dtype=np.float64)

        # Torso: stadium sections from the seat to the shoulders (girths interpolated).
        chest_w, chest_d = _stadium_size(shape.chest, 0.68)
        waist_w, waist_d = _stadium_size(shape.waist, 0.72)
        hip_w, hip_d = _stadium_size(shape.hip, 0.70)
        top_w, top_d = 2 * shoulder_x, 0.62 * chest_d
        keys = np.array(
            [
                [0.530 * h, hip_w, hip_d],
                [0.630 * h, waist_w, waist_d],
                [0.720 * h, chest_w, chest_d],
                [0.790 * h, 0.92 * chest_w, 0.85 * chest_d],
                [0.808 * h, top_w, top_d],
            ]
        )
        zs = np.array([0.530, 0.565, 0.600, 0.630, 0.660, 0.690, 0.720, 0.755, 0.790]) * h
        sections = np.stack(
            [zs, np.interp(zs, keys[:, 0], keys[:, 1]), np.interp(zs, keys[:, 0], keys[:, 2])], -1
        )
        prims: list[_Primitive] = []
        for i, (z, w, d) in enumerate(sections):
            half = max(w - d, 0.0) / 2
            prims.append(
                _Primitive(
                    "pelvis", np.array([-half, 0, z]), np.array([half, 0, z]), d / 2, f"torso_{i}"
                )
            )
        # Shoulder yoke: from shoulder to shoulder, carries the t-shirt.
        yoke_r = 0.050 * s
        prims.append(
            _Primitive(
                "pelvis", rest[3] + [0.01, 0, 0], rest[6] - [0.01, 0, 0], yoke_r, "shoulders"
            )
        )
        j = {n: rest[i] for i, n in enumerate(JOINTS)}
        prims += [
            _Primitive("neck", j["neck"] - [0, 0, 0.03 * h], j["head"], 0.052 * s, "neck"),
            _Primitive(
                "head",
                j["head"] + [0, 0, 0.065 * h],
                j["head"] + [0, 0, 0.065 * h],
                0.098 * s,
                "head",
            ),
        ]
        thigh_r = 0.56 * shape.hip / (2 * math.pi)
        for side in ("r", "l"):
            sh, el, wr = j[f"shoulder_{side}"], j[f"elbow_{side}"], j[f"wrist_{side}"]
            hip, knee, ankle = j[f"hip_{side}"], j[f"knee_{side}"], j[f"ankle_{side}"]
            hand = wr + 0.032 * h * (wr - el) / np.linalg.norm(wr - el)
            mid = 0.5 * (hip + knee)
            prims += [
                _Primitive(f"shoulder_{side}", sh, el, 0.046 * s, f"upper_arm_{side}"),
                _Primitive(f"elbow_{side}", el, wr, 0.037 * s, f"forearm_{side}"),
                _Primitive(f"wrist_{side}", hand, hand, 0.045 * s, f"hand_{side}"),
                _Primitive(f"hip_{side}", hip - [0, 0, 0.02 * h], mid, thigh_r, f"thigh_{side}"),
                _Primitive(
                    f"hip_{side}", mid, knee, 0.5 * (thigh_r + 0.052 * s), f"lower_thigh_{side}"
                ),
                _Primitive(f"knee_{side}", knee, ankle, 0.050 * s, f"shin_{side}"),
                _Primitive(
                    f"ankle_{side}",
                    ankle,
                    ankle + np.array([0, -0.11 * h, -0.015 * h]),
                    0.035 * s,
                    f"foot_{side}",
                ),
            ]
        levels = {
            "waist": 0.630 * h,
            "hip": 0.530 * h,
            "crotch": pelvis_z - 0.02 * h - thigh_r * 0.6,
            "shoulder_top": shoulder_z + yoke_r,
            "neck_point": shoulder_z + yoke_r + 0.01,
        }
        if np.any(shift != 0):
            rest = rest + shift
            prims = [dataclasses.replace(p, p0=p.p0 + shift, p1=p.p1 + shift) for p in prims]
            levels = {k: v + float(shift[2]) for k, v in levels.items()}
            sections = sections + np.array([shift[2], 0.0, 0.0])
        return Mannequin(shape, rest, tuple(prims), levels, sections, shift)

    @property
    def capsule_count(self) -> int:
        """C."""
        return len(self.primitives)

    @property
    def primitive_joints(self) -> np.ndarray:
        """Joint (bone) index of each primitive, int64, shape (C,)."""
        return np.array([JOINTS.index(p.joint) for p in self.primitives], dtype=np.int64)

    def joint_transforms(self, angles: np.ndarray) -> np.ndarray:
        """World transforms of the joints' frames, angles (B, 15, 3) [deg] -> (B, 15, 4, 4).

        The rest frame of every joint is axis-aligned at its rest position.
        """
        angles = np.asarray(angles, dtype=np.float64)
        batch = angles.shape[0]
        local = local_rotations(angles)
        out = np.zeros((batch, len(JOINTS), 4, 4))
        for i, name in enumerate(JOINTS):
            parent = JOINT_PARENTS[name]
            t = np.tile(np.eye(4), (batch, 1, 1))
            t[:, :3, :3] = local[:, i]
            if parent is None:
                t[:, :3, 3] = self.rest_joints[i]
                out[:, i] = t
            else:
                p = JOINTS.index(parent)
                t[:, :3, 3] = self.rest_joints[i] - self.rest_joints[p]
                out[:, i] = out[:, p] @ t
        return out

    def bone_transforms(self, angles: np.ndarray) -> np.ndarray:
        """Skinning matrices ``T_j(θ) T_j(0)^-1`` (B, 15, 4, 4) for angles (B, 15, 3) [deg]."""
        posed = self.joint_transforms(angles)
        rest_inv = np.tile(np.eye(4), (len(JOINTS), 1, 1))
        rest_inv[:, :3, 3] = -self.rest_joints
        return posed @ rest_inv

    def capsules(self, angles: np.ndarray) -> np.ndarray:
        """Posed primitives ``[p0, p1, radius]`` [m], angles (B, 15, 3) -> (B, C, 7)."""
        bones = self.bone_transforms(angles)
        idx = self.primitive_joints
        p0 = np.array([p.p0 for p in self.primitives])
        p1 = np.array([p.p1 for p in self.primitives])
        rad = np.array([p.radius for p in self.primitives])
        m = bones[:, idx]  # (B, C, 4, 4)
        q0 = np.einsum("bcij,cj->bci", m[..., :3, :3], p0) + m[..., :3, 3]
        q1 = np.einsum("bcij,cj->bci", m[..., :3, :3], p1) + m[..., :3, 3]
        r = np.broadcast_to(rad, q0.shape[:2])[..., None]
        return np.concatenate([q0, q1, r], axis=-1)

    def joint_positions(self, angles: np.ndarray) -> np.ndarray:
        """Posed joint positions [m], angles (B, 15, 3) -> (B, 15, 3)."""
        return self.joint_transforms(angles)[..., :3, 3]

    def trimesh(self, pose: Pose | None = None, *, segments: int = 20):
        """The posed body as one ``trimesh.Trimesh`` (primitives concatenated, not fused)."""
        import trimesh

        caps = self.capsules((pose or Pose()).angles[None])[0]
        parts = []
        for row in caps:
            length = float(np.linalg.norm(row[3:6] - row[:3]))
            if length < 1e-9:
                mesh = trimesh.creation.icosphere(subdivisions=2, radius=float(row[6]))
                mesh.apply_translation(row[:3])
            else:
                mesh = trimesh.creation.capsule(
                    height=length, radius=float(row[6]), count=[segments, segments // 2]
                )
                mesh.apply_transform(_segment_pose(row[:3], row[3:6]))
            parts.append(mesh)
        return trimesh.util.concatenate(parts)


def _segment_pose(p0: np.ndarray, p1: np.ndarray) -> np.ndarray:
    """Rigid transform taking a z-axis segment centred at the origin onto p0 -> p1, (4, 4)."""
    axis = p1 - p0
    d = axis / np.linalg.norm(axis)
    z = np.array([0.0, 0.0, 1.0])
    pose = np.eye(4)
    pose[:3, 3] = 0.5 * (p0 + p1)
    c = float(d @ z)
    if c < -1 + 1e-12:
        pose[:3, :3] = np.diag([1.0, -1.0, -1.0])
        return pose
    v = np.cross(z, d)
    vx = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    pose[:3, :3] = np.eye(3) + vx + vx @ vx / (1.0 + c)
    return pose


def capsule_distance(points: np.ndarray, capsules: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Signed distance of points to every capsule surface and the closest axis points.

    Args:
        points: query points [m], shape (N, 3).
        capsules: ``[p0, p1, radius]`` [m], shape (C, 7).

    Returns:
        ``(distance (N, C) [m], negative inside; closest axis point (N, C, 3) [m])``.
    """
    p0, axis = capsules[None, :, :3], capsules[None, :, 3:6] - capsules[None, :, :3]
    rel = points[:, None, :] - p0
    t = np.clip((rel * axis).sum(-1) / np.maximum((axis * axis).sum(-1), 1e-12), 0.0, 1.0)
    closest = p0 + t[..., None] * axis
    dist = np.linalg.norm(points[:, None, :] - closest, axis=-1) - capsules[None, :, 6]
    return dist, closest
