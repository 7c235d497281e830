"""End to end on tiny data: seal a set with a planted effect, diagnose it, check the answer.

The trained run is a randomly initialised CNN+LSTM saved as a checkpoint (the diagnosis only
reads its layers); the training data is a tiny wind spec (32 x 32 frames, mesh level 1).
"""

import csv
import dataclasses
import hashlib
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from hydra.utils import instantiate

from datasets.manifest import write_json
from datasets.spec import DatasetSpec, SizePreset
from models.material_classifier import MaterialClassifierModule
from render.camera import CameraSpec
from sim2real.candidates import candidate_library
from sim2real.diagnosis import CandidateResult, rank_candidates
from sim2real.pipeline import Budget, DiagnosisRequest, run_diagnosis
from sim2real.result import Diagnosis
from sim2real.study.rescore import decide_again
from sim2real.study.seal import draw_answer, seal_set
from simulator.cloth.rollout import SimSettings
from simulator.cloth.scenes import ScenarioWind
from tests.sim2real.reports import as_diagnosis, ranking_of

NET = {
    "_target_": "models.components.video_nets.CNNLSTMNet",
    "encoder": {
        "_target_": "models.components.frame_encoder.FrameEncoder",
        "name": "alexnet5",
        "feature_dim": 32,
        "width": 0.25,
    },
    "hidden_size": 16,
}
BUDGET = Budget(
    name="test",
    class_grid=None,
    sims_per_class=2,
    clips_per_sim=2,
    strengths=3,
    n_perm=99,
    n_boot=99,
    n_floor=5,
)
CANDIDATES = ["visual.sensor_noise", "visual.defocus_blur", "visual.white_balance"]


def _spec() -> DatasetSpec:
    return DatasetSpec(
        motion="wind",
        scenario=ScenarioWind(resolution_level=1, settle_time=0.2),
        preset=SizePreset(
            "tiny",
            sims_per_class=3,
            clips_per_sim=1,
            val_sims_per_class=1,
            test_sims_per_class=1,
            frames_per_clip=4,
        ),
        classes=(0, 20, 33, 53),
        lead_in=0.2,
        sim=SimSettings(dtype="float32", max_dt=0.00834, settle_max_dt=0.0167),
        camera=CameraSpec.wind(32, 32),
        texture_size=64,
    )


def _checkpoint(path, net_config, classes=54):
    config = {**net_config, "num_classes": classes}
    torch.manual_seed(0)
    module = MaterialClassifierModule(instantiate(config), net_config=config)
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.save(
        {"hyper_parameters": {"net_config": config}, "state_dict": module.state_dict()}, path
    )


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    """Training-data spec, a run with a checkpoint, and a sealed set with sensor noise."""
    root = tmp_path_factory.mktemp("sim2real")
    spec = _spec()
    write_json(root / "data" / "spec.json", {"key": spec.key(), "spec": spec.to_json()})
    _checkpoint(root / "run" / "checkpoints" / "best.ckpt", NET)
    answer = {
        "seed": 1,
        "kind": "single",
        "effects": [
            {"name": "visual.sensor_noise", "stage": "camera", "strength": 6.0, "library": True}
        ],
    }
    answer_path, digest = seal_set(
        root / "real", base=spec, seed=1, videos=8, clips_per_video=2, clip_len=4, answer=answer
    )
    return {"root": root, "answer": answer_path, "digest": digest}


def _diagnose(world, out, candidates=CANDIDATES, **changes):
    root = world["root"]
    kwargs = {
        "real_dir": root / "real",
        "run": root / "run",
        "data_dir": root / "data",
        "cache_dir": root / "cache",
        "mesh_cache": root / "meshes",
        "budget": BUDGET,
        "candidates": candidates,
        "clip_len": 4,
        "clip_stride": 4,
        "progress": False,
    }
    kwargs.update(changes)
    return run_diagnosis(DiagnosisRequest(**kwargs), out)


def test_sealed_set_holds_only_what_real_footage_has(world):
    root = world["root"]
    real = root / "real"
    entries = sorted(p.name for p in real.iterdir())
    assert entries == ["labels.csv", *[f"v{i:03d}" for i in range(8)]]
    with open(real / "labels.csv") as handle:
        rows = list(csv.DictReader(handle))
    assert list(rows[0]) == ["video", "stiffness", "density", "wind", "fps"]
    assert all(float(r["stiffness"]) > 0 and float(r["density"]) > 0 for r in rows)
    assert not (real / "answer.json").exists()
    text = world["answer"].read_text()
    assert hashlib.sha256(text.encode()).hexdigest() == world["digest"]
    assert json.loads(text)["effects"][0]["name"] == "visual.sensor_noise"
    frames = sorted((real / "v000").iterdir())
    assert len(frames) == 8 and frames[0].suffix == ".png"


def test_a_slower_sealed_camera_films_as_many_frames_over_a_longer_time(world, tmp_path):
    answer = {
        "seed": 2,
        "kind": "single",
        "effects": [
            {"name": "visual.frame_rate", "stage": "camera", "strength": 0.5, "library": True}
        ],
    }
    seal_set(
        tmp_path / "slow",
        base=_spec(),
        seed=2,
        videos=4,
        clips_per_video=2,
        clip_len=4,
        answer=answer,
    )
    for video in sorted((tmp_path / "slow").glob("v*")):
        assert len(list(video.iterdir())) == 8  # 15 recorded frames at half the frame rate


def test_the_fitted_strengths_of_the_top_candidates_are_added_to_be_measured():
    from types import SimpleNamespace

    from sim2real.pipeline import REFINE_TOP, _check_fits

    library = candidate_library(_spec())
    names = [
        "visual.sensor_noise",
        "visual.compression",
        "physics.air_damping",
        "visual.shadows",
        *sorted(library)[: REFINE_TOP + 1],
    ]
    plan = [(library[n], library[n].strengths(3)) for n in dict.fromkeys(names)]
    fitted = {"visual.sensor_noise": 3.016, "visual.compression": 27.4, "physics.air_damping": 0.07}
    results = [
        SimpleNamespace(best_score=1.0 - 0.1 * i, fitted=fitted.get(c.name))
        for i, (c, _) in enumerate(plan)
    ]
    after = _check_fits(plan, results, "all")
    checked = {c.name: v for c, v in after}
    assert 3.016 in checked["visual.sensor_noise"]
    assert 27 in checked["visual.compression"]  # an integer strength (JPEG quality)
    assert 0.07 in checked["physics.air_damping"]
    assert checked["visual.shadows"] == plan[3][1]  # a switch: nothing to fit
    visual = {c.name: v for c, v in _check_fits(plan, results, "visual")}
    assert 0.07 not in visual["physics.air_damping"]  # would need a simulation
    assert _check_fits(plan, results, "none") == plan
    assert after[REFINE_TOP:] == plan[REFINE_TOP:]  # only the top candidates


def test_drawn_answers_cover_single_pair_and_open_kinds():
    library = candidate_library(_spec())
    kinds = {draw_answer(seed, library)["kind"] for seed in range(40)}
    assert kinds == {"single", "pair", "open"}
    pair = draw_answer(3, library, "pair")
    assert len(pair["effects"]) == 2 and all(e["library"] for e in pair["effects"])
    for effect in pair["effects"]:
        candidate = library[effect["name"]]
        if not candidate.binary:
            candidate.check_strength(effect["strength"])
    assert draw_answer(5, library) == draw_answer(5, library)


def test_a_coalition_explains_the_gap_only_when_its_kernel_closure_agrees_and_all_add():
    from sim2real.pipeline import explained_together

    ranking = ranking_of(explained=False, top="a", threshold=0.5, look_alike=True)
    alone = {"a": 0.3, "b": 0.2, "c": 0.2}
    shapley = {
        "coalitions": {"a+b": 0.8, "a+c": 0.7, "b+c": 0.9, "a+b+c": 0.95},
        "kernel_closure": {"a+b": 0.1, "a+c": 0.6, "b+c": 1.0, "a+b+c": 0.9},
    }
    out = explained_together(ranking, shapley, alone)
    # a+b closes more of the classifier gap but not of the kernel distance; b+c lacks the
    # top; a+b+c passes both, but without a it closes 0.9 of the 0.95: a adds, so it wins
    assert out.explained and out.explained_by == ["a", "b", "c"] and not out.look_alike
    assert out.explained_by_kernel_closure == 0.9
    shapley["coalitions"]["a+b+c"] = 0.85  # now a lowers b+c's 0.9: a rides along
    out = explained_together(ranking, shapley, alone)
    assert out.explained_by == ["a", "c"] and out.explained_by_kernel_closure == 0.6
    shapley["kernel_closure"]["a+c"] = 0.4
    assert explained_together(ranking, shapley, alone) == ranking
    shapley["kernel_closure"]["a+c"] = None  # no rung above its MMD² floor: too weak
    assert explained_together(ranking, shapley, alone) == ranking
    shapley["kernel_closure"]["a+c"] = 0.6
    shapley["coalitions"]["a+c"] = 0.6  # above the threshold, but not by the margin
    assert explained_together(ranking, shapley, alone) == ranking
    shapley["coalitions"]["a+c"] = 0.9  # passes again, unless a cannot be told from its absence
    assert explained_together(ranking, shapley, alone).explained_by == ["a", "c"]
    indistinct = dataclasses.replace(ranking, neutral_in_interval=True)
    assert explained_together(indistinct, shapley, alone) == indistinct


def test_planted_effect_is_ranked_first_and_the_report_is_written(world, tmp_path):
    out = tmp_path / "report"
    result = _diagnose(world, out)
    assert result.ranking.top == "visual.sensor_noise"
    assert result.ranking.explained
    assert "pixel" in result.location.significant
    # the report names the model that answered by its bytes, so a round's rows can be checked
    checkpoint = Path(result.inputs.checkpoint).read_bytes()
    assert result.inputs.checkpoint_digest == hashlib.sha256(checkpoint).hexdigest()[:16]
    assert json.loads((out / "report.json").read_text())["inputs"]["checkpoint_digest"] == (
        result.inputs.checkpoint_digest
    )
    noise = result.candidates["visual.sensor_noise"]
    assert noise["best_strength"] >= 2.0
    assert len(noise["strengths"]) > 3  # the grid was refined around the best strength
    for name in (
        "report.html",
        "report.md",
        "report.json",
        "rungs.png",
        "candidates.png",
        "clips.png",
    ):
        assert (out / name).stat().st_size > 0, name
    shapley = result.shapley
    assert shapley is not None and "visual.sensor_noise" in shapley["players"]
    grand = "+".join(sorted(shapley["players"]))
    assert sum(shapley["values"].values()) == pytest.approx(shapley["closure"][grand])
    assert shapley["closure"][grand] >= shapley["coalitions"][grand]
    assert shapley["closure"][grand] >= noise["best_score"]
    assert set(shapley["kernel_closure"]) == set(shapley["coalitions"])
    assert result.ranking.kernel_closure == noise["kernel_closure"] >= 0.5
    assert not result.ranking.look_alike
    joint = result.joint  # every candidate that closes some of the gap, calibrated together
    if joint is not None:
        assert joint.strengths.get("visual.sensor_noise") in noise["strengths"]
        assert sum(joint.shapley.values()) == pytest.approx(joint.closure, abs=1e-9)
        assert joint.closure >= noise["best_score"] - 0.05
        assert "Every factor calibrated together" in (out / "report.md").read_text()
        assert (out / "shares.png").stat().st_size > 0
    residual = result.residual  # the gap tests between R and the top's best set
    assert residual["candidate"] == "visual.sensor_noise"
    assert residual["strength"] in noise["strengths"]
    assert set(residual["p_gap"]) == set(result.rungs) and 0 < residual["gap_p"] <= 1
    # the gap test compared R with S and S' pooled; candidates are scored against S alone
    pooled, alone = result.detection_rungs["pixel"], result.rungs["pixel"]
    assert pooled["n_x"] == 2 * alone["n_x"] and pooled["groups_x"] == 2 * alone["groups_x"]
    assert result.location.gap_p < 0.05
    seen = result.detectability  # every built strength tested against S'
    assert set(seen) == set(CANDIDATES)
    assert seen["visual.sensor_noise"]["strengths"] == noise["strengths"]
    assert seen["visual.sensor_noise"]["detected"][-1]  # the strongest noise shows, sim vs sim
    assert "What the gap test can see" in (out / "report.md").read_text()
    saved = Diagnosis.from_json(json.loads((out / "report.json").read_text()))
    assert saved.ranking.top == "visual.sensor_noise"
    again = decide_again(saved)  # the stored closures, decided again by the same rules
    assert again.replayed and dataclasses.replace(again, replayed=None) == saved.ranking
    lines = (out / "report.md").read_text().split("\n")
    assert "visual.sensor_noise" in lines[2]  # the answer leads
    assert "To close it" in lines[2]
    assert "With visual.sensor_noise added at" in lines[lines.index("## Evidence") + 2]
    page = (out / "report.html").read_text()  # real tables, not Markdown source
    assert "<table>" in page and "|---|" not in page and 'class="answer"' in page

    # counterfactual (b): the sealed set's sensor noise is measured and emulated on S
    camera = result.counterfactuals["camera"]
    noise_match = camera["matched"]["visual.sensor_noise"]
    assert noise_match["present"] and "noise" in noise_match["statistic"]
    assert camera["rungs"]["pixel"]["closure"] > 0.5
    # counterfactual (c): AdaBN on R for every layer of the net (it has batch norm)
    norm = result.counterfactuals["batchnorm"]
    assert norm["available"] and "enc.block1" in norm["layers"]
    assert "material_score~stiffness" in norm["correlations"]["after"]
    report = (out / "report.md").read_text()
    assert "Counterfactual stage swaps" in report and "AdaBN" in report

    # one more candidate: only its sets are built, everything else comes from the cache (the
    # camera swap already built the camera effects at the budget's strengths)
    again = _diagnose(
        world,
        tmp_path / "again",
        candidates=[*CANDIDATES, "visual.compression"],
        budget=dataclasses.replace(BUDGET, joint_top=0),
    )  # no new combinations
    library = candidate_library(_spec())
    grid = set(library["visual.compression"].strengths(BUDGET.strengths))
    new_sets = len(set(again.candidates["visual.compression"]["strengths"]) - grid)
    new_sets += len(set(again.shapley["coalitions"]) - set(result.shapley["coalitions"]))
    assert again.sets["built"] == new_sets
    assert again.sets["cached"] == again.sets["total"] - 1 - new_sets
    assert again.ranking.top == "visual.sensor_noise"


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"candidates": ["visual.rain"]}, r"candidates: unknown \['visual.rain'\]"),
        ({"strengths": {"visual.sensor_noise": [99.0]}}, r"noise_read_sigma.*\[0.5, 8.0\]"),
        ({"data_dir": None}, r"\.hydra/config\.yaml"),
        ({"n_jobs": 0}, "n_jobs must be an integer >= 1"),
    ],
)
def test_bad_arguments_fail_with_one_clear_message_and_write_nothing(
    world, tmp_path, change, message
):
    with pytest.raises((ValueError, FileNotFoundError), match=message):
        _diagnose(world, tmp_path / "out", **change)
    assert not (tmp_path / "out").exists()


HEADER = ("video", "stiffness", "density", "fps")


def _real_folder(path, rows, frames=8):
    path.mkdir()
    header = rows[0]
    for row in rows[1:]:
        folder = path / row[0]
        folder.mkdir()
        import cv2

        for t in range(frames):
            image = np.random.default_rng(t).integers(0, 255, (32, 32, 3), dtype=np.uint8)
            cv2.imwrite(str(folder / f"f{t:03d}.png"), image)
    (path / "labels.csv").write_text("\n".join(",".join(r) for r in [header, *rows[1:]]) + "\n")
    return path


@pytest.mark.parametrize(
    ("rows", "message"),
    [
        ([("video", "stiffness")], r"lacks column\(s\) \['density'\]"),
        ([("video", "stiffness", "density")], "lists no videos"),
        ([("video", "stiffness", "density"), ("a", "soft", "0.3")], "must be a number"),
        (
            [HEADER, *[(f"v{i}", "1", "-0.3", "15") for i in range(4)]],
            r"column 'density' must be > 0",
        ),
        ([HEADER, ("v0", "1", "0.3", "15"), ("v1", "2", "0.3", "15")], "at least 4"),
    ],
)
def test_bad_real_folders_fail_with_one_clear_message(world, tmp_path, rows, message):
    real = _real_folder(tmp_path / "real", rows)
    with pytest.raises(ValueError, match=message):
        _diagnose(world, tmp_path / "out", real_dir=real)
    assert not (tmp_path / "out").exists()


def test_unreadable_video_and_wrong_class_count_are_refused(world, tmp_path):
    real = tmp_path / "real"
    real.mkdir()
    (real / "clip.mp4").write_bytes(b"not a video")
    (real / "labels.csv").write_text("video,stiffness,density\nclip.mp4,1,0.3\n")
    with pytest.raises(ValueError, match="cannot open video"):
        _diagnose(world, tmp_path / "out", real_dir=real)
    run = tmp_path / "run10"
    _checkpoint(run / "checkpoints" / "best.ckpt", NET, classes=10)
    with pytest.raises(ValueError, match=r"has 10 output classes; .* wang54 has 54 \(the 6 x 9"):
        _diagnose(world, tmp_path / "out", run=run)
    assert not (tmp_path / "out").exists()


def test_command_lines_compose_and_fail_with_one_line(tmp_path):
    import subprocess
    import sys

    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "sim2real.diagnose",
            f"real_dir={tmp_path}/none",
            f"run={tmp_path}/none",
            f"hydra.run.dir={tmp_path}/hydra",
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 2
    assert done.stderr.strip().splitlines()[-1].startswith("error: run: ")
    for module in ("sim2real.study.seal", "sim2real.study.validate"):
        done = subprocess.run(
            [sys.executable, "-m", module, "--help"], capture_output=True, text=True, timeout=300
        )
        assert done.returncode == 0 and "usage:" in done.stdout


def test_shrink_retrains_with_the_effect_and_reports_before_and_after(world, tmp_path):
    """A tiny trained run (config saved like Hydra does), diagnosed, then shrunk."""
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    import models.training as train_entry
    from datasets.generation import generate_dataset
    from sim2real.shrink import shrink

    root = world["root"]
    data = tmp_path / "train-data"
    spec = _spec()
    generate_dataset(spec, data, mesh_cache=root / "meshes", progress=False)
    run = tmp_path / "logs" / "train" / "tiny"
    configs = str(Path(__file__).resolve().parents[2] / "configs")
    with initialize_config_dir(config_dir=configs, version_base="1.3"):
        cfg = compose(
            config_name="train",
            overrides=[
                f"dataset.dir={data}",
                f"paths.output_dir={run}",
                f"paths.log_dir={run.parent}",
                f"paths.work_dir={run}",
                "encoder.width=0.25",
                "encoder.feature_dim=16",
                "data.batch_size=2",
                "data.num_workers=0",
                "trainer.max_epochs=1",
                "~logger",
                "callbacks.progress_bar=null",
                "callbacks.lr_monitor=null",
                "test=false",
                "trainer.log_every_n_steps=1",
            ],
        )
    (run / ".hydra").mkdir(parents=True)
    OmegaConf.save(cfg, run / ".hydra" / "config.yaml")
    train_entry.train(cfg)
    out = tmp_path / "report"
    result = _diagnose(world, out, candidates=["visual.sensor_noise"], run=run, data_dir=None)
    assert result.ranking.top == "visual.sensor_noise"
    section = shrink(out, epochs=2, preset="same", n_jobs=1, control=True)
    assert section["effects"][0]["name"] == "visual.sensor_noise"
    # the control fine-tunes as long on the run's own (nominal) training data
    assert Path(section["control"]["data"]) == data
    assert Path(section["control"]["checkpoint"]).is_file()
    for label in ("before", "after", "control"):
        for target in ("stiffness", "density"):
            entry = section["correlations"][label][target]
            assert entry["count"] == 8
        every = section["score_correlations"][label]  # every score, pooled and per wind
        assert set(every) >= {"all"} and len(every) > 1
        assert set(every["all"]) == {"material_score", "stretch_score", "bend_score"}
        assert (
            every["all"]["material_score"]["stiffness"]
            == section["correlations"][label]["stiffness"]
        )
    assert set(section["rungs"]) == set(result.rungs)
    noise = result.candidates["visual.sensor_noise"]
    predicted = {**noise["closure"], **noise["closure_auc"]}  # the classifier's where scored
    assert section["rungs"]["pixel"]["closure_predicted"] == predicted["pixel"][noise["best"]]
    # predictivity over the run's best and last checkpoints and both fine-tuned epochs
    srcc = section["predictivity"]
    assert [Path(r["checkpoint"]).name for r in srcc["rows"]] == [
        "best.ckpt",
        "last.ckpt",
        "epoch00.ckpt",
        "epoch01.ckpt",
    ]
    assert all(-1 <= r[k] <= 1 for r in srcc["rows"] for k in ("sim", "sim_effect", "real"))
    assert srcc["before"]["checkpoints"] == srcc["after"]["checkpoints"] == 4
    text = (out / "report.md").read_text()
    assert "## 3. How far it shrinks" in text and "fine-tuned for 2 epochs" in text
    assert section["lr_scale"] == 0.1 and "at 0.1 of its training rate" in text
    assert "| pooled | bend_score | stiffness |" in text  # every score against every column
    assert "nominal control" in text and "after − nominal" in text
    assert "SRCC" in text
    assert json.loads((out / "report.json").read_text())["shrink"]["epochs"] == 2

    # a density axis for the model after: the run's cells at two densities, trained afresh
    dense = dataclasses.replace(spec.material_set, name="dense", density_multipliers=(0.5, 1.0))
    with pytest.raises(ValueError, match="give init=scratch"):
        shrink(out, epochs=1, preset="same", n_jobs=1, material_set=dense)
    again = tmp_path / "report-dense"  # a report's shrink folder holds one retrain
    shutil.copytree(out, again, ignore=shutil.ignore_patterns("shrink"))
    section = shrink(again, epochs=1, preset="same", n_jobs=1, init="scratch", material_set=dense)
    assert section["material_set"] == "dense" and section["classes_after"].startswith("108 (")
    from models.material_classifier import load_classifier

    assert load_classifier(section["checkpoint_after"]).class_grid == dense.grid
    every = section["score_correlations"]
    assert "density_score" in every["after"]["all"]
    assert "density_score" not in every["before"]["all"]
    assert "| pooled | density_score | density | – | – |" in (again / "report.md").read_text()


def _merged(out: Path, report: dict, answer: Path) -> None:
    """A merged validation folder holding set 1's finished report and its answer."""
    (out / "reports" / "set1").mkdir(parents=True)
    (out / "reports" / "set1" / "report.json").write_text(
        json.dumps(as_diagnosis(report).to_json())
    )
    (out / "answers").mkdir()
    (out / "answers" / "set1.json").write_text(answer.read_text())


def test_finished_only_scores_the_finished_sets_and_seals_nothing(world, tmp_path, capsys):
    from sim2real.study.validate import main as validate

    root, out = world["root"], tmp_path / "merged"
    report = {
        "ranking": {
            "ranking": ["visual.sensor_noise", "visual.defocus_blur"],
            "top": "visual.sensor_noise",
            "explained": True,
        },
        "candidates": {
            "visual.sensor_noise": {
                "stage": "camera",
                "best_score": 0.9,
                "strength_interval": [4.0, 8.0],
            }
        },
        "scored_rungs": ["pixel"],
        "residual_stage": "",
        "inputs": {"budget": "quick"},
        "timing": {"total": 600.0},
    }
    _merged(out, report, world["answer"])
    args = [
        "--kinds",
        "single:2",
        "--first-seed",
        "1",
        "--sets",
        "0",
        "--finished-only",
        "--run",
        str(root / "run"),
        "--data-dir",
        str(root / "data"),
        "--out",
        str(out),
    ]
    validate(args)
    rows = json.loads((out / "validation.json").read_text())["sets"]
    assert [r["seed"] for r in rows] == [1] and rows[0]["top1"] and rows[0]["stage_correct"]
    assert rows[0]["strength_in_interval"]
    assert rows[0]["minutes"] == 10.0  # the diagnosis's own time, not the time to reload it
    assert not (out / "sets").exists()  # set 2 was neither sealed nor diagnosed
    assert (out / "validation.md").is_file() and (out / "confusion.png").is_file()
    assert (out / "validation.md").read_text().startswith("Diagnosed at budget quick")
    capsys.readouterr()
    with pytest.raises(SystemExit) as stop:
        validate([*args, "--budget", "tiny"])
    assert stop.value.code == 2
    assert "--budget must be one of full, quick" in capsys.readouterr().err
    with pytest.raises(SystemExit) as stop:
        validate([*args[:-1], str(tmp_path / "empty")])
    assert stop.value.code == 2
    assert "no finished sealed set" in capsys.readouterr().err
    # a plan carried over machines: set 2 was scored elsewhere, set 1's row there is stale
    other = {**rows[0], "seed": 2, "top1": False, "predicted": "unexplained"}
    earlier = tmp_path / "elsewhere.json"
    earlier.write_text(json.dumps({"sets": [other, {**rows[0], "top1": False}]}))
    validate([*args, "--scored", str(earlier)])
    merged = json.loads((out / "validation.json").read_text())
    assert [r["seed"] for r in merged["sets"]] == [1, 2]
    assert merged["sets"][0]["top1"] and not merged["sets"][1]["top1"]  # here wins for set 1
    assert merged["summary"]["top1"] == 0.5 and not (out / "sets").exists()
    earlier.write_text(json.dumps({"sets": [{**other, "kind": "open"}]}))
    capsys.readouterr()
    with pytest.raises(SystemExit) as stop:
        validate([*args, "--scored", str(earlier)])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("error: --scored") and "kind 'open'" in err and "'single'" in err


def test_a_shard_reads_the_reruns_of_its_stability_position(world, tmp_path):
    from sim2real.study.validate import main as validate

    root, out = world["root"], tmp_path / "merged"
    report = {
        "ranking": {
            "ranking": ["visual.sensor_noise", "visual.defocus_blur", "visual.shadows"],
            "top": "visual.sensor_noise",
            "explained": True,
        },
        "candidates": {
            n: {"stage": "camera", "best_score": s, "strength_interval": [4.0, 8.0]}
            for n, s in (
                ("visual.sensor_noise", 0.9),
                ("visual.defocus_blur", 0.2),
                ("visual.shadows", 0.1),
            )
        },
        "scored_rungs": ["pixel"],
        "residual_stage": "",
        "inputs": {"budget": "quick"},
    }
    _merged(out, report, world["answer"])
    swapped = {
        **report,
        "ranking": {
            **report["ranking"],
            "ranking": ["visual.sensor_noise", "visual.shadows", "visual.defocus_blur"],
        },
    }
    for sim_seed, stored in ((1, report), (2, swapped)):
        (out / "reports" / f"set1-sim{sim_seed}").mkdir()
        (out / "reports" / f"set1-sim{sim_seed}" / "report.json").write_text(
            json.dumps(as_diagnosis(stored).to_json())
        )
    # plan single:3 from seed 0: --stability 2 reruns positions 0 and 2 (seeds 0 and 2), not
    # seed 1, so the finished set 1 is scored without a tau
    args = [
        "--kinds",
        "single:3",
        "--first-seed",
        "0",
        "--finished-only",
        "--run",
        str(root / "run"),
        "--data-dir",
        str(root / "data"),
        "--out",
        str(out),
    ]
    validate([*args, "--sets", "0", "--stability", "2"])
    (row,) = json.loads((out / "validation.json").read_text())["sets"]
    assert "kendall_tau" not in row
    # --stability 3 takes every position; a shard of position 1 alone (--skip 1) reads its reruns
    validate([*args, "--skip", "1", "--sets", "1", "--stability", "3"])
    data = json.loads((out / "validation.json").read_text())
    assert data["sets"][0]["kendall_tau"] == pytest.approx((1 + 1 / 3 + 1 / 3) / 3)
    assert "ranking stability on single sets (Kendall tau)" in (out / "validation.md").read_text()


def test_rescore_decides_stored_sets_again_beside_the_blind_table(world, tmp_path, capsys):
    from sim2real.study.validate import main as validate

    root, out = world["root"], tmp_path / "merged"
    fit = CandidateResult(
        "visual.sensor_noise",
        "camera",
        (2.0, 6.0),
        {"pixel": [0.1, 0.0]},
        {"pixel": [0.4, 0.9]},
        [0.4, 0.9],
    )
    null = CandidateResult("S'", "null", (None,), {"pixel": [0.1]}, {"pixel": [0.0]}, [0.0])
    report = {
        "candidates": {fit.name: {**fit.to_json(), "best": fit.best}},
        "null": null.to_json(),
        "ranking": rank_candidates([fit], null, ["pixel"]).to_json(),
        "shapley": None,
        "stacked": None,
        "scored_rungs": ["pixel"],
        "residual_stage": "physics (stored by an older rule)",
        "location": {"significant": ["pixel"], "first_significant_layer": None},
    }
    _merged(out, report, world["answer"])
    args = [
        "--kinds",
        "single:1",
        "--first-seed",
        "1",
        "--sets",
        "0",
        "--rescore",
        "--run",
        str(root / "run"),
        "--data-dir",
        str(root / "data"),
        "--out",
        str(out),
    ]
    validate(args)
    rows = json.loads((out / "rescored.json").read_text())["sets"]
    assert rows[0]["top1"] and rows[0]["replayed"]
    validate([*args, "--open-set-threshold", "0.95"])
    saved = json.loads((out / "rescored.json").read_text())
    assert saved["summary"]["open_set_threshold"] == 0.95
    assert saved["sets"][0]["predicted"] == "unexplained" and not saved["sets"][0]["top1"]
    assert saved["sets"][0]["stage_correct"]  # the residual stage is decided again: camera
    assert "open-set threshold 0.95" in (out / "rescored.md").read_text()
    assert (out / "confusion_rescored.png").is_file()
    assert not (out / "validation.md").exists() and not (out / "sets").exists()
    capsys.readouterr()
    with pytest.raises(SystemExit) as stop:
        validate([*args, "--open-set-threshold", "1.5"])
    assert stop.value.code == 2
    assert "--open-set-threshold must be in (0, 1]" in capsys.readouterr().err
    with pytest.raises(SystemExit) as stop:
        validate([*args, "--scored", str(out / "rescored.json")])
    assert stop.value.code == 2
    assert "--scored rows cannot be decided again" in capsys.readouterr().err
    blind = [a for a in args if a != "--rescore"]
    with pytest.raises(SystemExit) as stop:
        validate([*blind, "--finished-only", "--open-set-threshold", "0.5"])
    assert stop.value.code == 2
    assert "applies only with --rescore" in capsys.readouterr().err


def test_a_stored_diagnosis_reopens_and_scores_as_it_did(world, tmp_path):
    """Reopened from its report and the cache, a diagnosis scores a candidate set exactly as
    it scored it, and any combination of candidates besides."""
    from sim2real.diagnosis.joint import assignment
    from sim2real.reopen import reopen

    out = tmp_path / "report"
    _diagnose(world, out)  # every set comes from the cache of the earlier tests
    stored = Diagnosis.from_json(json.loads((out / "report.json").read_text()))
    reopened = reopen(stored)
    noise = stored.candidates["visual.sensor_noise"]
    best = noise["strengths"][noise["best"]]
    both = assignment({"visual.sensor_noise": best, "visual.white_balance": 0.3})
    nominal, alone, together = reopened.values(
        [(), assignment({"visual.sensor_noise": best}), both]
    )
    assert nominal.closure == 0.0 and np.all(nominal.replicates == 0.0)
    assert alone.closure > 0.3
    assert np.isfinite(together.closure) and together.replicates.shape == (BUDGET.n_boot,)
    if stored.joint is not None:  # the calibrated simulator closes what the diagnosis said
        (calibrated,) = reopened.values([assignment(stored.joint.strengths)])
        assert calibrated.closure == pytest.approx(stored.joint.closure, abs=1e-12)
    (measured,) = reopened.classifier([assignment({"visual.sensor_noise": best})])
    assert set(measured) == set(stored.scored_rungs)
    assert all(0.0 <= m["auc"] <= 1.0 for m in measured.values())
    # the sealed truth, attributed as the diagnosis attributes its own fits
    from sim2real.study.multi import truth_attribution

    answer = json.loads(Path(world["answer"]).read_text())
    truth = truth_attribution(stored, answer)
    assert truth["matter"] == ["visual.sensor_noise"] and truth["closure"] > 0.5
    # refitted from the sealed strength: never worse than the sealed strength itself
    assert truth["closure"] >= truth["closure_at_sealed"]
    # the fabrics' density spread (every sealed set's) is a factor of the truth as well
    assert set(truth["strengths"]) <= {"visual.sensor_noise", "physics.density_variation"}
    assert sum(truth["shapley"].values()) == pytest.approx(truth["closure_of_those_that_matter"])
    camera = truth["shapley"]["visual.sensor_noise"]
    assert truth["stage_shares"]["camera"] == pytest.approx(camera) and camera > 0.5, truth
