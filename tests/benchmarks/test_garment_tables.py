"""The garment tables (*thesis* Tables 6.1-6.3): the docs' table is the results file's."""

import copy
import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from benchmarks.thesis.garment_tables import (
    DOCS_PAGE,
    TABLE_END,
    TABLE_START,
    main,
    markdown_table,
    print_probe,
    thesis_column,
    wrinkle_probe,
)
from simulator.garment.body import Pose

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "docs" / "results" / "garment_tables.json"


def test_the_docs_table_is_what_the_results_file_gives():
    page = (ROOT / DOCS_PAGE).read_text()
    shown = page.split(TABLE_START, 1)[1].split(TABLE_END, 1)[0].strip()
    assert shown == markdown_table(json.loads(RESULTS.read_text())).strip()


def test_table_says_which_targets_are_missed():
    report = json.loads(RESULTS.read_text())
    text = markdown_table(report)
    row = report["rows"][0]
    garment, m = next(iter(row["garments"].items()))
    assert f"| {row['scene']} | {garment} |" in text
    assert f"{100 * m['material_accuracy']:.1f}" in text
    good = copy.deepcopy(report)
    good.update(sizing_accuracy_min=0.96, material_accuracy_min=0.91)
    good.update(joint_angle_err_max_deg=2.0, minutes_per_garment_max=14.0)
    bad = copy.deepcopy(good)
    bad.update(material_accuracy_min=0.89)
    assert "missed" not in markdown_table(good)
    assert markdown_table(bad).count("**missed**") == 1


def test_thesis_columns_follow_the_tables_scene_order():
    assert thesis_column("a_midday", "tshirt") == 0
    assert thesis_column("c_sunset", "pants") == 5
    assert thesis_column("skirt_high_midday", "skirt") == 2
    assert thesis_column("a_midday", "skirt") is None


def test_table_flag_prints_the_tables(capsys):
    summary = main(["--table", "--out", str(RESULTS)])
    out = capsys.readouterr().out
    assert out.startswith("| scene | garment |") and "| summary" in out
    assert (
        summary["material_accuracy_min"] == json.loads(RESULTS.read_text())["material_accuracy_min"]
    )


def test_a_killed_run_resumes_at_the_scene_it_was_on(tmp_path, monkeypatch):
    import benchmarks.thesis.garment_tables as tables

    report = json.loads(RESULTS.read_text())
    made = []

    def fake_scene(scene, settings, edge_length, log, **_garments_kept):
        made.append(scene.name)
        if scene.name == "a_sunset" and len(made) == 2:
            raise KeyboardInterrupt  # killed on the second scene
        row = copy.deepcopy(report["rows"][0])
        return {**row, "scene": scene.name}

    monkeypatch.setattr(tables, "run_scene", fake_scene)
    monkeypatch.setattr(tables, "use_process_threads", lambda *a, **k: None)  # keep pytest's
    argv = ["--scenes", "a_midday", "a_sunset", "--out", str(tmp_path / "r.json")]
    argv += ["--work", str(tmp_path / "work")]
    try:
        main(argv)
    except KeyboardInterrupt:
        pass
    assert made == ["a_midday", "a_sunset"] and not (tmp_path / "r.json").exists()
    summary = main(argv)
    assert made == ["a_midday", "a_sunset", "a_sunset"]  # a_midday kept
    assert summary["scenes"] == ["a_midday", "a_sunset"]
    written = json.loads((tmp_path / "r.json").read_text())
    assert [r["scene"] for r in written["rows"]] == ["a_midday", "a_sunset"]
    assert len(written["commits"]) == 1
    main([*argv, "--fresh"])
    assert made[3:] == ["a_midday", "a_sunset"]
    main([*argv, "--swarm", "4"])  # other settings: other rows
    assert made[5:] == ["a_midday", "a_sunset"]


def test_a_scene_killed_on_its_second_garment_keeps_the_first(tmp_path, monkeypatch):
    import benchmarks.thesis.garment_tables as tables

    template = json.loads(RESULTS.read_text())["rows"][0]
    scene, garments = template["scene"], list(template["garments"])
    occluded = template["occluded"]
    recovered, kill = [], [True]

    def set_up(scene_spec, settings, edge_length, log):
        fit = SimpleNamespace(
            pose=Pose(), shape=SimpleNamespace(height=1.7), offset=np.zeros(3), loss=0.1
        )
        draped = dict.fromkeys(garments)
        return tables.SceneSetup(
            scene_spec, None, None, draped, None, None, None, [], Pose(), occluded, fit, 0.0, 0.0
        )

    def recover(setup, k, settings, log):
        g = setup.garments[k]
        recovered.append(g)
        if k == 1 and kill[0]:
            kill[0] = False
            raise KeyboardInterrupt  # killed on the second garment
        angles = np.zeros((15, 3))
        angles[:, k] = 5.0 * (k + 1)  # each garment's pose decides its own joints
        return copy.deepcopy(template["garments"][g]), Pose(angles)

    monkeypatch.setattr(tables, "set_up_scene", set_up)
    monkeypatch.setattr(tables, "recover_one", recover)
    monkeypatch.setattr(tables, "use_process_threads", lambda *a, **k: None)  # keep pytest's
    argv = ["--scenes", scene, "--out", str(tmp_path / "r.json"), "--work", str(tmp_path / "w")]
    with pytest.raises(KeyboardInterrupt):
        main(argv)
    (folder,) = (tmp_path / "w").iterdir()
    assert [p.name for p in folder.iterdir()] == [f"{scene}.{garments[0]}.json"]
    main(argv)
    assert recovered == [garments[0], garments[1], garments[1]]  # the first one kept
    assert [p.name for p in folder.iterdir()] == [f"{scene}.json"]  # its partial removed
    resumed = json.loads((folder / f"{scene}.json").read_text())
    assert resumed["garments"] == template["garments"]
    main([*argv, "--fresh"])  # uninterrupted: every garment recovered, the same row
    assert recovered[3:] == garments
    fresh = json.loads((folder / f"{scene}.json").read_text())
    assert fresh["joint_err_deg"] == resumed["joint_err_deg"]
    assert len(set(fresh["joint_err_deg"].values())) > 1  # both garments' poses took part
    fit_only = fresh["joint_err_deg_body_fit"]  # the fit's pose is the truth's here
    assert fit_only.keys() == fresh["joint_err_deg"].keys()
    assert max(fit_only.values()) < 1e-6
    summary = tables.summarise([fresh])
    assert summary["joint_angle_err_max_deg_body_fit"] < 1e-6 < summary["joint_angle_err_max_deg"]
    assert tables.summarise([template])["joint_angle_err_max_deg_body_fit"] is None  # older rows


def test_the_wrinkle_probe_reads_every_region_of_a_layered_garment():
    rows = wrinkle_probe(0.12, "tshirt", bends=(1.0, 100.0))
    assert [r["bend"] for r in rows] == [1.0, 100.0]
    for row in rows:
        assert set(row) == {
            "bend",
            "converged",
            "max_speed",
            "curvature",
            "density_midday",
            "density_sunset",
        }
        for key in ("curvature", "density_midday", "density_sunset"):
            assert list(row[key]) == ["body", "sleeves"]
            assert all(np.isfinite(v) and v >= 0 for v in row[key].values())
    # A stiffer fabric folds less: the sleeves' curvature falls from x1 to x100.
    assert rows[1]["curvature"]["sleeves"] < rows[0]["curvature"]["sleeves"]
    print_probe(rows)


def test_the_probe_names_the_garments_it_knows(capsys):
    with pytest.raises(SystemExit):
        main(["--probe", "hat"])
    assert "invalid choice: 'hat'" in capsys.readouterr().err


def test_a_finer_material_mesh_drapes_the_scenes_finer_in_rows_of_their_own(tmp_path, monkeypatch):
    import benchmarks.thesis.garment_tables as tables

    report = json.loads(RESULTS.read_text())
    made = []

    def fake_scene(scene, settings, edge_length, log, **_garments_kept):
        made.append((settings.edge_length, settings.material_edge_length, edge_length))
        return {**copy.deepcopy(report["rows"][0]), "scene": scene.name}

    monkeypatch.setattr(tables, "run_scene", fake_scene)
    monkeypatch.setattr(tables, "use_process_threads", lambda *a, **k: None)
    argv = ["--scenes", "a_midday", "--out", str(tmp_path / "r.json")]
    argv += ["--work", str(tmp_path / "work")]
    main(argv)
    main([*argv, "--material-edge-length", "0.025"])
    assert made == [(0.05, None, 0.05), (0.05, 0.025, 0.025)]
    assert len(list((tmp_path / "work").iterdir())) == 2


def test_the_start_probe_reads_a_particle_per_start_and_bend(capsys):
    from benchmarks.thesis.garment_tables import print_start_probe, start_probe

    probe = start_probe(0.12, "tshirt", bends=(2.0, 32.0))
    assert probe["regions"] == ["body", "sleeves"]
    assert np.asarray(probe["settled"]).shape == (2, 2)
    particles = np.asarray(probe["particles"])
    assert particles.shape == (2, 2, 2) and np.isfinite(particles).all()
    assert (particles >= 0).all()
    print_start_probe(probe)
    assert "particle from x32" in capsys.readouterr().out
