"""Shard round trip and the detection of missing or corrupted shards."""

import numpy as np
import pytest

from datasets.shards import (
    ShardError,
    ShardReader,
    decode_frames,
    decode_stack,
    encode_frames,
    encode_stack,
    frames_sha256,
    verify_shard,
    write_shard,
)


def _clip(seed: int, frames: int = 3, size: int = 20) -> np.ndarray:
    return np.random.default_rng(seed).integers(
        0, 256, size=(frames, size, size + 3, 3), dtype=np.uint8
    )


def test_png_round_trip_is_exact():
    clip = _clip(0)
    assert np.array_equal(decode_frames(encode_frames(clip)), clip)


def test_shard_round_trip_is_exact_and_deterministic(tmp_path):
    clips = {f"clip-{i}": _clip(i) for i in range(3)}
    samples = [(k, {"frame_count": len(v), "key": k}, v) for k, v in clips.items()]
    info = write_shard(tmp_path / "a.tar", samples)
    again = write_shard(tmp_path / "b.tar", samples)
    assert info == again, "same clips must give the same shard bytes"
    assert (tmp_path / "a.tar").read_bytes() == (tmp_path / "b.tar").read_bytes()
    reader = ShardReader(tmp_path / "a.tar")
    assert reader.keys() == list(clips)
    for key, clip in clips.items():
        record, frames = reader.read(key)
        assert record == {"frame_count": 3, "key": key}
        assert np.array_equal(frames, clip)
        assert frames_sha256(frames) == frames_sha256(clip)
    verify_shard(tmp_path / "a.tar", info["sha256"], info["bytes"])


def test_corrupted_and_missing_shards_are_named(tmp_path):
    path = tmp_path / "train-unit-0000.tar"
    info = write_shard(path, [("k", {"frame_count": 2}, _clip(1, frames=2))])
    data = bytearray(path.read_bytes())
    data[700] ^= 0xFF
    path.write_bytes(bytes(data))
    with pytest.raises(ShardError, match=r"corrupted: .*train-unit-0000\.tar"):
        verify_shard(path, info["sha256"], info["bytes"])
    path.write_bytes(bytes(data[:1000]))
    with pytest.raises(ShardError, match=r"corrupted: .*train-unit-0000\.tar"):
        verify_shard(path, info["sha256"], info["bytes"])
    path.unlink()
    with pytest.raises(ShardError, match=r"missing: .*train-unit-0000\.tar"):
        verify_shard(path, info["sha256"], info["bytes"])


def test_bad_keys_and_frames_are_refused(tmp_path):
    with pytest.raises(ValueError, match="key"):
        write_shard(tmp_path / "x.tar", [("a.b", {"frame_count": 1}, _clip(0, 1))])
    with pytest.raises(ValueError, match="uint8"):
        encode_frames(np.zeros((1, 4, 4, 3), np.float32))
    assert not (tmp_path / "x.tar").exists()


def test_coverage_round_trips_and_is_optional_per_clip(tmp_path):
    clip = _clip(3)
    cover = np.random.default_rng(4).integers(0, 256, size=clip.shape[:3], dtype=np.uint8)
    assert np.array_equal(decode_stack(encode_stack(cover), len(cover)), cover)
    samples = [("with", {"frame_count": 3}, clip, cover), ("without", {"frame_count": 3}, clip)]
    write_shard(tmp_path / "a.tar", samples)
    reader = ShardReader(tmp_path / "a.tar")
    assert reader.keys() == ["with", "without"]
    assert np.array_equal(reader.read_coverage("with", 3), cover)
    assert reader.read_coverage("without", 3) is None
    assert np.array_equal(reader.read("with")[1], clip)
    with pytest.raises(ValueError, match="coverage of clip 'bad'"):
        write_shard(tmp_path / "b.tar", [("bad", {"frame_count": 3}, clip, cover[:2])])
    with pytest.raises(ValueError, match="layer must be uint8"):
        encode_stack(cover.astype(np.float32))


def test_rgb_layers_round_trip_beside_coverage(tmp_path):
    clip = _clip(2, frames=2)
    rng = np.random.default_rng(5)
    cover = rng.integers(0, 256, size=clip.shape[:3], dtype=np.uint8)
    white = rng.integers(0, 256, size=clip.shape, dtype=np.uint8)
    background = rng.integers(0, 256, size=(1, *clip.shape[1:]), dtype=np.uint8)
    layers = {"white": white, "background": background}
    write_shard(tmp_path / "a.tar", [("c", {"frame_count": 2}, clip, cover, layers)])
    reader = ShardReader(tmp_path / "a.tar")
    assert np.array_equal(reader.read_layer("c", "white", 2), white)  # RGB order kept
    assert np.array_equal(reader.read_layer("c", "background", 1), background)
    assert np.array_equal(reader.read_coverage("c", 2), cover)
    assert reader.read_layer("c", "uvm", 2) is None
    assert np.array_equal(reader.read("c")[1], clip)
    with pytest.raises(ValueError, match="layer 'white' of clip 'd'"):
        write_shard(
            tmp_path / "b.tar", [("d", {"frame_count": 2}, clip, None, {"white": white[:, :3]})]
        )
    with pytest.raises(ValueError, match="layer name"):
        write_shard(tmp_path / "b.tar", [("d", {"frame_count": 2}, clip, None, {"00": white})])
    assert not (tmp_path / "b.tar").exists()
