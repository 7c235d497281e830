"""Split protocols (held-out simulations vs the thesis's sub-sequences) and the geometry oracle."""

import json
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from benchmarks.thesis.geometry_oracle import (
    clip_geometry,
    clip_motion,
    clip_pixels,
    oracle_accuracy,
    run_oracle,
)
from datasets.clip_dataset import ClothClipDataset
from datasets.datamodule import ClothVideoDataModule
from datasets.manifest import Manifest

SPLITS = ("train", "val", "test")


def _manifest(sims_per_class=(3, 1, 2), clips_per_sim=4, classes=(0, 7, 53)) -> Manifest:
    """Synthetic manifest: per class, sims in train/val/test, several clips each."""
    clips = []
    for class_id in classes:
        s = 0
        for split, count in zip(SPLITS, sims_per_class, strict=True):
            for _ in range(count):
                for k in range(clips_per_sim):
                    key = f"wind-c{class_id:02d}-s{s:02d}-k{k:02d}"
                    clips.append(
                        {
                            "key": key,
                            "class_id": class_id,
                            "split": split,
                            "stretch_index": class_id // 9,
                            "bend_index": class_id % 9,
                            "sim_id": f"c{class_id:02d}-s{s:02d}",
                            "clip_index": k,
                            "shard": f"{split}-unit-0000.tar",
                        }
                    )
                s += 1
    return Manifest(root=Path("."), spec={}, spec_key="", shards=(), clips=tuple(clips))


def _sims(clips) -> set[str]:
    return {c["sim_id"] for c in clips}


def test_simulation_protocol_holds_out_whole_simulations():
    manifest = _manifest()
    train, test = manifest.clips_of("train"), manifest.clips_of("test")
    assert not _sims(train) & _sims(test)
    assert manifest.clips_of("test", "simulation") == test


def test_sequence_protocol_keeps_split_sizes_per_class_and_shares_simulations():
    manifest = _manifest()
    dealt = {split: manifest.clips_of(split, "sequence") for split in SPLITS}
    for split in SPLITS:
        before = Counter(c["class_id"] for c in manifest.clips_of(split))
        assert Counter(c["class_id"] for c in dealt[split]) == before
        assert all(c["split"] == split for c in dealt[split])
    keys = [c["key"] for split in SPLITS for c in dealt[split]]
    assert sorted(keys) == sorted(c["key"] for c in manifest.clips), "every clip exactly once"
    assert _sims(dealt["train"]) & _sims(dealt["test"]), "the thesis split mixes simulations"
    assert manifest.clips_of("test", "sequence") == dealt["test"], "the deal is deterministic"
    shuffled = Manifest(Path("."), {}, "", (), tuple(reversed(manifest.clips)))
    assert shuffled.clips_of("test", "sequence") == dealt["test"], "independent of file order"


def test_unknown_split_protocol_is_named():
    with pytest.raises(ValueError, match="split_protocol must be one of"):
        _manifest().clips_of("test", "by_frame")
    with pytest.raises(ValueError, match="split_protocol must be one of"):
        ClothVideoDataModule(".", split_protocol="by_frame")


def test_sequence_protocol_reads_clips_from_the_shards_they_live_in(tiny_dataset):
    test = ClothClipDataset(tiny_dataset, "test", split_protocol="sequence")
    train = ClothClipDataset(tiny_dataset, "train", split_protocol="sequence")
    assert len(test) == len(ClothClipDataset(tiny_dataset, "test"))
    moved = [r for r in test.records if not r["shard"].startswith("test-")]
    assert moved, "some test clips come from simulations generated as training ones"
    assert test[0]["video"].shape[0] == 4 and len(train) + len(test) > 0


def test_geometry_oracle_finds_the_class_whose_shape_is_nearest():
    manifest = _manifest()
    rng = np.random.default_rng(0)
    # Shape = class offset + small per-clip noise: every test clip's neighbour is its class.
    geometry = {
        c["key"]: np.float32(c["class_id"] + 0.01 * rng.normal(size=30)) for c in manifest.clips
    }
    result = oracle_accuracy(manifest.clips_of("train"), manifest.clips_of("test"), geometry)
    assert result == {
        "clips": 24,
        "acc": 1.0,
        "stretch_acc": 1.0,
        "bend_acc": 1.0,
        "same_simulation": 0.0,
    }
    itself = oracle_accuracy(manifest.clips_of("test"), manifest.clips_of("test"), geometry)
    assert itself["same_simulation"] == 1.0


def test_geometry_oracle_reads_the_dataset_meshes(tiny_dataset, tmp_path):
    manifest = Manifest.load(tiny_dataset)
    geometry = clip_geometry(manifest, tiny_dataset / "meshes")
    assert sorted(geometry) == sorted(c["key"] for c in manifest.clips)
    sizes = {g.shape for g in geometry.values()}
    assert sizes == {(4 * 256 * 3,)}, "4 frames x 256 vertices x 3"
    assert all(np.all(g[:3] == 0) for g in geometry.values()), "relative to the first vertex"
    pixels = clip_pixels(manifest)
    assert {p.shape for p in pixels.values()} == {(3 * 32 * 32,)}
    assert all(0 <= p.min() and p.max() <= 1 for p in pixels.values())
    motion = clip_motion(manifest)
    assert {m.shape for m in motion.values()} == {(3 * 16 * 16,)}, "3 differences of 4 frames"
    assert all(0 <= m.min() and m.max() <= 1 for m in motion.values())
    assert any(m.max() > 0 for m in motion.values()), "the cloth moves"
    results = run_oracle(tiny_dataset, tiny_dataset / "meshes", tmp_path)
    stored = json.loads((tmp_path / f"{tiny_dataset.name}.json").read_text())
    assert stored["results"] == results and set(results) == {"geometry", "pixels", "motion"}
    assert all(set(v) == {"simulation", "sequence"} for v in results.values())
    assert results["geometry"]["simulation"]["same_simulation"] == 0.0
    assert "| pixels | sequence |" in (tmp_path / f"{tiny_dataset.name}.md").read_text()


def test_geometry_oracle_names_a_missing_mesh_cache(tiny_dataset, tmp_path):
    with pytest.raises(FileNotFoundError, match=r"mesh cache .*unit-0000\.npz not found"):
        clip_geometry(Manifest.load(tiny_dataset), tmp_path)
