"""The recovery: swarm known-answer tests on tiny scenes, the command's files, bad input."""

import json
import xml.etree.ElementTree as ET
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
from hydra import compose, initialize_config_dir

import apps.garment.recover as recover_entry
from apps.garment.image import SilhouetteTarget, mesh_mask
from apps.garment.recovery import _hinges, _swarm, accuracy
from apps.garment.scenes import (
    GARMENT_COLORS,
    POSES,
    SCENES,
    drape_scene,
    render_scene,
    scene_camera,
    scene_light,
)
from common.errors import InputError
from simulator.garment.body import Mannequin
from simulator.garment.curvature import regional_curvature
from simulator.garment.drape import (
    DrapeSettings,
    GarmentBatch,
    drape,
    garment_material,
    register_batch,
)
from simulator.garment.patterns import PatternTopology, build_pattern, default_params

CONFIGS = str(Path(__file__).resolve().parents[3] / "configs")
TINY = [
    "recovery.edge_length=0.1",
    "recovery.swarm_size=2",
    "recovery.rounds=1",
    "recovery.sizing_iters=1",
    "recovery.material_iters=1",
    "recovery.joint_rounds=1",
    "recovery.pose_iters=1",
    "recovery.body_swarm=4",
    "recovery.body_iters=3",
    "recovery.drape_steps=6",
    "recovery.first_drape_steps=12",
]


def _tiny_drapes(topology, body, coords, bend, stretch, angles, start, steps=60):
    caps = body.capsules(angles)
    settings = DrapeSettings(max_steps=steps, speed_tol=0.02)
    batch = GarmentBatch.build(
        topology, coords, garment_material(bend, stretch), caps, settings, pos_hint=start
    )
    return drape(batch, start, settings).pos.numpy()


def _swarm_minimise(objective, lo, hi, incumbent, size, iters, seed=0):
    swarm = _swarm(np.asarray(lo), np.asarray(hi), size, seed, incumbent, spread=0.3)
    for _ in range(iters):
        swarm.tell(objective(swarm.ask()))
    return swarm.best_x, swarm.best_f


def test_swarm_recovers_a_known_skirt_length_from_its_silhouette():
    """Sizing swarm (Eq. 6.10 on batched drapes) on a tiny scene: r2 comes back."""
    body = Mannequin.build()
    topology = PatternTopology.build("skirt", 0.1)
    camera = scene_camera(160)
    angles = POSES["a"].angles[None]
    truth = {**default_params("skirt"), "r2": 0.55}
    pattern = build_pattern("skirt", truth, topology=topology)
    x0 = register_batch(topology, pattern.coords[None], [truth], body, angles)
    target_pos = _tiny_drapes(topology, body, pattern.coords[None], [10.0], [1.0], angles, x0)
    px, _ = camera.project(target_pos[0])
    target = SilhouetteTarget.from_mask(mesh_mask(px, topology.tri_indices, (160, 160)))

    def objective(xs):
        params = [{**truth, "r2": float(x[0])} for x in xs]
        coords = np.stack([topology.coords(p) for p in params])
        start = np.repeat(target_pos, len(xs), 0)  # warm start, as the recovery does
        pos = _tiny_drapes(
            topology,
            body,
            coords,
            [10.0] * len(xs),
            [1.0] * len(xs),
            np.repeat(angles, len(xs), 0),
            start,
            steps=30,
        )
        return np.array(
            [
                target.distance(mesh_mask(camera.project(p)[0], topology.tri_indices, (160, 160)))
                for p in pos
            ]
        )

    best, _ = _swarm_minimise(objective, [0.3], [0.7], [0.4], size=6, iters=4)
    assert abs(best[0] - 0.55) < 0.04, best


def test_swarm_recovers_a_known_bending_stiffness_from_the_curvature():
    """Material swarm (Eq. 6.5 with a known target K) on batched drapes: bend comes back."""
    body = Mannequin.build()
    topology = PatternTopology.build("skirt", 0.1)
    angles = POSES["a"].angles[None]
    params = default_params("skirt")
    pattern = build_pattern("skirt", params, topology=topology)
    x0 = register_batch(topology, pattern.coords[None], [params], body, angles)
    tri = torch.as_tensor(topology.tri_indices)
    edges = torch.as_tensor(_hinges(topology))
    whole = np.zeros(topology.vert_count, dtype=np.int64)

    def curvature(bends):
        n = len(bends)
        pos = _tiny_drapes(
            topology,
            body,
            np.repeat(pattern.coords[None], n, 0),
            bends,
            [1.0] * n,
            np.repeat(angles, n, 0),
            np.repeat(x0, n, 0),
            steps=80,
        )
        return regional_curvature(torch.as_tensor(pos), tri, edges, whole, 1)[:, 0].numpy()

    target = curvature([40.0])[0]

    def objective(xs):
        return ((curvature(10 ** xs[:, 0]) - target) / target) ** 2

    best, _ = _swarm_minimise(objective, [0.0], [2.0], [1.0], size=6, iters=4)
    bend = 10 ** best[0]
    assert accuracy({"bend": bend}, {"bend": 40.0}) > 0.7, bend


def test_accuracy_is_the_thesis_measure():
    assert accuracy({"a": 1.1, "b": 2.0}, {"a": 1.0, "b": 2.5}) == pytest.approx(1 - 0.15)


def _tiny_image(tmp_path: Path, size: int = 128) -> tuple[Path, Path, Path]:
    scene = next(s for s in SCENES if s.name == "skirt_low_midday")
    body = Mannequin.build()
    draped = drape_scene(scene, body, 0.1, DrapeSettings(max_steps=40, speed_tol=0.03))
    caps = body.capsules(scene.pose_angles()[None])[0]
    image, person, masks = render_scene(
        scene_camera(size),
        scene_light("midday"),
        caps,
        [
            (r.pos[0].numpy(), p.topology.tri_indices, GARMENT_COLORS[g])
            for g, (p, r) in draped.items()
        ],
    )
    paths = tmp_path / "in.png", tmp_path / "mask.png", tmp_path / "person.png"
    cv2.imwrite(str(paths[0]), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
    cv2.imwrite(str(paths[1]), masks[0].astype(np.uint8) * 255)
    cv2.imwrite(str(paths[2]), person.astype(np.uint8) * 255)
    return paths


def _compose(*overrides):
    with initialize_config_dir(config_dir=CONFIGS, version_base="1.3"):
        return compose(config_name="garment", overrides=list(overrides))


@pytest.mark.render
@pytest.mark.parametrize("material_mesh", [None, 0.07])
def test_the_command_writes_its_files(material_mesh, tmp_path):
    """Every output, with the material step on the sizing mesh or on a finer one of its own
    (the drape written is then on the finer mesh)."""
    image, mask, person = _tiny_image(tmp_path)
    out = tmp_path / "out"
    extra = [] if material_mesh is None else [f"recovery.material_edge_length={material_mesh}"]
    cfg = _compose(
        f"image={image}",
        "garment=skirt",
        f"mask={mask}",
        f"person_mask={person}",
        f"out_dir={out}",
        *TINY,
        *extra,
    )
    result = recover_entry.run(cfg)
    mesh = PatternTopology.build("skirt", material_mesh or 0.1)
    assert result.pattern.topology.vert_count == mesh.vert_count
    assert result.pos.shape == (mesh.vert_count, 3)
    names = sorted(p.name for p in out.iterdir())
    assert names == sorted([*recover_entry.OUTPUTS, "garment.obj", "body.obj"])
    svg = ET.parse(out / "pattern.svg").getroot()
    assert len(svg.findall("{http://www.w3.org/2000/svg}polygon")) == 4
    pattern = json.loads((out / "pattern.json").read_text())
    assert pattern["garment"] == "skirt" and set(pattern["material"]) >= {"bend", "stretch"}
    report = json.loads((out / "result.json").read_text())
    assert {k: v["value"] for k, v in report["params"].items()} == result.pattern.params
    assert [h["stage"] for h in report["history"]] == [
        "material",
        "sizing",
        "pose",
        "joint_material",
    ]
    for name in ("overlay.png", "side_by_side.png", "objective.png"):
        picture = cv2.imread(str(out / name))
        assert picture is not None and picture.size > 0, name
    assert cv2.imread(str(out / "side_by_side.png")).shape[1] == 2 * 128 + 8
    garment = (out / "garment.obj").read_text()
    assert garment.count("\nv ") == result.pattern.topology.vert_count


@pytest.mark.slow
@pytest.mark.render
def test_same_config_and_seed_write_the_same_bytes(tmp_path):
    image, mask, person = _tiny_image(tmp_path)
    outs = []
    for k in range(2):
        out = tmp_path / f"out{k}"
        cfg = _compose(
            f"image={image}",
            "garment=skirt",
            f"mask={mask}",
            f"person_mask={person}",
            f"out_dir={out}",
            *TINY,
        )
        recover_entry.run(cfg)
        outs.append(out)
    for name in recover_entry.OUTPUTS:
        if name != "timings.json":
            assert (outs[0] / name).read_bytes() == (outs[1] / name).read_bytes(), name


def _refuse(*args, **kwargs):
    raise AssertionError("the recovery ran although a field was bad")


@pytest.mark.parametrize(
    ("make", "override", "message"),
    [
        ("text", "", "image: cannot read"),
        ("empty", "", "image: cannot read"),
        ("none", "", "image: no such file"),
        ("image", "garment=dress", "garment must be one of skirt, pants, tshirt; got 'dress'"),
        ("image", "recovery.swarm_size=1", "recovery.swarm_size must be an integer >= 2"),
        ("image", "recovery.edge_length=0.5", "recovery.edge_length must lie in [0.02, 0.1] m"),
        (
            "image",
            "recovery.material_edge_length=0.01",
            "recovery.material_edge_length must lie in [0.02, 0.1] m",
        ),
        ("image", "+recovery.speed=3", "recovery: unknown ['speed']"),
        (
            "image",
            "under=[tshirt]",
            "under: 'tshirt' cannot be worn under a skirt; allowed: ['pants']",
        ),
        ("image", "under=pants", "under must be a list of garment names, got 'pants'"),
        ("image", "export=gif", "export must be one of obj, ply; got 'gif'"),
        ("image", "camera.yfov_deg=500", "camera.yfov_deg must be a number in [1.0, 120.0]"),
        ("bad_mask", "", "mask: "),
        ("small_person", "", "image: the person found is 12 px tall; at least 100 px"),
    ],
)
def test_bad_input_is_one_line_and_writes_nothing(make, override, message, tmp_path, monkeypatch):
    monkeypatch.setattr(recover_entry, "recover_garment", _refuse)
    picture = np.full((160, 160, 3), 200, np.uint8)
    path = tmp_path / "in.png"
    extra = []
    if make == "text":
        path.write_text("not an image")
    elif make == "empty":
        path.write_bytes(b"")
    elif make != "none":
        cv2.imwrite(str(path), picture)
    if make == "bad_mask":
        cv2.imwrite(str(tmp_path / "m.png"), np.full((80, 90), 255, np.uint8))
        extra.append(f"mask={tmp_path / 'm.png'}")
    if make == "small_person":
        person = np.zeros((160, 160), np.uint8)
        person[50:62, 70:80] = 255
        cv2.imwrite(str(tmp_path / "p.png"), person)
        extra.append(f"person_mask={tmp_path / 'p.png'}")
    out = tmp_path / "out"
    overrides = [f"image={path}", "garment=skirt", f"out_dir={out}", *extra]
    if override:
        overrides.append(override)
    cfg = _compose(*overrides)
    with pytest.raises(InputError) as info:
        recover_entry.run(cfg)
    text = str(info.value)
    assert message in text, text
    assert "\n" not in text
    assert not out.exists()


def test_mask_size_error_names_both_sizes(tmp_path):
    cv2.imwrite(str(tmp_path / "m.png"), np.full((80, 90), 255, np.uint8))
    with pytest.raises(InputError, match=r"mask: .* is 90 x 80 px, the image is 160 x 160 px"):
        recover_entry.read_mask(tmp_path / "m.png", "mask", (160, 160))


@pytest.mark.render
def test_the_evaluator_measures_the_true_drape_as_the_image_does():
    """Silhouette (Eq. 6.10-6.11) and wrinkle density of a particle that is the true drape,
    re-rendered under the true light, agree with what the image says: the objectives are zero
    at the truth."""
    from types import SimpleNamespace

    from apps.garment.recovery import BodyFit, RecoverySettings, _Evaluator, garment_target
    from simulator.garment.body import Pose
    from simulator.garment.patterns import GarmentType

    scene = next(s for s in SCENES if s.name == "skirt_low_midday")
    body = Mannequin.build()
    camera = scene_camera()
    pattern, result = drape_scene(scene, body, 0.1)["skirt"]
    pos = result.pos.numpy()
    caps = body.capsules(scene.pose_angles()[None])
    image, person, masks = render_scene(
        camera,
        scene_light(scene.lighting),
        caps[0],
        [(pos[0], pattern.topology.tri_indices, GARMENT_COLORS["skirt"])],
    )
    fit = BodyFit(body.shape, Pose(scene.pose_angles()), np.zeros(3), 0.0)
    target = garment_target(
        image, GarmentType.SKIRT, person, np.zeros_like(person), fit, camera, masks[0]
    )
    assert target.density[0] > 1.0  # the drape has folds to find
    light = SimpleNamespace(light_spec=lambda: scene_light(scene.lighting))
    timings = dict.fromkeys(("simulation", "rendering", "bookkeeping"), 0.0)
    settings = RecoverySettings(edge_length=0.1)
    ev = _Evaluator(pattern.topology, target, fit, camera, light, settings, timings, None)
    try:
        assert ev.silhouette(pos)[0] < 3.0  # px: anti-aliased outline pixels
        np.testing.assert_allclose(ev.densities(pos, caps), target.density[None], rtol=0.05)
    finally:
        ev.close()


def test_a_swarm_without_spread_covers_the_box_and_keeps_the_incumbent():
    lo, hi = np.array([0.0, -1.0]), np.array([2.0, 1.0])
    swarm = _swarm(lo, hi, 8, 3, np.array([0.1, -0.9]), spread=None)
    x = swarm.ask()
    np.testing.assert_allclose(x[0], [0.1, -0.9])
    unit = (x[1:] - lo) / (hi - lo)
    for d in range(2):  # one particle per eighth of each range, but the incumbent's
        assert len(set(np.floor(unit[:, d] * 8).astype(int))) >= 6
    near = _swarm(lo, hi, 8, 3, np.array([0.1, -0.9]), spread=0.05).ask()
    assert np.ptp(near[:, 0]) < 0.5 < np.ptp(x[:, 0])


def test_the_pose_step_compares_the_body_with_the_person_for_every_layer():
    """Alg. 4's body term (Eq. 6.14) measures the posed body against the person's silhouette,
    for an outer garment (a t-shirt over pants) as for an inner one: zero at the true body, and
    a moved arm costs."""
    from apps.garment.image import capsule_mask
    from apps.garment.recovery import BodyFit, expected_mask, garment_target
    from simulator.garment.body import JOINTS, Pose
    from simulator.garment.patterns import GarmentType

    body = Mannequin.build()
    camera = scene_camera()
    angles = POSES["a"].angles
    fit = BodyFit(body.shape, Pose(angles), np.zeros(3), 0.0)
    shape = (camera.height, camera.width)
    true_body = capsule_mask(camera, body.capsules(angles[None])[0], shape)
    person = true_body.copy()
    tshirt = expected_mask(fit, "tshirt", camera, shape)
    pants = expected_mask(fit, "pants", camera, shape) & ~tshirt
    skin = person & ~tshirt & ~pants
    image = np.full((*shape, 3), 128, np.uint8)
    moved = angles.copy()
    moved[JOINTS.index("shoulder_r"), 1] += 8.0
    moved_body = capsule_mask(camera, body.capsules(moved[None])[0], shape)
    for garment, mask in ((GarmentType.TSHIRT, tshirt), (GarmentType.PANTS, pants)):
        target = garment_target(image, garment, person, skin, fit, camera, mask)
        assert target.body.distance(true_body) == 0.0, garment
        assert target.body.distance(moved_body) > 1.0, garment


def test_an_outer_garment_drapes_over_the_layers_worn_under_it():
    """The true t-shirt of a scene (draped over the pants) is at rest in the recovery's drape
    when the recovery is told the pants are under it; without them it sinks onto the torso."""
    from types import SimpleNamespace

    from apps.garment.recovery import BodyFit, RecoverySettings, _Evaluator, check_under
    from apps.garment.scenes import COVERS
    from simulator.garment.body import Pose, capsule_distance
    from simulator.garment.patterns import GarmentType

    scene = next(s for s in SCENES if s.name == "a_midday")
    body = Mannequin.build()
    camera = scene_camera()
    pattern, result = drape_scene(scene, body, 0.1)["tshirt"]
    pos = result.pos.numpy()
    angles = scene.pose_angles()[None]
    fit = BodyFit(body.shape, Pose(angles[0]), np.zeros(3), 0.0)
    target = SimpleNamespace(
        garment=GarmentType.TSHIRT, mask=np.zeros((camera.height, camera.width), bool)
    )
    torso = [c for c, p in enumerate(body.primitives) if p.name.startswith("torso")]
    moved, gap = {}, {}
    for under in ((), ("pants",)):
        covered = tuple(p for g in check_under("tshirt", under) for p in COVERS[g])
        timings = dict.fromkeys(("simulation", "rendering", "bookkeeping"), 0.0)
        settings = RecoverySettings(edge_length=0.1)
        ev = _Evaluator(
            pattern.topology, target, fit, camera, None, settings, timings, None, covered
        )
        out, caps, _ = ev.drape(pattern.coords[None], [8.0], [1.5], angles, pos, 20)
        moved[under] = np.abs(out[0] - pos[0]).max()
        gap[under] = capsule_distance(out[0], caps[0])[0][:, torso].min()
    assert moved[("pants",)] < 0.002  # m: measured 0.8 mm
    assert moved[()] > 0.02 and gap[()] < 0.01  # measured 4 cm, 4.7 mm from the torso
