"""Checkpoints and run configs from someone else load no code (issue 61, section 1).

Every route that reads a checkpoint or a run folder's config gets a file whose payload would
create a marker file; the test asserts the route refused it in one line and the marker does
not exist. A fuzz test feeds random and damaged bytes to the loader.
"""

import io
import os
import pickle
import zipfile

import numpy as np
import pytest
import torch
import yaml

import sim2real.pipeline as pipeline
import sim2real.shrink as shrink
from common.errors import InputError
from models.checkpoint import (
    NET_TARGETS,
    read_checkpoint,
    read_run_config,
    run_config_targets,
)
from models.components.frame_encoder import FrameEncoder
from models.components.video_nets import load_encoder_state
from models.material_classifier import init_weights_from, load_classifier
from tests.models.conftest import TINY_NET, write_checkpoint


class _Payload:
    """Pickles to a call of ``os.makedirs(marker)``: what a hostile checkpoint would hold."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return (os.makedirs, (self.marker,))


def _pickled_payload(path, marker):
    """A checkpoint that looks like ours but runs ``os.makedirs`` when unpickled unsafely."""
    module = load_classifier(write_checkpoint(path.parent / "good.ckpt"))
    torch.save(
        {
            "hyper_parameters": {"net_config": {**TINY_NET, "num_classes": 54}},
            "state_dict": module.state_dict(),
            "extra": _Payload(marker),
        },
        path,
    )
    return path


def _target_payload(path, marker):
    """A tensors-only checkpoint whose nested net_config names ``os.makedirs``."""
    write_checkpoint(path)
    raw = torch.load(path, weights_only=True)
    config = raw["hyper_parameters"]["net_config"]
    config["encoder"] = {"_target_": "os.makedirs", "name": str(marker)}
    torch.save(raw, path)
    return path


@pytest.fixture(params=["pickle", "target"])
def hostile(request, tmp_path):
    marker = tmp_path / "payload-ran"
    make = _pickled_payload if request.param == "pickle" else _target_payload
    return make(tmp_path / "hostile.ckpt", marker), marker


def _refused(call, marker, *words):
    with pytest.raises(InputError) as info:
        call()
    message = str(info.value)
    assert "\n" not in message
    for word in words:
        assert word in message, message
    assert not marker.exists(), "the checkpoint's payload ran"
    return message


def test_load_classifier_refuses_code_and_foreign_targets(hostile):
    path, marker = hostile
    message = _refused(lambda: load_classifier(path), marker, "checkpoint:", str(path))
    assert "os.makedirs" in message


def test_init_from_and_encoder_checkpoint_refuse_a_pickled_payload(tmp_path):
    marker = tmp_path / "payload-ran"
    path = _pickled_payload(tmp_path / "hostile.ckpt", marker)
    module = load_classifier(tmp_path / "good.ckpt")
    _refused(lambda: init_weights_from(module, path), marker, "init_from:", "os.makedirs")
    encoder = FrameEncoder(name="alexnet5", feature_dim=16, width=0.25)
    _refused(lambda: load_encoder_state(encoder, path), marker, "encoder_checkpoint:")


def test_diagnosis_and_clone_refuse_the_checkpoint_naming_run(hostile):
    from apps.clone import load_checked_classifier
    from datasets.runs import TrainedRun

    path, marker = hostile
    _refused(lambda: pipeline._load_net(str(path), "cpu"), marker, "run:", str(path))
    trained = TrainedRun(checkpoint=path, data_dir=path.parent, spec=None)
    _refused(lambda: load_checked_classifier(trained), marker, "run:")


def test_evaluate_refuses_the_checkpoint_before_reading_any_data(hostile, tmp_path):
    from hydra import compose, initialize_config_dir

    from models.evaluate import run as evaluate_run
    from tests.models.test_pipeline import CONFIGS

    path, marker = hostile
    with initialize_config_dir(config_dir=CONFIGS, version_base="1.3"):
        cfg = compose("evaluate", [f"ckpt_path={path}", f"data_dir={tmp_path}/none"])
    _refused(lambda: evaluate_run(cfg), marker, "ckpt_path:", str(path))


def test_train_refuses_a_hostile_resume_or_init_from(tmp_path, model_dataset):
    import models.training as train_entry
    from tests.models.test_pipeline import _train_cfg

    marker = tmp_path / "payload-ran"
    path = _pickled_payload(tmp_path / "hostile.ckpt", marker)
    for override, field in (
        (f"ckpt_path={path}", "ckpt_path:"),
        (f"init_from={path}", "init_from:"),
    ):
        run = tmp_path / field.rstrip(":")
        cfg = _train_cfg(model_dataset, run, override, "test=false")
        _refused(lambda cfg=cfg: train_entry.train(cfg), marker, field, "os.makedirs")
        assert not (run / "checkpoints").exists()


def _run_config(tmp_path, target):
    """A run folder whose saved training config has a callback with ``target``."""
    from tests.models.test_pipeline import _train_cfg

    cfg = _train_cfg(tmp_path / "data", tmp_path / "run")
    from omegaconf import OmegaConf

    plain = OmegaConf.to_container(cfg, resolve=False)
    plain["callbacks"]["sneaky"] = {"_target_": target, "name": str(tmp_path / "payload-ran")}
    folder = tmp_path / "run" / ".hydra"
    folder.mkdir(parents=True)
    (folder / "config.yaml").write_text(yaml.safe_dump(plain))
    return tmp_path / "run"


def test_a_run_config_with_a_foreign_target_is_refused_before_anything_is_built(tmp_path):
    run = _run_config(tmp_path, "os.makedirs")
    message = _refused(
        lambda: shrink._run_config(run),
        tmp_path / "payload-ran",
        "run: config",
        "callbacks.sneaky._target_",
        "os.makedirs",
    )
    assert "lightning.pytorch.callbacks.EarlyStopping" in message  # the allowed names


def test_the_project_training_configs_pass_the_allow_list(tmp_path):
    run = _run_config(tmp_path, "lightning.pytorch.callbacks.EarlyStopping")
    assert read_run_config(run / ".hydra" / "config.yaml").callbacks.sneaky is not None
    assert set(NET_TARGETS) <= set(run_config_targets())
    assert not any("Lambda" in name for name in run_config_targets())


def _fuzz_cases(good: bytes, seed: int = 61, count: int = 120):
    """Random byte strings, truncations and byte flips of a real checkpoint (bounded)."""
    rng = np.random.default_rng(seed)
    for i in range(count):
        kind = i % 4
        if kind == 0:
            data = rng.integers(0, 256, size=int(rng.integers(1, 4096)), dtype=np.uint8).tobytes()
        elif kind == 1:
            data = good[: int(rng.integers(1, len(good)))]
        elif kind == 2:  # flips in the weights' bytes load: only the other kinds must fail
            flipped = bytearray(good)
            for at in rng.integers(0, len(flipped), size=int(rng.integers(1, 16))):
                flipped[at] = int(rng.integers(0, 256))
            data = bytes(flipped)
        else:  # a valid zip (torch's container) with random members, or a plain pickle
            buffer = io.BytesIO()
            with zipfile.ZipFile(buffer, "w") as archive:
                archive.writestr("archive/data.pkl", rng.bytes(int(rng.integers(1, 200))))
            data = buffer.getvalue() if i % 8 == 3 else pickle.dumps(rng.bytes(8))
        yield kind, data


def test_fuzzed_checkpoints_give_one_line_errors(tmp_path):
    good = write_checkpoint(tmp_path / "good.ckpt").read_bytes()
    path = tmp_path / "fuzz.ckpt"
    refused = dict.fromkeys(range(4), 0)
    for kind, data in _fuzz_cases(good):
        path.write_bytes(data)
        try:
            load_classifier(path)
        except InputError as error:
            assert "\n" not in str(error) and str(error).startswith(f"checkpoint: {path}")
            refused[kind] += 1
    assert refused[0] == refused[1] == refused[3] == 30, refused
    assert refused[2] > 0, refused


@pytest.mark.parametrize(
    ("write", "words"),
    [
        (lambda p: p.write_bytes(b""), "is empty"),
        (lambda p: p.write_text("epoch: 3\n"), "is not a torch checkpoint"),
        (lambda p: torch.save(torch.zeros(3), p), "holds a Tensor, not a training checkpoint"),
        (lambda p: p.mkdir(), "is not a file"),
        (lambda p: None, "does not exist"),
    ],
)
def test_files_that_are_not_checkpoints_are_named_in_one_line(write, words, tmp_path):
    path = tmp_path / "x.ckpt"
    write(path)
    with pytest.raises(InputError, match=rf"^ckpt_path: {path} .*{words}"):
        read_checkpoint(path, "ckpt_path")


def test_a_truncated_checkpoint_is_called_truncated(tmp_path):
    good = write_checkpoint(tmp_path / "good.ckpt").read_bytes()
    (tmp_path / "cut.ckpt").write_bytes(good[: len(good) // 2])
    with pytest.raises(InputError, match="is truncated or damaged"):
        load_classifier(tmp_path / "cut.ckpt")
