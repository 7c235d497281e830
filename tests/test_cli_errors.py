"""Bad command-line values end each entry point with one line naming the field, before any
work is done and before anything is written (issue 28, "no silent wrong results")."""

import subprocess
import sys
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra

import benchmarks.thesis.tissue_jobs as tissue_entry
import models.training as train_entry
import sim2real.diagnose as diagnose_entry
import simulator.cloth.simulate as simulate_entry
from common.errors import InputError
from tests.conftest import subprocess_env

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = str(ROOT / "configs")


def _compose(config, *overrides):
    with initialize_config_dir(config_dir=CONFIGS, version_base="1.3"):
        return compose(config_name=config, overrides=list(overrides))


def _refuse_to_simulate(*args, **kwargs):
    raise AssertionError("the simulation ran although a field was bad")


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("classes=[1.7]", r"classes[0] must be an integer class id in [0, 53], got 1.7"),
        ("classes=[0,54]", r"classes[1] must be an integer class id in [0, 53], got 54"),
        ("classes=5", "classes must be a list of integer class ids in [0, 53]"),
        ("seed=abc", "seed must be an integer >= 0, got 'abc'"),
        ("wind_level=3", "wind_level must be an integer in [0, 2], got 3"),
        ("fps=0", "fps must be a number > 0, got 0"),
        ("record_time=abc", "record_time must be a finite number > 0, got 'abc'"),
        ("export=gif", "export must be one of obj, ply or null, got 'gif'"),
        ("sim.max_dt=abc", "sim.max_dt must be a number, got 'abc'"),
        ("sim.dtype=float16", "sim.dtype must be 'float32' or 'float64', got 'float16'"),
        ("sim.device=tpu", "sim.device must be one of auto, cpu, cuda, cuda:N; got 'tpu'"),
        ("+sim.fast=true", "sim.fast is not a field of sim; allowed: max_dt"),
        ("scenario.resolution_level=7", "scenario.resolution_level must be one of [1, 2, 3]"),
        ("scenario=wind", "scenario must be a scene's fields (scenario.<field>=...); pick"),
        ("effects.aero_lift=maybe", "effects.aero_lift must be true or false, got 'maybe'"),
        ("threads=0", "threads must be an integer >= 1 or null"),
    ],
)
def test_simulate_checks_every_field_before_simulating(override, message, tmp_path, monkeypatch):
    monkeypatch.setattr(simulate_entry, "simulate", _refuse_to_simulate)
    cfg = _compose("simulate", f"paths.output_dir={tmp_path}", override)
    with pytest.raises(InputError) as info:
        simulate_entry.run(cfg)
    assert str(info.value).startswith(message)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.skipif(torch.cuda.is_available(), reason="the machine has CUDA")
def test_cuda_requests_without_cuda_are_refused(tmp_path, monkeypatch):
    monkeypatch.setattr(simulate_entry, "simulate", _refuse_to_simulate)
    with pytest.raises(InputError, match=r"^sim.device=cuda asks for CUDA, but this machine"):
        simulate_entry.run(_compose("simulate", f"paths.output_dir={tmp_path}", "sim.device=cuda"))
    for override in ("trainer=gpu", "trainer.accelerator=gpu"):
        cfg = _compose("train", f"paths.output_dir={tmp_path}", override)
        with pytest.raises(
            InputError, match=r"^trainer.accelerator=gpu asks for CUDA.*trainer=cpu"
        ):
            train_entry.train(cfg)


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("seed=abc", "seed must be an integer in [0, 4294967295], got 'abc'"),
        ("train=maybe", "train must be true or false, got 'maybe'"),
        ("threads=0", "threads must be an integer >= 1 or null"),
        ("trainer.max_epochs=abc", "trainer.max_epochs must be an integer or null, got 'abc'"),
        ("trainer.precision=bf17", "trainer.precision must be one of 64, 32, 16,"),
        ("data.batch_size=abc", "data.batch_size must be an integer, got 'abc'"),
        ("data.batch_size=0", "batch_size must be an integer >= 1, got 0"),
        ("model.optimizer.lr=abc", "model.optimizer.lr must be a number, got 'abc'"),
        (
            "callbacks.early_stopping.patience=x",
            "callbacks.early_stopping.patience must be an integer, got 'x'",
        ),
        ("encoder.width=wide", "model.net.encoder.width must be a number, got 'wide'"),
    ],
)
def test_train_checks_fields_before_reading_data(override, message, tmp_path):
    # data.batch_size=0 passes the type check and is refused by the datamodule itself,
    # before the run folder gets its dataset record.
    run = tmp_path / "run"
    cfg = _compose("train", f"paths.output_dir={run}", f"dataset.dir={tmp_path}/none", override)
    if override == "data.batch_size=0":
        cfg.dataset.dir = str(_empty_dataset(tmp_path))
    with pytest.raises(InputError) as info:
        train_entry.train(cfg)
    assert str(info.value).startswith(message)
    assert not (run / train_entry.DATASET_RECORD).exists()


def _empty_dataset(tmp_path):
    """A folder with a manifest.json (enough for the dataset identity, not for training)."""
    root = tmp_path / "data"
    root.mkdir()
    (root / "manifest.json").write_text("{}\n")
    return root


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (["tissue_job=ukf", "tissue_job.trials=abc"], "tissue_job.trials must be an integer"),
        (["tissue_job=ukf", "tissue_job.trials=0"], "tissue_job.trials must be an integer >= 1"),
        (["tissue_job=ukf", "tissue_job.body=lung"], "tissue_job.body must be one of beam, heart"),
        (
            ["tissue_job=ukf", "tissue_job.moduli_kpa=[40,-1]"],
            "tissue_job.moduli_kpa must be a number > 0, got -1",
        ),
        (
            ["tissue_job=tables", "tissue_job.only=[t33]"],
            "tissue_job.only must be one of t31, t32, sens; got 't33'",
        ),
        (
            ["tissue_job=monocular", "tissue_job.elements=[256,abc]"],
            "tissue_job.elements must be a list of integers",
        ),
        (["seed=abc"], "seed must be an integer >= 0, got 'abc'"),
    ],
)
def test_tissue_job_fields_are_checked_before_the_job_writes(overrides, message, tmp_path):
    out = tmp_path / "out"
    cfg = _compose("tissue", f"out_dir={out}", "paths.output_dir=/tmp/unused", *overrides)
    with pytest.raises(InputError) as info:
        tissue_entry.run(cfg)
    assert str(info.value).startswith(message)
    assert not out.exists()


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("clip_len=abc", "clip_len must be an integer >= 1, got 'abc'"),
        ("clip_stride=0", "clip_stride must be an integer >= 1, got 0"),
        ("alpha=2", "alpha must be a number in (0, 1], got 2"),
        ("n_jobs=x", "n_jobs must be an integer >= 1, got 'x'"),
        ("device=tpu", "device must be one of auto, cpu, cuda; got 'tpu'"),
        ("progress=sometimes", "progress must be true or false, got 'sometimes'"),
    ],
)
def test_diagnose_checks_fields_before_it_starts(override, message, tmp_path):
    cfg = _compose(
        "diagnose",
        f"real_dir={tmp_path}/real",
        f"run={tmp_path}/run",
        f"out_dir={tmp_path}/out",
        "paths.output_dir=/tmp/unused",
        override,
    )
    with pytest.raises(InputError) as info:
        diagnose_entry.run(cfg)
    assert str(info.value) == message
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("command", "line"),
    [
        (
            ["-m", "simulator.cloth.simulate", "classes=[1.7]"],
            "error: classes[0] must be an integer class id in [0, 53], got 1.7",
        ),
        (["-m", "datasets.generate", "seed=abc"], "error: seed must be an integer >= 0, got 'abc'"),
        (
            ["train.py", "trainer.max_epochs=abc"],
            "error: trainer.max_epochs must be an integer or null, got 'abc'",
        ),
        (
            ["-m", "benchmarks.thesis.tissue_jobs", "tissue_job=ukf", "tissue_job.trials=abc"],
            "error: tissue_job.trials must be an integer, got 'abc'",
        ),
    ],
)
def test_entry_points_print_one_line_and_exit_2(command, line, tmp_path):
    env = subprocess_env()
    if command[0] == "train.py":
        command = [str(ROOT / "train.py"), *command[1:]]
    done = subprocess.run(
        [sys.executable, *command, f"paths.root_dir={tmp_path}"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 2, done.stderr
    assert done.stderr.strip().splitlines() == [line]
    assert "Traceback" not in done.stdout + done.stderr
    written = [p for p in tmp_path.rglob("*") if p.is_file() and ".hydra" not in p.parts]
    assert [p for p in written if p.suffix != ".log"] == []  # Hydra's log file only


def _options(group):
    with initialize_config_dir(config_dir=CONFIGS, version_base="1.3"):
        return sorted(GlobalHydra.instance().config_loader().get_group_options(group))


EXPERIMENTS = [  # every method on every dataset under every split protocol, and the recipes
    (f"experiment=train/{method}", f"dataset={dataset}", f"protocol={protocol}")
    for method in _options("experiment/train")
    for dataset in _options("dataset")
    for protocol in _options("protocol")
] + [(f"experiment=recipe/{recipe}",) for recipe in _options("experiment/recipe")]


@pytest.mark.parametrize("experiment", EXPERIMENTS, ids=" ".join)
def test_every_training_experiment_passes_the_field_checks(experiment):
    train_entry._check_fields(
        _compose("train", *experiment, "trainer=cpu", "paths.output_dir=/tmp/unused")
    )


@pytest.mark.parametrize("motion", ["wind", "arm"])
@pytest.mark.parametrize("preset", ["tiny", "small", "full"])
def test_generation_presets_pass_the_field_checks(motion, preset):
    from datasets.generate import _run_fields, spec_from_config

    cfg = _compose("generate", f"motion={motion}", f"preset={preset}", "paths.output_dir=/tmp/x")
    assert spec_from_config(cfg).preset.name == preset
    assert _run_fields(cfg)["n_jobs"] >= 1


@pytest.mark.parametrize("scene", ["wind", "arm_bend"])
def test_simulate_scenarios_pass_the_field_checks(scene):
    fields = simulate_entry._checked(
        _compose("simulate", f"scene={scene}", "paths.output_dir=/tmp/unused")
    )
    assert fields["classes"] == (0, 26, 53) and fields["export"] is None
