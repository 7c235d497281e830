"""models.evaluate on real-like footage, as a user runs it: columns, groups, plots, folders."""

import json
import logging
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir

import models.evaluate as evaluate
from common.errors import InputError
from common.grid import ClassGrid
from datasets.manifest import legacy_class_grid
from models.report import wind_label
from models.scores import CORRELATED_SCORES

from .conftest import FABRICS, write_checkpoint

CONFIGS = str(Path(__file__).resolve().parents[2] / "configs")
ROOT = Path(__file__).resolve().parents[2]
FAST = ["real.clip_len=4", "real.clip_stride=4", "real.size=32", "bootstrap.rounds=200"]
COLUMNS = "real.columns=[stiffness,density,bending_rigidity]"


def _cfg(*overrides):
    with initialize_config_dir(config_dir=CONFIGS, version_base="1.3"):
        return compose(config_name="evaluate", overrides=[*FAST, *overrides])


@pytest.fixture
def run_dir(tmp_path):
    """A trained-run folder: checkpoint plus the training's own eval/sim_test.json."""
    run = tmp_path / "logs" / "train" / "tiny-cnn_lstm"
    write_checkpoint(run / "checkpoints" / "best.ckpt")
    (run / "eval").mkdir(parents=True)
    (run / "eval" / "sim_test.json").write_text('{"acc": 0.5, "epochs": 3}\n')
    return run


def test_every_score_meets_every_chosen_column_with_fabric_groups(run_dir, fabric_folder, caplog):
    ckpt = run_dir / "checkpoints" / "best.ckpt"
    with caplog.at_level(logging.WARNING, logger="datasets.real_video"):
        results = evaluate.run(_cfg(f"ckpt_path={ckpt}", f"real_dir={fabric_folder}", COLUMNS))
    assert any("short.mp4" in r.getMessage() for r in caplog.records)
    real, folder = results["real"], Path(results["out_dir"])
    assert folder.parent == run_dir / "eval" and folder.name.startswith("fabrics-")
    assert (real["videos_listed"], real["videos_used"], real["videos_skipped"]) == (19, 18, 1)
    assert real["skipped"] == [{"video": "short.mp4", "frame_count": 2, "frames_needed": 4}]
    assert real["groups"] == FABRICS and real["group_column"] == "fabric"

    grid = real["score_correlations"]
    assert set(grid) == {"all", "W1", "W2", "W3"}
    for name, by_score in grid.items():
        assert set(by_score) == set(CORRELATED_SCORES)
        for by_column in by_score.values():
            assert set(by_column) == {"stiffness", "density", "bending_rigidity"}
            for c in by_column.values():
                # 18 videos but 6 fabrics: the bootstrap and p-values count fabrics
                assert c["count"] == (18 if name == "all" else FABRICS)
                assert c["group_count"] == FABRICS
    # the thesis's figures (material score vs each column) stay where sim2real reads them
    assert (
        real["correlations"]["all"]["bending_rigidity"]
        == grid["all"]["material_score"]["bending_rigidity"]
    )

    for score in CORRELATED_SCORES:
        for column in ("stiffness", "density", "bending_rigidity"):
            png = folder / real["scatter"][score][column]
            assert png.name == f"scatter_{score}_vs_{column}.png"
            assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 2000
    md = (folder / "real.md").read_text()
    assert "19 listed in labels.csv, 18 used" in md and "1 skipped" in md
    assert "| short.mp4 | 2 | 4 |" in md
    assert "6 independent groups, formed by column `fabric`" in md
    row = next(line for line in md.splitlines() if line.startswith("| W2 | bend_score | density"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert cells[3:5] == ["6", "6"]
    interval = r"-?\d\.\d\d \[-?\d\.\d\d, -?\d\.\d\d\]|n/a"
    assert re.fullmatch(interval, cells[5]) and re.fullmatch(interval, cells[7])  # r and rho
    assert re.fullmatch(r"<0\.001|\d\.\d{3}|n/a", cells[6])  # p-values printed
    for png in real["scatter"]["stretch_score"].values():
        assert f"]({png})" in md
    csv_header = (folder / "real_videos.csv").read_text().splitlines()[0]
    assert csv_header.startswith("video,group,wind,clips,stiffness,density,bending_rigidity")
    assert json.loads((folder / "real.json").read_text())["videos_skipped"] == 1


def test_a_model_with_a_density_axis_gets_a_density_score(tmp_path, fabric_folder):
    run = tmp_path / "logs" / "train" / "dense-cnn_lstm"
    grid = ClassGrid((1.0, 2.0), (1.0, 3.0, 9.0), (0.5, 1.0, 2.0))
    ckpt = write_checkpoint(run / "checkpoints" / "best.ckpt", grid=grid)
    results = evaluate.run(_cfg(f"ckpt_path={ckpt}", f"real_dir={fabric_folder}"))
    real, folder = results["real"], Path(results["out_dir"])
    assert real["scores"] == [*CORRELATED_SCORES, "density_score"]
    by_column = real["score_correlations"]["all"]["density_score"]
    assert set(by_column) == {"stiffness", "density"} and by_column["density"]["count"] == 18
    scores = [v["density_score"] for v in real["per_video"]]
    assert all(0.0 <= s <= 2.0 for s in scores) and len(set(scores)) > 1
    assert (folder / real["scatter"]["density_score"]["density"]).is_file()
    assert "`density_score` = expected density index 0..2" in (folder / "real.md").read_text()
    assert "(stretch_index * 3 + bend_index) * 3 + density_index" in real["score_definition"]


def test_each_evaluation_gets_its_own_folder(run_dir, fabric_folder):
    ckpt = run_dir / "checkpoints" / "best.ckpt"
    training_report = (run_dir / "eval" / "sim_test.json").read_bytes()
    first = Path(evaluate.run(_cfg(f"ckpt_path={ckpt}", f"real_dir={fabric_folder}"))["out_dir"])
    first_report = (first / "real.json").read_bytes()
    second = Path(
        evaluate.run(_cfg(f"ckpt_path={ckpt}", f"real_dir={fabric_folder}", COLUMNS))["out_dir"]
    )
    assert second != first and second.parent == first.parent
    assert (first / "real.json").read_bytes() == first_report
    assert (run_dir / "eval" / "sim_test.json").read_bytes() == training_report
    assert json.loads((second / "evaluation.json").read_text())["real"]["columns"] == [
        "stiffness",
        "density",
        "bending_rigidity",
    ]

    # Same inputs, same folder: refused rather than rewritten, unless asked for.
    with pytest.raises(InputError, match=r"already holds the evaluation .* overwrite=true"):
        evaluate.run(_cfg(f"ckpt_path={ckpt}", f"real_dir={fabric_folder}"))
    again = evaluate.run(_cfg(f"ckpt_path={ckpt}", f"real_dir={fabric_folder}", "overwrite=true"))
    assert Path(again["out_dir"]) == first

    # A changed labels.csv is another input, so another folder.
    labels = fabric_folder / "labels.csv"
    labels.write_text(labels.read_text().replace("fabric5,6.0", "fabric5,6.5"))
    third = evaluate.run(_cfg(f"ckpt_path={ckpt}", f"real_dir={fabric_folder}"))["out_dir"]
    assert Path(third) not in (first, second)


def test_class_count_mismatch_is_refused_before_predicting(tmp_path, fabric_folder, monkeypatch):
    ckpt = write_checkpoint(tmp_path / "run10" / "checkpoints" / "best.ckpt", classes=10)

    def must_not_run(*args, **kwargs):
        raise AssertionError("predict ran on a checkpoint of the wrong class count")

    monkeypatch.setattr(evaluate, "predict", must_not_run)
    with pytest.raises(InputError, match=r"predicts 10 classes but .*fabrics has 54") as info:
        evaluate.run(_cfg(f"ckpt_path={ckpt}", f"real_dir={fabric_folder}"))
    assert "\n" not in str(info.value)
    assert not (tmp_path / "run10" / "eval").exists()
    module = evaluate.load_classifier(ckpt)
    with pytest.raises(InputError, match="predicts 10 classes"):
        evaluate.evaluate_real(module, fabric_folder, tmp_path / "out", size=32, clip_len=4)
    assert not (tmp_path / "out").exists()


def test_command_line_user_errors_print_one_line(tmp_path, fabric_folder):
    good = write_checkpoint(tmp_path / "run" / "checkpoints" / "best.ckpt")
    wrong = write_checkpoint(tmp_path / "run10" / "checkpoints" / "best.ckpt", classes=10)
    cases = [
        (wrong, "real.columns=[stiffness]", f"checkpoint {wrong} predicts 10 classes but"),
        (good, "real.columns=[stiffness,bend]", "lacks column(s) ['bend']; it has ['video',"),
    ]
    for ckpt, override, message in cases:
        args = [
            f"ckpt_path={ckpt}",
            f"real_dir={fabric_folder}",
            override,
            f"hydra.run.dir={tmp_path}/hydra",
        ]
        done = subprocess.run(
            [sys.executable, "-m", "models.evaluate", *args],
            capture_output=True,
            text=True,
            timeout=300,
            cwd=ROOT,
        )
        assert done.returncode == 2, done.stderr
        last = done.stderr.strip().splitlines()[-1]
        assert last.startswith("error: ") and message in last, last
        assert "Traceback" not in done.stderr
    with pytest.raises(InputError, match=r"real\.clip_len must be an integer >= 1, got 'zero'"):
        evaluate.run(_cfg(f"ckpt_path={good}", f"real_dir={fabric_folder}", "real.clip_len=zero"))
    with pytest.raises(InputError, match="split must be one of train, val, test; got 'tset'"):
        evaluate.run(_cfg(f"ckpt_path={good}", f"real_dir={fabric_folder}", "split=tset"))


def test_wind_levels_are_reported_as_w1_w2_w3():
    assert [wind_label(level) for level in (0, 1, 2, "2", -1)] == ["W1", "W2", "W3", "W3", "none"]
    assert evaluate._breakdown_label("wind_level", "0") == "wind W1"
    assert evaluate._breakdown_label("clip_index", "1") == "clip index 1"


def test_predict_runs_the_module_through_lightnings_test_loop(tmp_path):
    module = evaluate.load_classifier(write_checkpoint(tmp_path / "run" / "best.ckpt"))
    generator = torch.Generator().manual_seed(0)
    clips = [
        {"video": torch.rand(4, 3, 32, 32, generator=generator), "label": i, "key": f"k{i}"}
        for i in range(5)
    ]
    cpu = torch.device("cpu")
    logits, meta = evaluate.predict(module, clips, batch_size=2, device=cpu, class_count=54)
    with torch.no_grad():
        expected = module.eval()(torch.stack([c["video"] for c in clips]))
    torch.testing.assert_close(logits, expected)
    assert meta == [{"label": i, "key": f"k{i}"} for i in range(5)]
    with pytest.raises(InputError, match="predicts 54 classes but the dataset has 10"):
        evaluate.predict(module, clips, device=cpu, class_count=10)


def test_checkpoints_from_before_the_class_grid_read_as_wang54(tmp_path):
    """No ``num_classes`` in the net config, no ``class_grid``: as train.py used to write them."""
    path = write_checkpoint(tmp_path / "old.ckpt")
    raw = torch.load(path, weights_only=False)
    raw["hyper_parameters"]["net_config"].pop("num_classes")
    assert "class_grid" not in raw["hyper_parameters"]
    torch.save(raw, path)
    module = evaluate.load_classifier(path)
    assert module.net.classifier.out_features == 54
    assert module.hparams["net_config"]["num_classes"] == 54
    assert module.class_grid == ClassGrid.from_json(legacy_class_grid())
    assert evaluate.module_grid(module).num_classes == 54


def test_a_video_replaced_with_the_same_size_and_time_is_another_input(tmp_path, fabric_folder):
    settings = evaluate._settings(_cfg("ckpt_path=x", f"real_dir={fabric_folder}"))
    ckpt = write_checkpoint(tmp_path / "best.ckpt")
    before, _ = evaluate.evaluation_folder(tmp_path, ckpt, None, fabric_folder, settings)
    video = fabric_folder / "videos" / "f0_w1.mp4"
    stat = video.stat()
    data = bytearray(video.read_bytes())
    data[-1] ^= 0xFF
    video.write_bytes(bytes(data))
    os.utime(video, ns=(stat.st_atime_ns, stat.st_mtime_ns))
    after, _ = evaluate.evaluation_folder(tmp_path, ckpt, None, fabric_folder, settings)
    assert after != before
    (fabric_folder / "notes.txt").write_text("not footage")  # not read, so not an input
    assert evaluate.evaluation_folder(tmp_path, ckpt, None, fabric_folder, settings)[0] == after


@pytest.mark.parametrize(
    ("rows", "message"),
    [
        (
            ["f0_w1.mp4,1,0.2", "f1_w1.mp4,1,0.2", "f2_w1.mp4,1,0.2"],
            r"every measured column of .* has one value for all 3 videos \(stiffness = 1, density",
        ),
        (
            ["f0_w1.mp4,1,0.2", "f1_w1.mp4,2,0.3", "short.mp4,3,0.4"],
            r"2 of the 3 videos listed in .* are long enough for a clip; .* at least 3",
        ),
    ],
)
def test_footage_that_cannot_be_correlated_is_refused(
    rows, message, tmp_path, fabric_folder, monkeypatch
):
    def must_not_run(*args, **kwargs):
        raise AssertionError("predict ran on footage that cannot be correlated")

    monkeypatch.setattr(evaluate, "predict", must_not_run)
    (fabric_folder / "labels.csv").write_text("\n".join(["video,stiffness,density", *rows]) + "\n")
    module = evaluate.load_classifier(write_checkpoint(tmp_path / "best.ckpt"))
    with pytest.raises(InputError, match=message):
        evaluate.evaluate_real(module, fabric_folder, tmp_path / "out", size=32, clip_len=4)
