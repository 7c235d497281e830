"""End-to-end generation: content, determinism, resume after interruption, verification."""

import json
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from datasets.clip_dataset import ClothClipDataset
from datasets.generation import generate_dataset
from datasets.manifest import Manifest
from datasets.shards import ShardError
from render.effects import VisualEffects
from simulator.sequence import MeshSequence
from tests.conftest import subprocess_env

from .conftest import tiny_spec

pytestmark = pytest.mark.render


def _tree_bytes(root: Path) -> dict[str, bytes]:
    files = [*sorted((root / "shards").glob("*.tar")), *sorted((root / "units").glob("*.json"))]
    files += [root / "manifest.json", root / "manifest.csv", root / "spec.json"]
    return {str(p.relative_to(root)): p.read_bytes() for p in files}


def test_manifest_lists_every_clip_with_labels_and_physics(tiny_dataset):
    manifest = Manifest.load(tiny_dataset)
    assert len(manifest.clips) == 6
    assert {c["class_id"] for c in manifest.clips} == {0, 53}
    for clip in manifest.clips:
        assert clip["shard"].startswith(clip["split"] + "-")
        assert clip["frame_count"] == 4 and (clip["height"], clip["width"]) == (32, 32)
        assert clip["stretch_stiffness"] > 0 and clip["bend_stiffness"] > 0
        assert clip["density"] > 0 and clip["motion"] == "wind"
        assert clip["resolution_level"] == 1 and clip["texture_mode"] == "random"
    stiff = next(c for c in manifest.clips if c["class_id"] == 53)
    soft = next(c for c in manifest.clips if c["class_id"] == 0)
    assert stiff["stretch_stiffness"] == pytest.approx(40 * soft["stretch_stiffness"])
    assert stiff["bend_stiffness"] == pytest.approx(40 * soft["bend_stiffness"])
    sims = {}
    for clip in manifest.clips:
        sims.setdefault(clip["sim_id"], set()).add(clip["split"])
    assert all(len(splits) == 1 for splits in sims.values()), "a simulation spans two splits"
    manifest.verify()


def test_clips_show_a_moving_cloth_over_the_background(tiny_dataset):
    data = ClothClipDataset(tiny_dataset, None, check_clips=True)
    for i in range(len(data)):
        sample = data[i]
        video = sample["video"]
        assert video.shape == (4, 3, 32, 32)
        assert 0.0 <= float(video.min()) and float(video.max()) <= 1.0
        motion = (video[1:] - video[:-1]).abs().mean()
        assert motion > 1e-3, f"clip {sample['key']} does not move"


def test_generation_is_deterministic_and_resumes_after_a_partial_run(tmp_path, tiny_dataset):
    spec = tiny_spec()
    partial = tmp_path / "partial"
    assert generate_dataset(spec, partial, max_units=1, progress=False) is None
    assert len(list((partial / "units").glob("*.json"))) == 1
    assert not Manifest.path(partial).exists(), "an unfinished dataset must have no manifest"
    # Simulate a writer killed mid-shard: a stray temporary file and a half-written shard
    # of a unit whose index was never written.
    (partial / "shards" / ".train-unit-0001.tar.abc.tmp").write_bytes(b"half")
    (partial / "shards" / "train-unit-0001.tar").write_bytes(b"truncated tar")
    assert generate_dataset(spec, partial, progress=False) is not None
    assert not list((partial / "shards").glob(".*.tmp"))
    assert _tree_bytes(partial) == _tree_bytes(tiny_dataset)


def test_rerun_skips_finished_units_and_regenerates_a_corrupted_one(tmp_path, tiny_dataset):
    root = tmp_path / "copy"
    shutil.copytree(tiny_dataset, root)
    shard = sorted((root / "shards").glob("*.tar"))[0]
    shard.write_bytes(shard.read_bytes()[:-100])
    untouched = sorted((root / "shards").glob("*.tar"))[-1]
    before = untouched.stat().st_mtime_ns
    assert generate_dataset(tiny_spec(), root, progress=False) is not None
    assert untouched.stat().st_mtime_ns == before, "a finished unit was regenerated"
    assert _tree_bytes(root) == _tree_bytes(tiny_dataset)


def test_killed_process_resumes_to_the_uninterrupted_result(tmp_path, tiny_dataset):
    root = tmp_path / "killed"
    code = (
        "from tests.datasets.conftest import tiny_spec\n"
        "from datasets.generation import generate_dataset\n"
        f"generate_dataset(tiny_spec(), {str(root)!r}, progress=False)\n"
    )
    proc = subprocess.Popen([sys.executable, "-c", code], env=subprocess_env())
    deadline = time.monotonic() + 240
    while not (root / "units" / "unit-0000.json").exists():
        assert proc.poll() is None, "generation ended before it could be killed"
        assert time.monotonic() < deadline, "first unit took too long"
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert not Manifest.path(root).exists()
    assert generate_dataset(tiny_spec(), root, progress=False) is not None
    assert _tree_bytes(root) == _tree_bytes(tiny_dataset)


def test_missing_or_corrupted_shard_is_reported_by_name(tmp_path, tiny_dataset):
    root = tmp_path / "broken"
    shutil.copytree(tiny_dataset, root)
    manifest = Manifest.load(root)
    first = manifest.shard_path(manifest.shards[0]["name"])
    data = bytearray(first.read_bytes())
    data[600] ^= 0x01
    first.write_bytes(bytes(data))
    with pytest.raises(ShardError, match=f"corrupted: .*{first.name}"):
        ClothClipDataset(root, None)
    first.unlink()
    with pytest.raises(ShardError, match=f"missing: .*{first.name}"):
        ClothClipDataset(root, None)


def test_out_dir_of_another_config_is_refused(tmp_path, tiny_dataset):
    root = tmp_path / "other"
    shutil.copytree(tiny_dataset, root)
    with pytest.raises(ValueError, match="different config"):
        generate_dataset(tiny_spec(texture_mode="grid"), root, progress=False)


def test_rendering_only_variant_reuses_the_mesh_cache(tmp_path, tiny_dataset):
    cache = tmp_path / "cache"
    first = generate_dataset(tiny_spec(), tmp_path / "a", mesh_cache=cache, progress=False)
    cached = sorted(cache.rglob("*.npz"))
    stamps = [p.stat().st_mtime_ns for p in cached]
    grid = generate_dataset(
        tiny_spec(texture_mode="grid"), tmp_path / "b", mesh_cache=cache, progress=False
    )
    assert [p.stat().st_mtime_ns for p in sorted(cache.rglob("*.npz"))] == stamps
    assert first is not None and grid is not None
    assert json.loads((tmp_path / "b" / "spec.json").read_text())["spec"]["texture_mode"] == "grid"
    a = ClothClipDataset(tmp_path / "a", None).read(0)[1]
    b = ClothClipDataset(tmp_path / "b", None).read(0)[1]
    assert not np.array_equal(a, b)


def test_a_slower_camera_records_longer_and_the_cache_serves_the_shorter_prefix(
    tmp_path, tiny_dataset
):
    cache = tmp_path / "cache"
    slow_spec = tiny_spec(visual=VisualEffects(frame_rate=True, frame_rate_ratio=0.5))
    assert slow_spec.frames_per_sim == tiny_spec().lead_in_frames + 7  # 4 frames at half rate
    slow = generate_dataset(slow_spec, tmp_path / "slow", mesh_cache=cache, progress=False)
    assert slow is not None
    (recording,) = {MeshSequence.load(p).frame_count for p in cache.rglob("*.npz")}
    assert recording == slow_spec.frames_per_sim
    stamps = [p.stat().st_mtime_ns for p in sorted(cache.rglob("*.npz"))]
    nominal = generate_dataset(tiny_spec(), tmp_path / "nominal", mesh_cache=cache, progress=False)
    assert nominal is not None  # served from the longer recording: nothing re-simulated
    assert [p.stat().st_mtime_ns for p in sorted(cache.rglob("*.npz"))] == stamps
    assert _tree_bytes(tmp_path / "nominal") == _tree_bytes(tiny_dataset)
    # Output frame j of the half-rate camera shows recorded frame 2 j: its clip is 4 frames
    # long and spans twice the time of the nominal clip.
    slow_clip = ClothClipDataset(tmp_path / "slow", None).read(0)[1]
    nominal_clip = ClothClipDataset(tiny_dataset, None).read(0)[1]
    assert slow_clip.shape == nominal_clip.shape
    np.testing.assert_array_equal(slow_clip[:2], nominal_clip[::2])


def test_cluster_workers_split_the_units_and_the_last_writes_the_manifest(tmp_path, tiny_dataset):
    root = tmp_path / "sharded"
    first = generate_dataset(tiny_spec(), root, worker_index=0, worker_count=2, progress=False)
    assert first is None, "worker 0 alone cannot finish the dataset"
    assert sorted(p.name for p in (root / "units").glob("*.json")) == [
        "unit-0000.json",
        "unit-0002.json",
    ]
    second = generate_dataset(tiny_spec(), root, worker_index=1, worker_count=2, progress=False)
    assert second is not None
    assert _tree_bytes(root) == _tree_bytes(tiny_dataset)


def test_each_split_verifies_its_own_shards(tmp_path, tiny_dataset):
    root = tmp_path / "split-check"
    shutil.copytree(tiny_dataset, root)
    train = next((root / "shards").glob("train-*.tar"))
    train.write_bytes(train.read_bytes()[:-10])
    assert len(ClothClipDataset(root, "test")) == 2
    with pytest.raises(ShardError, match=train.name):
        ClothClipDataset(root, "train")
