"""The body fit: the body raster, and a bare mannequin rendered in a known pose found again."""

import numpy as np
import pytest

from apps.garment.image import capsule_mask
from apps.garment.recovery import RecoverySettings, fit_body, skin_mask
from apps.garment.scenes import scene_camera, scene_light
from simulator.garment.body import JOINTS, Mannequin, Pose, joint_angle_errors


def test_capsule_mask_is_the_projected_capsule():
    """Area and centre of a capsule facing the camera match the projection to a pixel."""
    camera = scene_camera()
    caps = np.array([[-0.2, 0.0, 0.9, 0.2, 0.0, 0.9, 0.05]])
    mask = capsule_mask(camera, caps, (camera.height, camera.width))
    px, depth = camera.project(caps[:, :6].reshape(2, 3))
    focal = 0.5 * camera.height / np.tan(np.radians(camera.yfov_deg) / 2)
    r = 0.05 * focal / depth.mean()
    length = np.linalg.norm(px[1] - px[0])
    assert mask.sum() == pytest.approx(np.pi * r * r + 2 * r * length, rel=0.02)
    ys, xs = np.nonzero(mask)
    assert np.allclose([xs.mean() + 0.5, ys.mean() + 0.5], px.mean(0), atol=0.05)


@pytest.mark.render
def test_fit_body_finds_a_bare_mannequin_in_a_known_pose():
    from apps.garment.scenes import render_scene

    pose = Pose.from_dict(
        {
            "shoulder_r": [0, -62, 0],
            "shoulder_l": [0, 58, 0],
            "elbow_r": [0, -18, 0],
            "elbow_l": [0, 10, 0],
            "hip_r": [0, 4, 0],
            "hip_l": [0, -6, 0],
        }
    )
    body = Mannequin.build()
    camera = scene_camera()
    caps = body.capsules(pose.angles[None])[0]
    # A tiny garment far behind the body keeps the renderer's mesh input valid.
    far = np.array([[0.0, 3.0, 0.0], [0.01, 3.0, 0.0], [0.0, 3.0, 0.01]])
    image, person, _ = render_scene(
        camera,
        scene_light("midday"),
        caps,
        [(far, np.array([[0, 1, 2]]), (10, 10, 10))],
        masks=False,
    )
    settings = RecoverySettings()
    fit = fit_body(person, skin_mask(image, person), camera, settings)
    errors = joint_angle_errors(fit.pose, pose)
    assert max(errors.values()) < 3.0, errors
    assert fit.shape.height == pytest.approx(1.70, abs=0.02)
    assert np.abs(fit.offset).max() < 0.01
    assert set(errors) == set(JOINTS)
