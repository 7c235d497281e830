"""Eq. 6.7 curvature on a cylinder, silhouettes (Eq. 6.10-6.11), wrinkle density, light fit."""

import math

import numpy as np
import pytest
import torch

from apps.garment.image import (
    SilhouetteTarget,
    capsule_mask,
    mesh_mask,
    region_map,
    wrinkle_density,
)
from apps.garment.recovery import BodyFit, estimate_light
from apps.garment.scenes import scene_camera, scene_light
from simulator.garment.body import Mannequin, Pose
from simulator.garment.curvature import edge_curvature, regional_curvature, vertex_mean_curvature
from simulator.mesh import TriMesh


def _cylinder(radius, around=48, along=12, length=0.3):
    grid = TriMesh.grid(around + 1, along, size_u=2 * math.pi * radius, size_v=length)
    uv = grid.uv.numpy()
    angle = uv[:, 0] / radius
    pos = np.stack([radius * np.cos(angle), radius * np.sin(angle), uv[:, 1]], -1)
    return TriMesh.from_arrays(pos, grid.tri_indices.numpy(), uv), torch.as_tensor(pos)[None]


@pytest.mark.parametrize("radius", [0.05, 0.2])
def test_eq_6_7_on_a_cylinder(radius):
    mesh, pos = _cylinder(radius)
    kappa = edge_curvature(pos, mesh.tri_indices, mesh.edge_indices)[0]
    # Edges along the axis bend by the angle between neighbouring facets.
    e = mesh.edge_indices
    axial = torch.linalg.vector_norm(pos[0, e[:, 3], :2] - pos[0, e[:, 2], :2], dim=-1) < 1e-12
    chord_angle = 2 * math.pi / 48
    # The facets' normal curvature 2 sin(theta/2) / chord -> 1/R as the mesh refines.
    exact = 2 * math.sin(chord_angle / 2) / (2 * radius * math.sin(chord_angle / 2)) / 1.0
    np.testing.assert_allclose(kappa[axial].numpy(), exact, rtol=2e-2)
    assert kappa[~axial].abs().max() < 1e-9  # flat across circumferential edges and diagonals
    # The area-weighted mean over interior vertices (away from the ends and the open seam) is
    # the mean curvature 1 / (2R) (single vertices alternate with their lumped areas).
    angle = torch.atan2(pos[0, :, 1], pos[0, :, 0]) % (2 * math.pi)
    interior = (pos[0, :, 2] > 0.01) & (pos[0, :, 2] < 0.29) & (angle > 0.2) & (angle < 6.0)
    regions = np.where(interior.numpy(), 0, -1)
    k = regional_curvature(pos, mesh.tri_indices, mesh.edge_indices, regions, 1)[0, 0]
    assert float(k) == pytest.approx(1 / (2 * radius), rel=2e-2)
    h, area = vertex_mean_curvature(pos, mesh.tri_indices, mesh.edge_indices)
    mean = (h * area)[0, interior].sum() / area[0, interior].sum()
    assert float(mean) == pytest.approx(float(k))


def test_regional_curvature_converges_to_the_mean_curvature():
    errors = []
    for around in (12, 24, 48):
        mesh, pos = _cylinder(0.1, around=around)
        regions = np.where(pos[0, :, 2].numpy() < 0.15, 0, 1)
        k = regional_curvature(pos, mesh.tri_indices, mesh.edge_indices, regions, 2)[0]
        # Boundary rows have half their hinges: compare against the same rows' weighting.
        errors.append(float((k[0] - 5.0).abs()))
    assert errors[-1] < errors[0]


def test_silhouette_distance_of_a_shifted_disc_is_the_shift():
    ys, xs = np.mgrid[:100, :100]
    disc = (xs - 50) ** 2 + (ys - 50) ** 2 <= 20**2
    shifted = (xs - 54) ** 2 + (ys - 50) ** 2 <= 20**2
    target = SilhouetteTarget.from_mask(disc)
    assert target.distance(disc) == 0.0
    d = target.distance(shifted)
    xor = np.count_nonzero(disc ^ shifted) / np.count_nonzero(disc | shifted)
    # Mean outline distance of two discs 4 px apart is 8/pi px (plus the area term).
    assert d - 100 * xor == pytest.approx(8 / math.pi, abs=0.6)
    assert target.distance(np.zeros_like(disc)) == math.inf


def test_mesh_mask_fills_projected_triangles():
    px = np.array([[10.0, 10.0], [50.0, 10.0], [10.0, 50.0], [50.0, 50.0]])
    mask = mesh_mask(px, np.array([[0, 1, 2], [1, 3, 2]]), (64, 64))
    assert abs(np.count_nonzero(mask) - 40 * 40) < 120


def test_mesh_mask_is_the_union_where_layers_overlap():
    # A square meshed as a grid of 8 x 8 cells, twice (a garment's front and back panels
    # project onto each other): the mask is the square, with no holes where layers overlap
    # or triangles share edges.
    grid = TriMesh.grid(9, 9, size_u=40.0, size_v=40.0)
    px = grid.uv.numpy() + 10.0
    tri = grid.tri_indices.numpy()
    two = np.concatenate([tri, tri + len(px)])
    mask = mesh_mask(np.concatenate([px, px + 0.3]), two, (64, 64))
    assert mask[12:49, 12:49].all()
    assert abs(np.count_nonzero(mask) - 40 * 40) < 160


def test_wrinkle_density_counts_folds_and_ignores_light_scale():
    h, w = 120, 120
    xs = np.arange(w)[None, :].repeat(h, 0)
    mask = np.zeros((h, w), bool)
    mask[10:110, 10:110] = True
    regions = np.where(mask, 0, -1)
    out = []
    for folds, gain in ((4, 1.0), (8, 1.0), (8, 0.5)):
        shade = 0.6 + 0.3 * np.cos(2 * math.pi * folds * xs / 100.0)
        img = np.clip(255 * gain * shade, 0, 255).astype(np.uint8)
        p, _ = wrinkle_density(np.stack([img] * 3, -1), mask, regions, 1, 0.01)
        out.append(p[0])
    assert out[1] > 1.6 * out[0]  # twice the folds, about twice the line length
    assert out[2] == pytest.approx(out[1], rel=0.1)  # log-luminance: intensity scale drops out


@pytest.mark.render
def test_light_estimate_finds_the_key_direction():
    from apps.garment.scenes import render_scene

    body = Mannequin.build()
    pose = Pose.from_dict({"shoulder_r": [0, -65, 0], "shoulder_l": [0, 65, 0]})
    camera = scene_camera(160)
    caps = body.capsules(pose.angles[None])[0]
    for name in ("midday", "sunset"):
        light = scene_light(name)
        # A tiny garment far behind the body keeps the renderer's mesh input valid.
        far = np.array([[0.0, 3.0, 0.0], [0.01, 3.0, 0.0], [0.0, 3.0, 0.01]])
        image, person, _ = render_scene(
            camera, light, caps, [(far, np.array([[0, 1, 2]]), (10, 10, 10))], masks=False
        )
        fit = BodyFit(body.shape, pose, np.zeros(3), 0.0)
        est = estimate_light(image, person, fit, camera)
        truth = np.asarray(light.direction)
        angle = math.degrees(math.acos(np.clip(est.direction @ truth, -1, 1)))
        assert angle < 5.0, (name, angle)


def test_region_map_follows_the_nearest_primitive():
    body = Mannequin.build()
    camera = scene_camera(160)
    caps = body.capsules(np.zeros((1, 15, 3)))[0]
    mask = capsule_mask(camera, caps, (160, 160))
    regions = np.full(len(caps), -1)
    names = [p.name for p in body.primitives]
    regions[names.index("head")] = 0
    regions[names.index("shin_r")] = 1
    out = region_map(camera, caps, regions, mask)
    head_px, _ = camera.project(caps[names.index("head"), None, :3])
    x, y = np.round(head_px[0]).astype(int)
    assert out[y, x] == 0
    assert set(np.unique(out)) == {-1, 0, 1}
