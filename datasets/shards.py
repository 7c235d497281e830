"""Shards: WebDataset-style tar files of PNG frames plus JSON metadata, and their checksums.

Why this format: a tar shard is one sequential file per work unit, the layout WebDataset,
torchdata and plain ``tar`` all read; PNG is lossless (the round trip is exact, and the
``compression`` visual effect stays a deliberate switch instead of a storage artefact) and
every frame can be opened with any image viewer. A clip with key ``k`` is stored as
``k.json`` (its manifest record), ``k.00.png`` ... ``k.09.png`` and, when the renderer's
coverage was kept, ``k.coverage.png``: the cloth's alpha of every frame, grey, the frames
stacked top to bottom (T * H, W), from which training can re-composite the cloth over other
backgrounds. WebDataset groups the files of a sample by the part of the name before the
first dot.

Shards are built in memory and written atomically (temporary file, fsync, rename) with
fixed tar headers (mtime 0, uid 0), so the same clips give the same bytes and a killed
writer never leaves a partial shard under the final name.
"""

from __future__ import annotations

import hashlib
import io
import json
import tarfile
from collections.abc import Iterable
from pathlib import Path

import cv2
import numpy as np

from simulator.sequence import atomic_write_bytes

__all__ = [
    "ShardError",
    "ShardReader",
    "decode_coverage",
    "decode_frames",
    "encode_coverage",
    "encode_frames",
    "file_sha256",
    "frames_sha256",
    "verify_shard",
    "write_shard",
]

_PNG_PARAMS = [cv2.IMWRITE_PNG_COMPRESSION, 3]


class ShardError(RuntimeError):
    """A shard is missing, corrupted, or does not hold what the manifest says."""


def frames_sha256(frames: np.ndarray) -> str:
    """Checksum of a clip's decoded pixels (uint8, shape (T, H, W, 3))."""
    frames = np.ascontiguousarray(frames, dtype=np.uint8)
    head = f"{frames.shape}".encode()
    return hashlib.sha256(head + frames.tobytes()).hexdigest()


def file_sha256(path: str | Path) -> str:
    """SHA-256 of a file's bytes."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def encode_frames(frames: np.ndarray) -> list[bytes]:
    """PNG bytes of each RGB frame of a uint8 clip (T, H, W, 3)."""
    frames = np.asarray(frames)
    if frames.dtype != np.uint8 or frames.ndim != 4 or frames.shape[-1] != 3:
        raise ValueError(f"frames must be uint8 (T, H, W, 3), got {frames.dtype} {frames.shape}")
    out = []
    for frame in frames:
        ok, data = cv2.imencode(".png", np.ascontiguousarray(frame[..., ::-1]), _PNG_PARAMS)
        if not ok:
            raise RuntimeError("PNG encoding failed")
        out.append(data.tobytes())
    return out


def decode_frames(pngs: Iterable[bytes]) -> np.ndarray:
    """Inverse of :func:`encode_frames`: uint8 RGB clip (T, H, W, 3)."""
    frames = []
    for data in pngs:
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
        if image is None:
            raise ShardError("a PNG frame could not be decoded")
        frames.append(image[..., ::-1])
    return np.ascontiguousarray(np.stack(frames))


def encode_coverage(coverage: np.ndarray) -> bytes:
    """One grey PNG of a clip's coverage (uint8 (T, H, W)), frames stacked top to bottom."""
    coverage = np.asarray(coverage)
    if coverage.dtype != np.uint8 or coverage.ndim != 3:
        raise ValueError(
            f"coverage must be uint8 (T, H, W), got {coverage.dtype} {coverage.shape}"
        )
    ok, data = cv2.imencode(
        ".png", np.ascontiguousarray(coverage.reshape(-1, coverage.shape[-1])), _PNG_PARAMS
    )
    if not ok:
        raise RuntimeError("PNG encoding failed")
    return data.tobytes()


def decode_coverage(data: bytes, frame_count: int) -> np.ndarray:
    """Inverse of :func:`encode_coverage`: uint8 (T, H, W)."""
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE)
    if image is None or image.shape[0] % frame_count:
        raise ShardError(f"a coverage PNG could not be decoded into {frame_count} frames")
    return image.reshape(frame_count, -1, image.shape[1])


def _tar_member(tar: tarfile.TarFile, name: str, data: bytes) -> None:
    info = tarfile.TarInfo(name)
    info.size = len(data)
    info.mtime = 0
    info.mode = 0o644
    info.uid = info.gid = 0
    info.uname = info.gname = ""
    tar.addfile(info, io.BytesIO(data))


def write_shard(path: str | Path, samples: Iterable[tuple]) -> dict:
    """Write clips as one tar shard, atomically.

    Each sample is ``(key, record, frames)`` or ``(key, record, frames, coverage)`` with
    ``coverage`` uint8 (T, H, W) or ``None``.

    Returns:
        ``{"bytes": size, "sha256": checksum, "clips": count}`` of the written file.
    """
    buffer = io.BytesIO()
    count = 0
    with tarfile.open(fileobj=buffer, mode="w", format=tarfile.USTAR_FORMAT) as tar:
        for key, record, frames, *rest in samples:
            if "." in key or "/" in key:
                raise ValueError(f"clip key must not contain '.' or '/', got {key!r}")
            coverage = rest[0] if rest else None
            if coverage is not None and np.shape(coverage) != np.shape(frames)[:3]:
                raise ValueError(
                    f"coverage of clip {key!r} must have shape {np.shape(frames)[:3]}, "
                    f"got {np.shape(coverage)}"
                )
            meta = json.dumps(record, sort_keys=True).encode()
            _tar_member(tar, f"{key}.json", meta)
            for t, png in enumerate(encode_frames(frames)):
                _tar_member(tar, f"{key}.{t:02d}.png", png)
            if coverage is not None:
                _tar_member(tar, f"{key}.coverage.png", encode_coverage(coverage))
            count += 1
    data = buffer.getvalue()
    atomic_write_bytes(path, data)
    return {"bytes": len(data), "sha256": hashlib.sha256(data).hexdigest(), "clips": count}


def verify_shard(path: str | Path, sha256: str, size: int | None = None) -> None:
    """Raise :class:`ShardError` naming ``path`` if it is missing or its bytes changed."""
    path = Path(path)
    if not path.is_file():
        raise ShardError(f"shard missing: {path} (listed in the manifest; regenerate it)")
    if size is not None and path.stat().st_size != size:
        raise ShardError(
            f"shard corrupted: {path} has {path.stat().st_size} bytes, the manifest says {size}"
        )
    actual = file_sha256(path)
    if actual != sha256:
        raise ShardError(
            f"shard corrupted: {path} sha256 {actual[:12]}... != manifest {sha256[:12]}..."
        )


class ShardReader:
    """Random access to the clips of one shard (opened lazily, so it survives fork)."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self._members: dict[str, tuple[int, int]] | None = None

    def _index(self) -> dict[str, tuple[int, int]]:
        if self._members is None:
            if not self.path.is_file():
                raise ShardError(f"shard missing: {self.path}")
            try:
                with tarfile.open(self.path, mode="r:") as tar:
                    self._members = {m.name: (m.offset_data, m.size) for m in tar.getmembers()}
            except tarfile.TarError as err:
                raise ShardError(
                    f"shard corrupted: {self.path} is not a readable tar ({err})"
                ) from err
        return self._members

    def keys(self) -> list[str]:
        """Clip keys in the shard, in stored order."""
        return [name[: -len(".json")] for name in self._index() if name.endswith(".json")]

    def _read(self, handle, name: str) -> bytes:
        try:
            offset, size = self._index()[name]
        except KeyError:
            raise ShardError(f"shard {self.path} has no member {name!r}") from None
        handle.seek(offset)
        data = handle.read(size)
        if len(data) != size:
            raise ShardError(f"shard corrupted: {self.path} is truncated in {name!r}")
        return data

    def read(self, key: str) -> tuple[dict, np.ndarray]:
        """The clip's record and frames (uint8, (T, H, W, 3))."""
        index = self._index()
        with open(self.path, "rb") as handle:
            record = json.loads(self._read(handle, f"{key}.json"))
            count = int(record["frame_count"])
            names = [f"{key}.{t:02d}.png" for t in range(count)]
            missing = [n for n in names if n not in index]
            if missing:
                raise ShardError(f"shard {self.path} lacks frames {missing[:3]} of clip {key!r}")
            frames = decode_frames(self._read(handle, n) for n in names)
        return record, frames

    def read_coverage(self, key: str, frame_count: int) -> np.ndarray | None:
        """The clip's coverage (uint8 (T, H, W)), or ``None`` if the shard has none."""
        name = f"{key}.coverage.png"
        if name not in self._index():
            return None
        with open(self.path, "rb") as handle:
            return decode_coverage(self._read(handle, name), frame_count)
