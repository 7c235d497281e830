"""models.training: a run folder belongs to one dataset; early stopping says why it stopped."""

import hashlib
import json
import logging
import shutil
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir

import models.training as train_entry
from common.errors import InputError

CONFIGS = str(Path(__file__).resolve().parents[2] / "configs")
FAST = [
    "encoder.width=0.25",
    "encoder.feature_dim=16",
    "data.batch_size=2",
    "data.num_workers=0",
    "~logger",
    "callbacks.progress_bar=null",
    "callbacks.lr_monitor=null",
    "trainer.log_every_n_steps=1",
    "test=false",
]


def _train_cfg(data_dir, run, *overrides):
    with initialize_config_dir(config_dir=CONFIGS, version_base="1.3"):
        return compose(
            config_name="train",
            overrides=[
                f"dataset.dir={data_dir}",
                f"paths.output_dir={run}",
                f"paths.log_dir={run.parent}",
                f"paths.work_dir={run}",
                *FAST,
                *overrides,
            ],
        )


def _sha(root: Path) -> str:
    return hashlib.sha256((root / "manifest.json").read_bytes()).hexdigest()


def _record(run: Path) -> list[dict]:
    return json.loads((run / train_entry.DATASET_RECORD).read_text())["datasets"]


def test_early_stopping_says_when_and_why_training_ended(model_dataset, tmp_path, caplog):
    # min_delta 2 on an accuracy: no epoch after the first can improve, patience 1 stops it.
    run = tmp_path / "train" / "early"
    cfg = _train_cfg(
        model_dataset,
        run,
        "trainer.max_epochs=4",
        "callbacks.early_stopping.patience=1",
        "callbacks.early_stopping.min_delta=2.0",
    )
    with caplog.at_level(logging.INFO, logger="models.training"):
        train_entry.train(cfg)
    (message,) = [r.getMessage() for r in caplog.records if "early stopping" in r.getMessage()]
    assert message.startswith(
        "early stopping ended training after epoch 2 of max_epochs 4: val/acc did not improve "
        "in the last 1 validation checks (best val/acc = "
    ), message
    assert _record(run) == [
        {"dir": str(model_dataset.resolve()), "manifest_sha256": _sha(model_dataset)}
    ]


def test_run_folder_refuses_a_different_dataset(model_dataset, tmp_path, caplog):
    run = tmp_path / "train" / "tiny-cnn_lstm"
    train_entry.train(_train_cfg(model_dataset, run, "trainer.max_epochs=1"))
    recorded = [{"dir": str(model_dataset.resolve()), "manifest_sha256": _sha(model_dataset)}]
    assert _record(run) == recorded
    last = run / "checkpoints" / "last.ckpt"
    stamp = last.stat().st_mtime_ns

    # The same folder name holding different data (regenerated): never resumed, never
    # re-evaluated, and the message names both datasets.
    other = tmp_path / "other"
    shutil.copytree(model_dataset, other)
    (other / "manifest.json").write_text((other / "manifest.json").read_text() + "\n")
    expected = (
        f"run folder {run} was made with dataset {model_dataset.resolve()} (manifest sha256 "
        f"{_sha(model_dataset)[:12]}), but this command reads {other.resolve()} (manifest "
        f"sha256 {_sha(other)[:12]}); a run is never resumed or re-evaluated on another dataset"
    )
    for mode in (["trainer.max_epochs=2"], ["train=false", "test=true"]):
        with pytest.raises(InputError) as info:
            train_entry.train(_train_cfg(other, run, *mode))
        assert str(info.value).startswith(expected)
    assert last.stat().st_mtime_ns == stamp and _record(run) == recorded

    # The same bytes in another folder (a moved dataset) are the same run, with a warning.
    moved = tmp_path / "moved"
    shutil.copytree(model_dataset, moved)
    with caplog.at_level(logging.WARNING, logger="models.training"):
        train_entry.train(_train_cfg(moved, run, "trainer.max_epochs=1"))
    assert any("its dataset moved" in r.getMessage() for r in caplog.records)
    assert _record(run) == [{"dir": str(moved.resolve()), "manifest_sha256": _sha(moved)}]

    # A run folder from before the record existed: adopted loudly, then checked like any.
    (run / train_entry.DATASET_RECORD).unlink()
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="models.training"):
        train_entry.train(_train_cfg(model_dataset, run, "trainer.max_epochs=1"))
    assert any("has checkpoints but no dataset.json" in r.getMessage() for r in caplog.records)
    assert _record(run) == recorded
    with pytest.raises(InputError, match="was made with dataset"):
        train_entry.train(_train_cfg(other, run, "trainer.max_epochs=1"))


def test_a_missing_dataset_is_named_before_the_run_folder_is_touched(tmp_path):
    run = tmp_path / "train" / "none"
    with pytest.raises(FileNotFoundError, match="no-such-data does not exist") as info:
        train_entry.train(_train_cfg(tmp_path / "no-such-data", run))
    assert str(info.value).endswith(  # and says how to make it
        "; make it with: python -m datasets.generate motion=wind level=1 texture=random "
        f"preset=full seed=0 out_dir={tmp_path / 'no-such-data'}"
    )
    assert not run.exists()
