"""CameraSpec and LightSpec: validation naming the field, projection, preset framing."""

import dataclasses

import numpy as np
import pytest

from render.camera import DEFAULT_RESOLUTION, CameraSpec
from render.lights import LightFrame, LightSpec

MARGIN_PX = 2.0


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("width", 0),
        ("width", -3),
        ("width", 32.5),
        ("width", True),
        ("height", 0),
        ("yfov_deg", 0.0),
        ("yfov_deg", 180.0),
        ("yfov_deg", -10.0),
        ("yfov_deg", float("nan")),
        ("position", (0.0, 1.0)),
        ("look_at", (0.0, float("inf"), 1.0)),
        ("znear", 0.0),
        ("zfar", 0.01),
    ],
)
def test_camera_rejects_bad_values_naming_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        CameraSpec(**{field: value})


def test_camera_rejects_degenerate_view():
    with pytest.raises(ValueError, match="look_at"):
        CameraSpec(position=(0, 0, 1), look_at=(0, 0, 1))
    with pytest.raises(ValueError, match="up"):
        CameraSpec(position=(0, 0, 2), look_at=(0, 0, 1), up=(0, 0, 1))


def test_camera_coerces_config_lists_and_stays_frozen():
    cam = CameraSpec(position=[0, -2, 1], look_at=[0, 0, 1], width=64, height=np.int64(48))
    assert cam.position == (0.0, -2.0, 1.0)
    assert isinstance(cam.height, int)
    with pytest.raises(dataclasses.FrozenInstanceError):
        cam.width = 3  # type: ignore[misc]


def test_project_centre_axes_and_pose_orthonormal():
    cam = CameraSpec(position=(0, -2, 1), look_at=(0, 0, 1), width=64, height=48)
    pose = cam.pose()
    np.testing.assert_allclose(pose[:3, :3].T @ pose[:3, :3], np.eye(3), atol=1e-12)
    px, depth = cam.project(np.array([[0, 0, 1], [0.1, 0, 1], [0, 0, 1.1]]))
    np.testing.assert_allclose(px[0], [32, 24], atol=1e-9)
    np.testing.assert_allclose(depth, [2, 2, 2], atol=1e-12)
    assert px[1, 0] > 32  # +x is to the right
    assert px[2, 1] < 24  # +z (up) is towards the top row


def _wind_motion_envelope() -> np.ndarray:
    """Cloth points from hanging to horizontal (+y), with +-15 deg wind yaw, 4 % stretch."""
    points = []
    for lift in np.radians(np.linspace(0, 90, 10)):
        for yaw in np.radians([-15, 0, 15]):
            for s in np.linspace(0, 0.52, 8):
                for x in np.linspace(-0.25, 0.25, 6):
                    points.append(
                        [
                            x + s * np.sin(lift) * np.sin(yaw),
                            s * np.sin(lift) * np.cos(yaw),
                            1.0 - s * np.cos(lift),
                        ]
                    )
    return np.asarray(points)


def _arm_envelope() -> np.ndarray:
    """Arm capsules through the 90 deg flexion plus the drape at rest (hanging 0.2 m)."""
    points = []
    for bend in np.radians(np.linspace(0, 90, 7)):
        wrist = np.array([0.28 * np.cos(bend), 0, 1 + 0.28 * np.sin(bend)])
        for t in np.linspace(0, 1, 5):
            points.append(np.array([-0.345, 0, 1]) * (1 - t) + wrist * t)
    for x in np.linspace(-0.25, 0.25, 6):
        for y in (-0.06, 0.06):
            for z in (0.8, 1.05):
                points.append([x, y, z])
    return np.asarray(points)


@pytest.mark.parametrize(
    ("preset", "envelope", "rest_width"),
    [
        (CameraSpec.wind, _wind_motion_envelope, 0.4),
        (CameraSpec.arm, _arm_envelope, 0.5),
    ],
)
def test_presets_keep_the_motion_in_frame_and_the_cloth_large(preset, envelope, rest_width):
    cam = preset()
    assert (cam.width, cam.height) == (DEFAULT_RESOLUTION, DEFAULT_RESOLUTION)
    px, depth = cam.project(envelope())
    assert (depth > cam.znear).all()
    assert px.min() >= MARGIN_PX and px.max() <= cam.width - MARGIN_PX, (px.min(0), px.max(0))
    # The 0.5 m cloth at rest spans a good part of the image width.
    ends, _ = cam.project(np.array([[-0.25, 0, 0.9], [0.25, 0, 0.9]]))
    assert abs(ends[1, 0] - ends[0, 0]) >= rest_width * cam.width
    assert preset(64, 32).width == 64


def test_light_validation_names_the_field():
    for field, value in [
        ("intensity", -1.0),
        ("ambient_intensity", float("nan")),
        ("direction", (0, 0, 0)),
        ("color", (1.5, 1, 1)),
        ("frame", "sideways"),
    ]:
        with pytest.raises(ValueError, match=field):
            LightSpec(**{field: value})


def test_light_direction_normalised_and_camera_frame_follows_camera():
    light = LightSpec(direction=(0, 0, -2))
    assert light.direction == (0.0, 0.0, -1.0)
    assert LightSpec.default() == LightSpec()
    front = CameraSpec(position=(0, -2, 1), look_at=(0, 0, 1))
    back = CameraSpec(position=(0, 2, 1), look_at=(0, 0, 1))
    # Camera -z is the viewing direction: a light along it travels away from the camera.
    np.testing.assert_allclose(light.world_direction(front.pose()), [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(light.world_direction(back.pose()), [0, -1, 0], atol=1e-12)
    world = LightSpec(direction=(0, 0, -1), frame=LightFrame.WORLD)
    np.testing.assert_allclose(world.world_direction(back.pose()), [0, 0, -1], atol=1e-12)
    pose = light.pose(front.pose())
    np.testing.assert_allclose(-pose[:3, 2], [0, 1, 0], atol=1e-12)  # shines along local -z


def test_light_jitter_stays_in_cone_and_is_deterministic():
    light = LightSpec()
    for seed in range(20):
        a = light.jittered(np.random.default_rng(seed), direction_deg=25, intensity_rel=0.3)
        b = light.jittered(np.random.default_rng(seed), direction_deg=25, intensity_rel=0.3)
        assert a == b
        cos = float(np.dot(a.direction, light.direction))
        assert cos >= np.cos(np.radians(25)) - 1e-9
        assert 0.7 * light.intensity <= a.intensity <= 1.3 * light.intensity
