"""Independent-engine footage (MuJoCo flex cloth, MuJoCo's renderer): the layout the real-footage
reader expects, labels, the physics, determinism and one-line refusals.

The footage is written by the command in a child process: MuJoCo picks its OpenGL backend when
it is first imported, and another test may already have imported it without EGL here.
"""

import csv
import itertools
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from sim2real.study import independent
from tests.conftest import subprocess_env

ROOT = Path(__file__).resolve().parents[2]
COLUMNS = [
    "video",
    "stiffness",
    "density",
    "wind",
    "fps",
    "fabric",
    "stretch_stiffness",
    "bend_stiffness",
    "vertex_speed",
    "out_of_plane_rms",
    "edge_strain_rms",
]
SMALL = [
    "--fabrics",
    "2",
    "--winds",
    "2",
    "--size",
    "32",
    "--frames",
    "10",
    "--seed",
    "3",
    "--no-progress",
]


def _command(*args, timeout=300):
    return subprocess.run(
        [sys.executable, "-m", "sim2real.study.independent", *args],
        cwd=ROOT,
        env=subprocess_env(),
        capture_output=True,
        text=True,
        timeout=timeout,
    )


@pytest.fixture(scope="module")
def renders():
    """Skip (naming why) unless MuJoCo imports and renders offscreen in a fresh process."""
    probe = subprocess.run(
        [
            sys.executable,
            "-c",
            "from sim2real.study.independent import render_available as r; print(r() or 'ok')",
        ],
        cwd=ROOT,
        env=subprocess_env(),
        capture_output=True,
        text=True,
        timeout=120,
    )
    reason = probe.stdout.strip().splitlines()[-1] if probe.stdout.strip() else probe.stderr
    if probe.returncode != 0 or reason != "ok":
        pytest.skip(f"MuJoCo offscreen (EGL) rendering unavailable: {reason.strip()[-300:]}")


@pytest.fixture(scope="module")
def footage(renders, tmp_path_factory):
    out = tmp_path_factory.mktemp("independent") / "set"
    done = _command("--out", str(out), "--codec", "png", *SMALL)
    assert done.returncode == 0, done.stderr
    return out


def _files(folder: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()
    }


@pytest.mark.render
def test_the_folder_reads_as_real_footage(footage):
    from datasets.real_video import RealVideoDataset
    from sim2real.domains import real_clips

    dataset = RealVideoDataset(footage, size=32, clip_len=10, clip_stride=10, target_fps=15)
    assert [v.name for v in dataset.videos] == ["v000", "v001", "v002", "v003"]
    assert dataset.skipped == () and len(dataset) == 4
    assert dataset.group_column == "fabric"  # the winds of one fabric are one group
    assert [v.group for v in dataset.videos] == ["f00", "f00", "f01", "f01"]
    sample = dataset[0]
    assert tuple(sample["video"].shape) == (10, 3, 32, 32)
    assert sample["wind"] == "W1" and sample["stiffness"] > 0 and sample["density"] > 0
    assert float(sample["video"].std()) > 0.01  # not a blank frame
    clips = real_clips(
        footage, size=32, clip_len=10, clip_stride=10, fps=15.0, max_clips_per_video=3
    )
    assert clips.frames.shape == (4, 10, 32, 32, 3) and clips.group_count == 4
    extra = RealVideoDataset(footage, size=32, columns=("stretch_stiffness", "bend_stiffness"))
    assert extra[0]["bend_stiffness"] > 0


@pytest.mark.render
def test_labels_have_the_columns_and_positive_values(footage):
    with open(footage / "labels.csv", newline="") as handle:
        reader = csv.DictReader(handle)
        rows = list(reader)
    assert reader.fieldnames == COLUMNS
    assert [r["wind"] for r in rows] == ["W1", "W3", "W1", "W3"]  # --winds 2: W1 and W3
    for row in rows:
        for column in ("stiffness", "density", "fps", "stretch_stiffness", "bend_stiffness"):
            assert float(row[column]) > 0, (row["video"], column)
    ranges = independent.measured_ranges()
    basis = ranges["basis_bend"][0]
    for row in rows:  # stiffness = the bend multiplier on the basis fabric, as the sealed sets'
        assert float(row["stiffness"]) == pytest.approx(
            float(row["bend_stiffness"]) / basis, rel=1e-3
        )
        for name in ("stretch_stiffness", "bend_stiffness", "density"):
            low, high = ranges[name]
            assert low * 0.999 <= float(row[name]) <= high * 1.001, name
    engine = json.loads((footage.parent / "set.engine.json").read_text())
    for topic in (
        "wind_model",
        "wind",
        "material_law",
        "pinning",
        "mass_distribution",
        "texture",
        "backdrop",
        "codec",
        "frame_rate",
    ):
        assert set(engine["differences"][topic]) == {"ours", "here"}, topic
    assert engine["codec"]["used"] == "png" and engine["frame_rate"] == 15.0
    truth = engine["videos"]
    assert [t["video"] for t in truth] == [r["video"] for r in rows]
    assert [t["bend_stiffness_nm"] for t in truth] == [float(r["bend_stiffness"]) for r in rows]
    for t, r in zip(truth, rows, strict=True):  # the 3D motion columns are the engine's truth
        assert float(r["vertex_speed"]) == pytest.approx(t["mean_vertex_speed_m_s"], rel=1e-5)
        assert float(r["out_of_plane_rms"]) == pytest.approx(t["out_of_plane_rms_m"], rel=1e-5)
        assert float(r["edge_strain_rms"]) == pytest.approx(t["edge_strain_rms"], rel=1e-5)
        assert 0 < t["edge_strain_rms"] < 0.05
    assert all(len(list((footage / r["video"]).glob("*.png"))) == 10 for r in rows)


def _motion(pos: np.ndarray) -> dict[str, float]:
    """Mean vertex speed per frame, non-rigid motion between frames, out-of-plane RMS [m]."""
    nonrigid = []
    for a, b in itertools.pairwise(pos):
        a, b = a - a.mean(axis=0), b - b.mean(axis=0)
        u, _, vt = np.linalg.svd(a.T @ b)
        rotation = u @ np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))]) @ vt
        nonrigid.append(np.sqrt(((a @ rotation - b) ** 2).sum(axis=1).mean()))
    return {
        "speed": float(np.linalg.norm(np.diff(pos, axis=0), axis=-1).mean()),
        "nonrigid": float(np.mean(nonrigid)),
        "out_of_plane": independent.out_of_plane_rms(pos),
    }


def _mujoco():
    try:
        return independent.import_mujoco(render=False)
    except (ImportError, OSError, AttributeError) as error:
        pytest.skip(f"cannot import mujoco (a dev dependency): {error!r}")


@pytest.mark.parametrize("drag", independent.WIND_DRAGS)
def test_a_stiffer_fabric_deforms_less_under_the_same_wind(drag):
    _mujoco()
    scene = independent.EngineScene(wind_drag=drag)
    ranges = independent.measured_ranges()
    density = float(np.sqrt(np.prod(ranges["density"])))
    soft = independent.EngineFabric(
        0, ranges["stretch_stiffness"][0], ranges["bend_stiffness"][0], density, 1.0
    )
    stiff = independent.EngineFabric(
        0, ranges["stretch_stiffness"][1], ranges["bend_stiffness"][1], density, 1.0
    )
    # the same index, seed and level: the same gusts, waviness and fan yaw
    motion = {
        name: _motion(independent.simulate_positions(fabric, 2, seed=0, frames=20, scene=scene))
        for name, fabric in (("soft", soft), ("stiff", stiff))
    }
    assert motion["soft"]["speed"] > 0.003  # W3 moves the cloth (m per frame)
    if drag == "isotropic":  # plate drag swings a stiff sheet as a whole about as fast
        assert motion["stiff"]["speed"] < motion["soft"]["speed"], motion
    assert motion["stiff"]["nonrigid"] < 0.95 * motion["soft"]["nonrigid"], motion
    assert motion["stiff"]["out_of_plane"] < 0.9 * motion["soft"]["out_of_plane"], motion


def test_edge_strain_is_zero_under_rigid_motion_and_the_stretch_under_scaling():
    rng = np.random.default_rng(0)
    rest_pos = rng.normal(size=(6, 3))
    edges = np.array([[0, 1], [1, 2], [2, 3], [3, 4], [4, 5], [0, 5], [1, 4]])
    rest = np.linalg.norm(rest_pos[edges[:, 0]] - rest_pos[edges[:, 1]], axis=-1)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    moved = np.stack([rest_pos, rest_pos @ q.T + [0.3, -1.0, 2.0]])
    assert independent.edge_strain_rms(moved, edges, rest) == pytest.approx(0.0, abs=1e-12)
    stretched = np.stack([rest_pos * 1.01, rest_pos * 0.98])
    expected = np.sqrt((0.01**2 + 0.02**2) / 2)
    assert independent.edge_strain_rms(stretched, edges, rest) == pytest.approx(expected)


def test_a_fabric_of_lower_stretch_stiffness_strains_more_under_the_same_wind():
    mujoco = _mujoco()
    scene = independent.EngineScene(wind_drag="plate")
    ranges = independent.measured_ranges()
    density = float(np.sqrt(np.prod(ranges["density"])))
    bend = float(np.sqrt(np.prod(ranges["bend_stiffness"])))
    strain = {}
    for name, stretch in zip(("soft", "stiff"), ranges["stretch_stiffness"], strict=True):
        fabric = independent.EngineFabric(0, stretch, bend, density, 1.0)
        model = mujoco.MjModel.from_xml_string(independent.scene_mjcf(scene, fabric))
        pos = independent.simulate_positions(fabric, 0, seed=0, frames=10, scene=scene)
        strain[name] = independent.edge_strain_rms(
            pos, np.asarray(model.flex_edge), np.asarray(model.flexedge_length0)
        )
    # load over stiffness: about the stiffness ratio (26x), more than 10x
    assert strain["soft"] > 10 * strain["stiff"] > 0, strain


def _plate_sheet(rotation: np.ndarray | None = None):
    """Plate drag on the flat rest sheet (x-z plane), optionally rotated about its top edge."""
    mujoco = _mujoco()
    scene = independent.EngineScene(wind_drag="plate", plate_friction_cd=0.05)
    fabric = independent.draw_fabric(0, 0)
    model = mujoco.MjModel.from_xml_string(independent.scene_mjcf(scene, fabric))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    assert model.opt.density == 0.0  # MuJoCo's own fluid model is off
    drag = independent.PlateDrag(mujoco, model, data, scene)
    qpos = np.zeros(model.nq)
    if rotation is not None:
        rest = np.array(data.flexvert_xpos)
        centre = np.array([0.0, rest[:, 1].mean(), rest[:, 2].max()])  # on the pinned edge
        moved = (rest - centre) @ rotation.T + centre
        for vert, body in enumerate(model.flex_vertbodyid):
            joints = np.flatnonzero(model.jnt_bodyid == body) if body > 0 else []
            for joint in joints:  # orthonormal slide axes: displacement along each
                qpos[model.jnt_qposadr[joint]] = (moved[vert] - rest[vert]) @ data.xaxis[joint]
    return scene, drag, qpos, np.zeros(model.nv)


@pytest.mark.parametrize("tilt_deg", [0.0, 35.0])
def test_plate_drag_is_pressure_on_the_normal_plus_skin_friction(tilt_deg):
    c, s = np.cos(np.radians(tilt_deg)), np.sin(np.radians(tilt_deg))
    rotation = np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])  # about x: tilts the sheet
    scene, drag, qpos, qvel = _plate_sheet(rotation)
    normal = rotation @ np.array([0.0, 1.0, 0.0])
    area = scene.size**2
    half_rho = 0.5 * 1.2
    for wind in (np.array([0.0, 2.0, 0.0]), np.array([1.5, 0.0, 0.0]), np.array([0.3, -1.1, 0.4])):
        total = drag.vertex_forces(qpos, qvel, wind).sum(axis=0)
        along = wind @ normal
        tangential = wind - along * normal
        expected = (
            half_rho
            * area
            * (
                scene.plate_normal_cd * along * abs(along) * normal
                + scene.plate_friction_cd * np.linalg.norm(tangential) * tangential
            )
        )
        np.testing.assert_allclose(total, expected, rtol=1e-9, atol=1e-12)
    # edge-on (wind in the sheet's plane): skin friction only, along the wind
    edge = drag.vertex_forces(qpos, qvel, np.array([2.0, 0.0, 0.0])).sum(axis=0)
    np.testing.assert_allclose(
        edge, [half_rho * area * scene.plate_friction_cd * 4.0, 0.0, 0.0], rtol=1e-9, atol=1e-12
    )


def test_plate_drag_vanishes_on_cloth_moving_with_the_air():
    scene, drag, qpos, qvel = _plate_sheet()
    mujoco = _mujoco()
    model = mujoco.MjModel.from_xml_string(
        independent.scene_mjcf(scene, independent.draw_fabric(0, 0))
    )
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    wind = np.array([0.4, 1.7, -0.2])
    for joint in range(model.njnt):  # every free vertex at the air's velocity
        qvel[model.jnt_dofadr[joint]] = wind @ data.xaxis[joint]
    force = drag.vertex_forces(qpos, qvel, wind)
    moving = np.asarray(model.flex_vertbodyid) > 0
    still = np.zeros(3)
    assert np.abs(force).max() > 0.0  # the triangles at the pins still feel the air
    # far from the three pins every triangle moves with the air: no force
    n = scene.vert_per_side
    lower = np.arange(n * n).reshape(n, n)  # flexcomp grid index (column, row) -> vertex
    far = lower[:, : n - 3].ravel()
    assert moving[far].all()
    np.testing.assert_allclose(force[far], 0.0, atol=1e-12)
    np.testing.assert_allclose(drag.vertex_forces(qpos, np.zeros(model.nv), still), 0.0)


def test_the_gusts_are_smooth_and_keep_their_mean():
    scene = independent.EngineScene()
    times = np.arange(20_000) * scene.max_dt
    wind, drawn = independent.wind_history(scene, 1, np.random.default_rng(0), times)
    speed = np.linalg.norm(wind[times > 1.0], axis=1)
    assert drawn["mean_speed_m_s"] == 1.5 and abs(drawn["fan_yaw_deg"]) <= scene.fan_yaw_deg
    assert speed.mean() == pytest.approx(1.5, rel=0.05)
    assert speed.std() / speed.mean() == pytest.approx(scene.gust_intensity, rel=0.35)
    # smooth: a physics step changes the speed by a few % of its spread (white noise: 141 %)
    assert np.std(np.diff(speed)) < 0.05 * speed.std()
    assert np.all(wind[times == 0] == 0)  # the fan starts at rest


@pytest.mark.render
def test_the_same_seed_gives_the_same_output(footage, tmp_path):
    again = tmp_path / "again"
    done = _command("--out", str(again), "--codec", "png", *SMALL)
    assert done.returncode == 0, done.stderr
    assert _files(again) == _files(footage)
    ours = json.loads((footage.parent / "set.engine.json").read_text())["videos"]
    theirs = json.loads((tmp_path / "again.engine.json").read_text())["videos"]
    assert [v["sha256"] for v in ours] == [v["sha256"] for v in theirs]


@pytest.mark.render
def test_a_video_codec_is_used_and_recorded(renders, tmp_path):
    from datasets.real_video import RealVideoDataset

    out = tmp_path / "videos"
    done = _command(
        "--out",
        str(out),
        "--fabrics",
        "1",
        "--winds",
        "1",
        "--size",
        "32",
        "--frames",
        "10",
        "--no-progress",
    )
    assert done.returncode == 0, done.stderr
    codec = json.loads((tmp_path / "videos.engine.json").read_text())["codec"]
    assert codec["requested"] == "h264" and codec["used"] in ("avc1", "mp4v", "MJPG")
    assert codec["used"] in done.stdout
    if codec["used"] != "avc1":
        assert "not available" in codec["note"]
    dataset = RealVideoDataset(out, size=32)
    assert [(v.name, v.frame_count, v.fps, v.wind) for v in dataset.videos] == [
        ("v000", 10, 15.0, "W2")
    ]
    assert dataset.read_frames(0).shape == (10, 32, 32, 3)


def test_fabrics_zero_is_refused_in_one_line(tmp_path):
    done = _command("--out", str(tmp_path / "set"), "--fabrics", "0")
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [
        "error: --fabrics must be an integer in [1, 1000], got 0"
    ]
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--winds", "4"], "error: --winds must be an integer in [1, 3], got 4"),
        (["--size", "abc"], "error: --size must be an integer in [16, 1024], got 'abc'"),
        (["--fps", "0"], "error: --fps must be a number in [1.0, 240.0], got 0"),
        (["--frames", "5"], "error: --frames must be an integer in [10, 100000], got 5"),
        (["--codec", "gif"], "error: --codec must be one of h264, mjpeg, png; got 'gif'"),
        (
            ["--wind-drag", "ellipsoid"],
            "error: --wind-drag must be one of isotropic, plate; got 'ellipsoid'",
        ),
    ],
)
def test_bad_values_are_refused_in_one_line_before_any_work(args, message, tmp_path, capsys):
    with pytest.raises(SystemExit) as info:
        independent.main(["--out", str(tmp_path / "set"), *args])
    assert info.value.code == 2
    assert capsys.readouterr().err.strip().splitlines() == [message]
    assert list(tmp_path.iterdir()) == []


def test_an_existing_folder_is_refused(tmp_path, capsys):
    (tmp_path / "set").mkdir()
    with pytest.raises(SystemExit):
        independent.main(["--out", str(tmp_path / "set")])
    assert "exists; choose another folder or pass --overwrite" in capsys.readouterr().err
