"""train.py and models.evaluate end to end on a tiny generated dataset and a tiny real folder."""

import json
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from hydra.errors import MissingConfigException
from hydra.utils import instantiate

import models.training as train_entry
from common.errors import InputError
from models.evaluate import run as evaluate_run
from models.material_classifier import load_classifier
from tests.models.conftest import write_checkpoint

CONFIGS = str(Path(__file__).resolve().parents[2] / "configs")
FAST = [
    "encoder.width=0.25",
    "encoder.feature_dim=16",
    "data.batch_size=2",
    "data.num_workers=0",
    "trainer.max_epochs=2",
    "~logger",
    "callbacks.progress_bar=null",
    "callbacks.lr_monitor=null",
    "trainer.log_every_n_steps=1",
]


def _compose(config="train", overrides=(), hydra=False):
    with initialize_config_dir(config_dir=CONFIGS, version_base="1.3"):
        return compose(config_name=config, overrides=list(overrides), return_hydra_config=hydra)


def _options(group):
    """The options of a config group (``experiment/train``: one experiment per method)."""
    with initialize_config_dir(config_dir=CONFIGS, version_base="1.3"):
        return sorted(GlobalHydra.instance().config_loader().get_group_options(group))


def _train_cfg(data_dir, out_dir, *overrides, log_dir=None):
    return _compose(
        "train",
        [
            f"dataset.dir={data_dir}",
            f"paths.output_dir={out_dir}",
            f"paths.log_dir={log_dir or out_dir.parent}",
            f"paths.work_dir={out_dir}",
            *FAST,
            *overrides,
        ],
    )


@pytest.mark.parametrize("protocol", _options("protocol"))
@pytest.mark.parametrize("dataset", _options("dataset"))
@pytest.mark.parametrize("method", _options("experiment/train"))
def test_every_experiment_composes_and_builds_its_model(method, dataset, protocol):
    overrides = [f"experiment=train/{method}", f"dataset={dataset}", f"protocol={protocol}"]
    cfg = _compose("train", [*overrides, "paths.output_dir=/tmp/x"], hydra=True)
    sequence = protocol == "sequence"  # thesis sub-sequence split: a run folder of its own
    swap = method == "cnn_lstm_2s"  # the two-stream model trains with background swap
    split_tag = "-seq" if sequence else ""
    tag = split_tag + ("-bgswap" if swap else "")
    assert cfg.model.method == method
    assert cfg.run_name == f"{cfg.dataset.name}{tag}-{cfg.model.method}"
    assert cfg.hydra.run.dir.endswith(f"/train/{cfg.run_name}")
    assert cfg.data.split_protocol == ("sequence" if sequence else "simulation")
    assert cfg.dataset.name.startswith(dataset) and cfg.dataset.motion == dataset
    if cfg.model.method in ("base2", "cnn_lstm_ft", "cnn_lstm_2s"):  # baseline 1's CNN first
        assert f"/train/{cfg.dataset.name}{tag}-base1/" in cfg.model.net.encoder_checkpoint
        assert cfg.model.net.freeze_encoder == (cfg.model.method == "base2")
    if cfg.model.method == "cnn_lstm_2s":  # its motion stream starts from the Diff-V run's CNN
        assert cfg.model.net.inputs == "two_stream" and cfg.model.net.motion_encoder.fc6_norm
        motion = cfg.model.net.motion_encoder_checkpoint
        assert f"/train/{cfg.dataset.name}{split_tag}-cnn_lstm_diff/" in motion
        cfg.model.net.motion_encoder_checkpoint = None
    assert cfg.model.net.encoder.fc6_norm  # every method: BatchNorm keeps fc6's units alive
    assert cfg.data.background_swap.prob == (1.0 if swap else 0.0)  # or variant=bgswap
    if cfg.model.method in ("cnn_lstm_diff", "cnn_lstm_2s"):  # differences: cloth scale kept
        assert cfg.model.net.inputs in ("frame_diff", "two_stream")
        assert list(cfg.data.augment.crop_scale) == [1.0, 1.0] and cfg.data.augment.flip_prob == 0
    if cfg.model.method in ("base2", "cnn_lstm_ft", "cnn_lstm_2s"):
        cfg.model.net.encoder_checkpoint = None  # baseline 1 is not trained here
    module = instantiate(cfg.model, net={"num_classes": 54})  # train.py: the data's count
    assert module(torch.rand(1, 3, 3, 64, 64)).shape == (1, 54)


@pytest.mark.parametrize(
    ("method", "epochs", "encoder_lr_scale"),
    [("base1", 15, 1.0), ("base2", 5, 1.0), ("cnn_lstm_ft", 10, 0.1), ("cnn_lstm", 20, 1.0)],
)
def test_the_sequence_protocol_sets_each_methods_schedule(method, epochs, encoder_lr_scale):
    for dataset in _options("dataset"):
        cfg = _compose(
            "train",
            [
                f"experiment=train/{method}",
                f"dataset={dataset}",
                "protocol=sequence",
                "paths.output_dir=/tmp/x",
            ],
        )
        assert cfg.trainer.max_epochs == epochs
        assert cfg.model.encoder_lr_scale == encoder_lr_scale
        held_out = _compose(
            "train", [f"experiment=train/{method}", f"dataset={dataset}", "paths.output_dir=/tmp/x"]
        )
        assert held_out.trainer.max_epochs == 20 and held_out.model.encoder_lr_scale == 1.0


def test_the_readme_recipe_is_diff_v_on_the_wind_grid_data():
    assert "wind_grid_diff" in _options("experiment/recipe")
    cfg = _compose(
        "train", ["experiment=recipe/wind_grid_diff", "paths.output_dir=/tmp/x"], hydra=True
    )
    assert cfg.run_name == "wind-L1-grid-full-s0-cnn_lstm_diff"
    assert cfg.hydra.run.dir.endswith(f"/train/{cfg.run_name}")
    assert cfg.data.split_protocol == "simulation" and cfg.trainer.max_epochs == 20
    assert list(cfg.data.augment.crop_scale) == [1.0, 1.0] and cfg.data.augment.flip_prob == 0
    module = instantiate(cfg.model, net={"num_classes": 54})
    assert module(torch.rand(1, 3, 3, 64, 64)).shape == (1, 54)


@pytest.mark.parametrize("protocol", _options("protocol"))
@pytest.mark.parametrize("variant", ["bgswap", "texswap"])
@pytest.mark.parametrize(("method", "dataset"), [("base2", "wind"), ("cnn_lstm_ft", "arm")])
def test_swap_variants_have_runs_of_their_own(method, dataset, variant, protocol):
    cfg = _compose(
        "train",
        [
            f"experiment=train/{method}",
            f"dataset={dataset}",
            f"protocol={protocol}",
            f"variant={variant}",
            "paths.output_dir=/tmp/x",
        ],
        hydra=True,
    )
    tag = ("-seq" if protocol == "sequence" else "") + f"-{variant}"  # apart from -seq, -<variant>
    assert cfg.run_name == f"{cfg.dataset.name}{tag}-{cfg.model.method}"
    assert cfg.hydra.run.dir.endswith(f"/train/{cfg.run_name}")
    assert f"/train/{cfg.dataset.name}{tag}-base1/" in cfg.model.net.encoder_checkpoint
    assert instantiate(cfg.data.background_swap).prob == 1.0  # both swap backgrounds
    assert instantiate(cfg.data.texture_swap).prob == (1.0 if variant == "texswap" else 0.0)


def test_unknown_model_or_encoder_names_fail_clearly():
    with pytest.raises(MissingConfigException, match="nope"):
        _compose("train", ["model=nope"])
    cfg = _compose("train", ["encoder.name=vgg99", "paths.output_dir=/tmp/x"])
    with pytest.raises(Exception, match="encoder name must be one of"):
        instantiate(cfg.model)


def test_missing_data_directory_fails_clearly(tmp_path):
    cfg = _train_cfg(tmp_path / "no-such-data", tmp_path / "run")
    with pytest.raises(Exception, match="no-such-data does not exist"):
        train_entry.train(cfg)


def test_encoder_lr_scale_gives_the_cnn_its_own_rate_through_the_schedule():
    cfg = _compose(
        "train",
        [
            "model=cnn_lstm",
            "model.encoder_lr_scale=0.1",
            "trainer.max_epochs=4",
            "paths.output_dir=/tmp/x",
            "+model.net.num_classes=54",
        ],
    )
    module = instantiate(cfg.model)
    config = module.configure_optimizers()
    optimizer, scheduler = config["optimizer"], config["lr_scheduler"]["scheduler"]
    rest, cnn = optimizer.param_groups
    assert {id(p) for p in cnn["params"]} == {id(p) for p in module.net.encoder.parameters()}
    assert len(rest["params"]) + len(cnn["params"]) == len(list(module.parameters()))
    assert rest["lr"] == pytest.approx(2e-3) and cnn["lr"] == pytest.approx(2e-4)
    optimizer.step()
    scheduler.step()
    assert cnn["lr"] / rest["lr"] == pytest.approx(0.1) and rest["lr"] < 2e-3
    plain = instantiate(
        _compose("train", ["model=cnn_lstm", "paths.output_dir=/tmp/x"]).model,
        net={"num_classes": 54},
    )
    assert len(plain.configure_optimizers()["optimizer"].param_groups) == 1
    for bad in (0.0, 1.5, True):
        with pytest.raises(Exception, match=r"model.encoder_lr_scale must be in \(0, 1\]"):
            instantiate(cfg.model, encoder_lr_scale=bad)


@pytest.mark.parametrize("model", ["cnn_lstm", "base1"])
def test_tiny_batch_is_overfit(model):
    torch.manual_seed(0)
    cfg = _compose(
        "train",
        [
            f"model={model}",
            "encoder.width=0.25",
            "encoder.dropout=0.0",
            "encoder.feature_dim=32",
            "model.label_smoothing=0.0",
            "paths.output_dir=/tmp/x",
            "+model.net.num_classes=54",
        ],
    )
    module = instantiate(cfg.model)
    video = torch.rand(6, 3, 3, 48, 48, generator=torch.Generator().manual_seed(0))
    labels = torch.tensor([0, 7, 19, 26, 40, 53])
    optimizer = torch.optim.Adam(module.parameters(), lr=3e-3)
    module.train()
    for _ in range(300):
        optimizer.zero_grad()
        loss = module.loss(module(video), labels)
        loss.backward()
        optimizer.step()
    assert loss.item() < 0.05
    module.eval()
    assert (module(video).argmax(1) == labels).all()


def test_train_evaluate_reload_and_baselines_end_to_end(model_dataset, real_folder, tmp_path):
    logs = tmp_path / "logs"
    run = logs / "train" / "tiny-cnn_lstm"
    metrics = train_entry.train(_train_cfg(model_dataset, run, log_dir=logs))
    best = run / "checkpoints" / "best.ckpt"
    assert best.is_file() and (run / "checkpoints" / "last.ckpt").is_file()
    assert 0.0 <= metrics["test/acc"] <= 1.0
    hparams = torch.load(best, weights_only=False)["hyper_parameters"]  # the data's classes
    assert hparams["net_config"]["num_classes"] == hparams["class_grid"]["num_classes"] == 54
    for name in ("sim_test.json", "sim_test.md", "confusion_test.png"):
        assert (run / "eval" / name).stat().st_size > 0
    report = json.loads((run / "eval" / "sim_test.json").read_text())
    assert report["epochs"] == 2 and report["train_minutes"] > 0  # last.ckpt after every epoch

    # Checkpoint round trip: the rebuilt module predicts exactly what the saved one did.
    first, second = load_classifier(best), load_classifier(best)
    clip = torch.rand(2, 4, 3, 32, 32)
    torch.testing.assert_close(first(clip), second(clip), rtol=0, atol=0)
    stored = torch.load(best, weights_only=False)["state_dict"]
    for key, value in first.state_dict().items():
        torch.testing.assert_close(value, stored[key], rtol=0, atol=0, msg=key)

    # Running again resumes from last.ckpt: nothing is retrained, the best stays the same.
    mtime = best.stat().st_mtime_ns
    train_entry.train(_train_cfg(model_dataset, run, log_dir=logs))
    assert best.stat().st_mtime_ns == mtime

    # Baseline 1 trains on frames and is scored on clips; baseline 2 freezes its CNN.
    base1 = logs / "train" / "tiny-base1"
    cfg1 = _train_cfg(model_dataset, base1, "model=base1", "data.mode=frame", log_dir=logs)
    train_entry.train(cfg1)
    base2 = logs / "train" / "tiny-base2"
    encoder = f"model.net.encoder_checkpoint={base1}/checkpoints/best.ckpt"
    cfg2 = _train_cfg(model_dataset, base2, "model=base2", encoder, log_dir=logs)
    train_entry.train(cfg2)
    b1, b2 = (
        load_classifier(base1 / "checkpoints/best.ckpt"),
        load_classifier(base2 / "checkpoints/best.ckpt"),
    )
    for key, value in b1.net.encoder.state_dict().items():
        torch.testing.assert_close(b2.net.encoder.state_dict()[key], value, msg=key)

    # A second stage starts from a run's weights (init_from) on its own schedule: at lr 0 the
    # trained parameters stay exactly those of the checkpoint it started from.
    stage2 = logs / "train" / "tiny-stage2-cnn_lstm"
    cfg_stage2 = _train_cfg(
        model_dataset,
        stage2,
        f"init_from={best}",
        "model.optimizer.lr=0.0",
        "model.optimizer.weight_decay=0.0",
        log_dir=logs,
    )
    train_entry.train(cfg_stage2)
    after = load_classifier(stage2 / "checkpoints" / "best.ckpt")
    for name, value in after.named_parameters():
        torch.testing.assert_close(value, first.get_parameter(name), rtol=0, atol=0, msg=name)
    with pytest.raises(InputError, match=r"init_from: .*nope.ckpt does not exist"):
        train_entry.train(_train_cfg(model_dataset, tmp_path / "x", "init_from=nope.ckpt"))
    wrong = _train_cfg(model_dataset, tmp_path / "y", f"init_from={base1}/checkpoints/best.ckpt")
    with pytest.raises(ValueError, match=r"init_from .* does not fit this model"):
        train_entry.train(wrong)  # baseline 1's per-frame net into a CNN+LSTM

    # The two-stream model, trained over swapped backgrounds, rebuilds from its checkpoint.
    two = logs / "train" / "tiny-cnn_lstm_2s"
    cfg3 = _train_cfg(
        model_dataset,
        two,
        "model=cnn_lstm_2s",
        encoder,
        f"model.net.motion_encoder_checkpoint={best}",
        "data.background_swap.prob=1.0",
        log_dir=logs,
    )
    assert 0.0 <= train_entry.train(cfg3)["test/acc"] <= 1.0
    rebuilt = load_classifier(two / "checkpoints" / "best.ckpt")
    assert rebuilt.net.inputs == "two_stream" and rebuilt(clip).shape == (2, 54)

    # The evaluation entry on the simulated test split and on real videos.
    out = tmp_path / "eval"
    cfg = _compose(
        "evaluate",
        [
            f"ckpt_path={best}",
            f"data_dir={model_dataset}",
            f"real_dir={real_folder}",
            f"out_dir={out}",
            "real.clip_len=4",
            "real.clip_stride=4",
            "real.size=32",
            "bootstrap.rounds=50",
        ],
    )
    training_report = (run / "eval" / "sim_test.json").read_bytes()
    results = evaluate_run(cfg)
    assert results["sim"]["clips"] == 2 and results["real"]["videos"] == 4
    correlations = results["real"]["correlations"]
    assert set(correlations) == {"all", "W1", "W2"}
    assert correlations["all"]["stiffness"]["count"] == 4
    folder = Path(results["out_dir"])  # out_dir/<dataset>-test+<real folder>-<hash>
    assert folder.parent == out and folder.name.startswith(f"{model_dataset.name}-test+")
    for name in ("real.json", "real.md", "real_videos.csv", "sim_test.json", "confusion_test.png"):
        assert (folder / name).stat().st_size > 0
    assert "Table 7.3" in (folder / "real.md").read_text()
    assert (run / "eval" / "sim_test.json").read_bytes() == training_report


def test_the_class_count_comes_from_the_data(model_dataset, tmp_path):
    cfg = _train_cfg(model_dataset, tmp_path / "run", "+model.net.num_classes=10")
    message = r"model\.net\.num_classes must be the data's class count 54"
    with pytest.raises(ValueError, match=message):
        train_entry.train(cfg)


def test_one_config_and_seed_train_the_same_weights(model_dataset, tmp_path):
    """Two runs of one config give bit-identical weights, with the random parts switched on:
    a loader worker process, colour/crop augmentation and background swap every sample."""
    random_parts = ("data.num_workers=1", "data.background_swap.prob=1.0")
    weights = []
    for name in ("first", "second"):
        run = tmp_path / "train" / name
        train_entry.train(_train_cfg(model_dataset, run, *random_parts, log_dir=tmp_path))
        checkpoint = torch.load(run / "checkpoints" / "last.ckpt", weights_only=False)
        weights.append(checkpoint["state_dict"])
    first, second = weights
    assert first.keys() == second.keys()
    for key, value in first.items():
        torch.testing.assert_close(second[key], value, rtol=0, atol=0, msg=key)


def test_evaluation_errors_name_the_problem(model_dataset, real_folder, tmp_path):
    with pytest.raises(ValueError, match=r"data_dir .* and/or real_dir"):
        evaluate_run(_compose("evaluate", ["ckpt_path=x.ckpt"]))
    with pytest.raises(InputError, match=r"^ckpt_path: x\.ckpt does not exist"):  # named first
        evaluate_run(_compose("evaluate", ["ckpt_path=x.ckpt", f"real_dir={tmp_path}/none"]))
    with pytest.raises(InputError, match=r"^ckpt_path: x\.ckpt does not exist"):
        evaluate_run(_compose("evaluate", ["ckpt_path=x.ckpt", f"data_dir={model_dataset}"]))
    ckpt = write_checkpoint(tmp_path / "run" / "best.ckpt")
    with pytest.raises(FileNotFoundError, match="real_dir"):
        evaluate_run(_compose("evaluate", [f"ckpt_path={ckpt}", f"real_dir={tmp_path}/none"]))
    (real_folder / "labels.csv").write_text("video,stiffness\nfabric0.mp4,1.0\n")
    from datasets.real_video import RealVideoDataset

    with pytest.raises(ValueError, match="density"):
        RealVideoDataset(real_folder)
