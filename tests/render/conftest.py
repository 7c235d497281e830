"""Fixtures of the render tests: a small hanging cloth and cameras on either side of it."""

import pytest

from render.camera import CameraSpec

from .shapes import CLOTH_CENTRE_Z, IMAGE_SIZE, grid_cloth


@pytest.fixture
def cloth():
    return grid_cloth()


@pytest.fixture
def front_camera() -> CameraSpec:
    """48 x 48 camera 1.2 m in front of the cloth (on -y), looking at its centre."""
    return CameraSpec(
        position=(0.0, -1.2, CLOTH_CENTRE_Z),
        look_at=(0.0, 0.0, CLOTH_CENTRE_Z),
        yfov_deg=40.0,
        width=IMAGE_SIZE,
        height=IMAGE_SIZE,
    )


@pytest.fixture
def back_camera(front_camera) -> CameraSpec:
    """The front camera mirrored to the other side of the cloth (+y)."""
    return CameraSpec(
        position=(0.0, 1.2, CLOTH_CENTRE_Z),
        look_at=front_camera.look_at,
        yfov_deg=front_camera.yfov_deg,
        width=front_camera.width,
        height=front_camera.height,
    )
