"""MLP feature references: a known answer on synthetic features, and the command end to end."""

import json

import numpy as np
import pytest

from benchmarks.thesis.feature_probe import (
    FEATURES,
    by_clip_index,
    class_separation,
    main,
    mlp_accuracy,
    probe_markdown,
    run_probe,
)
from tests.datasets.test_split_protocol import _manifest


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
    results = main(
        [
            str(tiny_dataset),
            "--mesh-cache",
            str(tiny_dataset / "meshes"),
            "--out",
            str(tmp_path),
            "--epochs",
            "2",
        ]
    )
    assert set(results) == set(FEATURES)
    stored = json.loads((tmp_path / f"{tiny_dataset.name}-mlp.json").read_text())
    assert stored["results"] == results and stored["protocol"] == "simulation"
    text = (tmp_path / f"{tiny_dataset.name}-mlp.md").read_text()
    assert "| geometry_shape |" in text
    assert "sqrt \\|grey frame difference\\|" in text  # pipes escaped inside the table
    with pytest.raises(SystemExit):
        main([str(tiny_dataset), "--epochs", "0"])
    for bad in (["--features", "geometry,colour"], ["--features", "pixels", "--by-clip-index"]):
        with pytest.raises(SystemExit):
            main([str(tiny_dataset), *bad])
    with pytest.raises(ValueError, match="subset"):
        run_probe(tiny_dataset, tiny_dataset / "meshes", tmp_path, kinds=("colour",))


@pytest.mark.render
def test_geometry_only_probe_per_clip_position(tiny_dataset, tmp_path):
    results = main(
        [
            str(tiny_dataset),
            "--mesh-cache",
            str(tiny_dataset / "meshes"),
            "--out",
            str(tmp_path),
            "--epochs",
            "2",
            "--features",
            "geometry",
            "--by-clip-index",
        ]
    )
    assert set(results) == {"geometry"}
    stored = json.loads((tmp_path / f"{tiny_dataset.name}-mlp.json").read_text())
    positions = stored["geometry_by_clip_index"]
    assert positions and all(r["spread"] >= 0 and r["spacing"] > 0 for r in positions.values())
    assert "spread cm" in (tmp_path / f"{tiny_dataset.name}-mlp.md").read_text()


def test_per_clip_position_reads_the_position_that_carries_the_class():
    manifest = _manifest(sims_per_class=(6, 1, 4))
    train, test = manifest.clips_of("train"), manifest.clips_of("test")
    positions = sorted({int(c["clip_index"]) for c in manifest.clips})
    assert len(positions) > 1
    informative = positions[-1]
    rng = np.random.default_rng(0)
    code = {c: rng.normal(size=20) for c in (0, 7, 53)}
    features = {
        c["key"]: np.float32(
            3.0 * (int(c["clip_index"]) == informative) * code[c["class_id"]] + rng.normal(size=20)
        )
        for c in manifest.clips
    }
    results = by_clip_index(train, test, features, epochs=40)
    assert sorted(results) == positions
    assert results[informative]["acc"] == 1.0
    assert all(results[k]["acc"] < 0.8 for k in positions if k != informative)
    assert results[informative]["spacing"] > results[informative]["spread"]
    assert all(results[k]["spacing"] < results[k]["spread"] for k in positions if k != informative)


def test_class_separation_on_known_clouds():
    """Class c's clips lie at c * d + (+-a) on every coordinate: spread a, spacing d."""
    a, d = 0.25, 2.0
    records, features = [], {}
    for c in (0, 1, 2):
        for sign in (-1.0, 1.0):
            key = f"{c}{sign}"
            records.append({"key": key, "class_id": c})
            features[key] = np.full(6, c * d + sign * a, np.float32)
    result = class_separation(records, features)
    assert result["spread"] == pytest.approx(a)
    assert result["spacing"] == pytest.approx(d)
    with pytest.raises(ValueError, match="at least 2 classes"):
        class_separation(records[:2], features)


def test_positions_table_lists_each_clip_start():
    result = {"clips": 4, "acc": 0.5, "stretch_acc": 0.75, "bend_acc": 0.5, "train_acc": 1.0}
    position = {**result, "spread": 0.0052, "spacing": 0.0024}
    text = probe_markdown(
        "d",
        "simulation",
        2,
        {"geometry": result},
        {0: position, 1: position},
        {0: (0, 0.0), 1: (10, 10 / 15)},
    )
    assert "| 1 | 10 | 0.67 | 4 | 50.0 | 75.0 | 50.0 | 100.0 | 0.52 | 0.24 |" in text
