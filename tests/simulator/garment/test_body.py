"""Mannequin kinematics, skinning (Eq. 6.4) and interpenetration removal."""

import math

import numpy as np
import pytest

from common.errors import InputError
from simulator.garment.body import (
    JOINTS,
    BodyShape,
    Mannequin,
    Pose,
    capsule_distance,
    joint_angle_errors,
)
from simulator.garment.patterns import GARMENT_TYPES, PatternTopology, build_pattern
from simulator.garment.skinning import (
    CLEARANCE,
    linear_blend,
    register,
    rest_placement,
    skinning_weights,
)

A_POSE = Pose.from_dict(
    {
        "shoulder_r": [0, -60, 0],
        "shoulder_l": [0, 60, 0],
        "elbow_r": [0, 0, 20],
        "hip_r": [-20, 0, 0],
        "knee_r": [30, 0, 0],
    }
)


def test_fifteen_joints_and_rest_transforms_are_identity():
    body = Mannequin.build()
    assert len(JOINTS) == 15
    bones = body.bone_transforms(np.zeros((1, 15, 3)))
    np.testing.assert_allclose(bones, np.broadcast_to(np.eye(4), bones.shape), atol=1e-15)


def test_torso_sections_carry_the_girths():
    shape = BodyShape(height=1.8, chest=1.0, waist=0.8, hip=1.05)
    body = Mannequin.build(shape)
    sec = body.torso_sections
    for z, girth in ((0.53 * 1.8, 1.05), (0.63 * 1.8, 0.8), (0.72 * 1.8, 1.0)):
        w = np.interp(z, sec[:, 0], sec[:, 1])
        d = np.interp(z, sec[:, 0], sec[:, 2])
        assert math.pi * d + 2 * (w - d) == pytest.approx(girth, rel=1e-9)


def test_elbow_rotation_moves_only_the_forearm_and_hand():
    body = Mannequin.build()
    rest = body.capsules(np.zeros((1, 15, 3)))[0]
    bent = body.capsules(Pose.from_dict({"elbow_r": [0, 0, 90]}).angles[None])[0]
    moved = {body.primitives[c].name for c in np.nonzero(np.abs(bent - rest).max(1) > 1e-12)[0]}
    assert moved == {"forearm_r", "hand_r"}
    # The forearm keeps its length and turns by 90 degrees about z.
    f = [p.name for p in body.primitives].index("forearm_r")
    a, b = rest[f, 3:6] - rest[f, :3], bent[f, 3:6] - bent[f, :3]
    assert np.linalg.norm(a) == pytest.approx(np.linalg.norm(b))
    assert a @ b == pytest.approx(0.0, abs=1e-12)


def test_joint_angle_error_is_the_geodesic_angle():
    truth = Pose.from_dict({"knee_l": [25, 0, 0], "shoulder_r": [0, -40, 10]})
    assert max(joint_angle_errors(truth, truth).values()) < 1e-6
    est = Pose.from_dict({"knee_l": [35, 0, 0], "shoulder_r": [0, -40, 10]})
    errors = joint_angle_errors(est, truth)
    assert errors["knee_l"] == pytest.approx(10.0)
    assert errors["shoulder_r"] < 1e-6


def test_capsule_distance_signs():
    caps = np.array([[0.0, 0, 0, 1.0, 0, 0, 0.1]])
    pts = np.array([[0.5, 0, 0], [0.5, 0.3, 0], [-0.2, 0, 0]])
    d, _ = capsule_distance(pts, caps)
    np.testing.assert_allclose(d[:, 0], [-0.1, 0.2, 0.1])


@pytest.mark.parametrize("garment", GARMENT_TYPES)
def test_rest_pose_skinning_is_the_identity(garment):
    body = Mannequin.build()
    pattern = build_pattern(garment, edge_length=0.05)
    rest = rest_placement(pattern, body)
    weights = skinning_weights(rest, body)
    assert np.all(weights >= 0)
    np.testing.assert_allclose(weights.sum(1), 1.0)
    posed = linear_blend(rest, weights, body.bone_transforms(np.zeros((2, 15, 3))))
    np.testing.assert_allclose(posed, np.broadcast_to(rest, posed.shape), atol=1e-14)


def test_skinning_with_one_bone_is_rigid():
    body = Mannequin.build()
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(20, 3))
    weights = np.zeros((20, 15))
    weights[:, JOINTS.index("elbow_r")] = 1.0
    posed = linear_blend(pts, weights, body.bone_transforms(A_POSE.angles[None]))[0]
    d0 = np.linalg.norm(pts[:, None] - pts[None], axis=-1)
    d1 = np.linalg.norm(posed[:, None] - posed[None], axis=-1)
    np.testing.assert_allclose(d1, d0, atol=1e-12)


@pytest.mark.parametrize("garment", GARMENT_TYPES)
def test_registration_leaves_no_vertex_inside_the_body(garment):
    body = Mannequin.build(BodyShape(height=1.62, hip=1.02))
    topology = PatternTopology.build(garment, 0.05)
    pattern = build_pattern(garment, topology=topology)
    tri = topology.tri_indices
    edges = np.unique(
        np.sort(np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]), 1), axis=0
    )
    angles = np.stack([np.zeros((15, 3)), A_POSE.angles])
    out = register(pattern, body, angles, edges=edges)
    caps = body.capsules(angles)
    for b in range(2):
        dist, _ = capsule_distance(out[b], caps[b])
        assert dist.min() >= CLEARANCE - 1e-3, (garment, b, dist.min())


def test_bad_shape_and_pose_name_the_field():
    with pytest.raises(InputError, match=r"body\.height must lie in \[1\.45, 2\.0\]"):
        BodyShape(height=3.0)
    with pytest.raises(InputError, match=r"pose\.elbow_l\[2\]"):
        Pose.from_dict({"elbow_l": [0, 0, 200]})
    with pytest.raises(InputError, match="unknown joint 'tail'"):
        Pose.from_dict({"tail": [0, 0, 0]})
