"""MLP feature references: a known answer on synthetic features, and the command end to end."""

import json

import numpy as np
import pytest

from datasets.feature_probe import FEATURES, by_clip_index, main, mlp_accuracy, probe_markdown

from .test_split_protocol import _manifest


def _clips(manifest, signal: float, seed: int = 0):
    """Features = a random class code times ``signal`` plus unit noise, per clip."""
    rng = np.random.default_rng(seed)
    code = {c: rng.normal(size=20) for c in (0, 7, 53)}
    return {
        c["key"]: np.float32(signal * code[c["class_id"]] + rng.normal(size=20))
        for c in manifest.clips
    }


def test_mlp_reads_a_class_code_and_not_noise():
    manifest = _manifest(sims_per_class=(6, 1, 4))
    train, test = manifest.clips_of("train"), manifest.clips_of("test")
    clear = mlp_accuracy(train, test, _clips(manifest, 3.0), epochs=40)
    assert clear["acc"] == clear["stretch_acc"] == clear["bend_acc"] == 1.0
    assert clear["clips"] == 48 and clear["train_acc"] == 1.0
    noise = mlp_accuracy(train, test, _clips(manifest, 0.0), epochs=40)
    assert noise["acc"] < 0.6  # 3 classes: chance is 1/3, and it fits the training noise
    again = mlp_accuracy(train, test, _clips(manifest, 0.0), epochs=40)
    assert again == noise, "seeded"


@pytest.mark.render
def test_probe_command_writes_json_and_markdown(tiny_dataset, tmp_path):
    results = main([str(tiny_dataset), "--mesh-cache", str(tiny_dataset / "meshes"),
                    "--out", str(tmp_path), "--epochs", "2"])  # fmt: skip
    assert set(results) == set(FEATURES)
    stored = json.loads((tmp_path / f"{tiny_dataset.name}-mlp.json").read_text())
    assert stored["results"] == results and stored["protocol"] == "simulation"
    text = (tmp_path / f"{tiny_dataset.name}-mlp.md").read_text()
    assert "| geometry_shape |" in text
    assert "sqrt \\|grey frame difference\\|" in text  # pipes escaped inside the table
    with pytest.raises(SystemExit):
        main([str(tiny_dataset), "--epochs", "0"])


def test_per_clip_position_reads_the_position_that_carries_the_class():
    manifest = _manifest(sims_per_class=(6, 1, 4))
    train, test = manifest.clips_of("train"), manifest.clips_of("test")
    positions = sorted({int(c["clip_index"]) for c in manifest.clips})
    assert len(positions) > 1
    informative = positions[-1]
    rng = np.random.default_rng(0)
    code = {c: rng.normal(size=20) for c in (0, 7, 53)}
    features = {
        c["key"]: np.float32(3.0 * (int(c["clip_index"]) == informative) * code[c["class_id"]]
                             + rng.normal(size=20))
        for c in manifest.clips
    }  # fmt: skip
    results = by_clip_index(train, test, features, epochs=40)
    assert sorted(results) == positions
    assert results[informative]["acc"] == 1.0
    assert all(results[k]["acc"] < 0.8 for k in positions if k != informative)


def test_positions_table_lists_each_clip_start():
    result = {"clips": 4, "acc": 0.5, "stretch_acc": 0.75, "bend_acc": 0.5, "train_acc": 1.0}
    text = probe_markdown("d", "simulation", 2, {"geometry": result}, {0: result, 1: result},
                          {0: (0, 0.0), 1: (10, 10 / 15)})  # fmt: skip
    assert "| 1 | 10 | 0.67 | 4 | 50.0 | 75.0 | 50.0 | 100.0 |" in text
