"""Shards: WebDataset-style tar files of PNG frames plus JSON metadata, and their checksums.

Why this format: a tar shard is one sequential file per work unit, the layout WebDataset,
torchdata and plain ``tar`` all read; PNG is lossless (the round trip is exact, and the
``compression`` visual effect stays a deliberate switch instead of a storage artefact) and
every frame can be opened with any image viewer. A clip with key ``k`` is stored as
``k.json`` (its manifest record), ``k.00.png`` ... ``k.09.png`` and optional *layers*, one
PNG each with the frames stacked top to bottom (T * H, W[, 3]): ``k.coverage.png``, the
cloth's alpha of every frame (grey), from which training can re-composite the cloth over
other backgrounds; with render passes (``render.store_passes``) ``k.grey.png``,
``k.black.png``, ``k.uvm.png`` (:mod:`render.passes`) and ``k.background.png`` (one image),
from which training can re-texture the cloth. WebDataset groups the files of a sample by the
part of the name before the first dot.

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

from common.errors import user_error
from common.files import atomic_write_bytes

__all__ = [
    "ShardError",
    "ShardReader",
    "decode_frames",
    "decode_stack",
    "encode_frames",
    "encode_stack",
    "file_sha256",
    "frames_sha256",
    "verify_shard",
    "write_shard",
]

_PNG_PARAMS = [cv2.IMWRITE_PNG_COMPRESSION, 3]


@user_error
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


def encode_stack(images: np.ndarray) -> bytes:
    """One PNG of N grey (N, H, W) or RGB (N, H, W, 3) uint8 images, stacked top to bottom."""
    images = np.asarray(images)
    rgb = images.ndim == 4 and images.shape[-1] == 3
    if images.dtype != np.uint8 or not (images.ndim == 3 or rgb):
        raise ValueError(
            f"a layer must be uint8 (N, H, W) or (N, H, W, 3), got {images.dtype} {images.shape}"
        )
    stacked = images.reshape(-1, *images.shape[2:])
    ok, data = cv2.imencode(
        ".png", np.ascontiguousarray(stacked[..., ::-1] if rgb else stacked), _PNG_PARAMS
    )
    if not ok:
        raise RuntimeError("PNG encoding failed")
    return data.tobytes()


def decode_stack(data: bytes, count: int) -> np.ndarray:
    """Inverse of :func:`encode_stack`: uint8 (count, H, W) or (count, H, W, 3)."""
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None or image.shape[0] % count:
        raise ShardError(f"a layer PNG could not be decoded into {count} images")
    if image.ndim == 3:
        image = image[..., ::-1]
    return np.ascontiguousarray(image.reshape(count, -1, *image.shape[1:]))


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

    Each sample is ``(key, record, frames)``, ``(key, record, frames, coverage)`` or
    ``(key, record, frames, coverage, layers)``: ``coverage`` uint8 (T, H, W) or ``None``,
    ``layers`` ``{name: uint8 (N, H, W[, 3])}`` (stored as ``key.name.png``) or ``None``.

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
            layers = dict(rest[1] or {}) if len(rest) > 1 else {}
            if coverage is not None:
                if np.shape(coverage) != np.shape(frames)[:3]:
                    raise ValueError(
                        f"coverage of clip {key!r} must have shape {np.shape(frames)[:3]}, "
                        f"got {np.shape(coverage)}"
                    )
                layers = {"coverage": coverage, **layers}
            for name, layer in layers.items():
                if not name.isidentifier() or name.isdigit():
                    raise ValueError(f"layer name must be an identifier, got {name!r}")
                shape = np.shape(layer)
                if shape[1:3] != np.shape(frames)[1:3] or shape[0] not in (1, len(frames)):
                    raise ValueError(
                        f"layer {name!r} of clip {key!r} must be 1 or {len(frames)} images of "
                        f"{np.shape(frames)[1:3]}, got shape {shape}"
                    )
            meta = json.dumps(record, sort_keys=True).encode()
            _tar_member(tar, f"{key}.json", meta)
            for t, png in enumerate(encode_frames(frames)):
                _tar_member(tar, f"{key}.{t:02d}.png", png)
            for name, layer in layers.items():
                _tar_member(tar, f"{key}.{name}.png", encode_stack(layer))
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

    def read_layer(self, key: str, name: str, count: int) -> np.ndarray | None:
        """The clip's layer ``name`` as ``count`` images, or ``None`` if the shard has none."""
        member = f"{key}.{name}.png"
        if member not in self._index():
            return None
        with open(self.path, "rb") as handle:
            return decode_stack(self._read(handle, member), count)

    def read_coverage(self, key: str, frame_count: int) -> np.ndarray | None:
        """The clip's coverage (uint8 (T, H, W)), or ``None`` if the shard has none."""
        return self.read_layer(key, "coverage", frame_count)
