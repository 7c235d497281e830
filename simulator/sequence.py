"""Mesh sequences: the simulator's output, one documented file format and exporters.

File format (``.npz``, written atomically, never containing NaN):

* ``pos`` float32 (B, K, V, 3): vertex positions [m] per instance and frame;
* ``tri_indices`` int64 (F, 3); ``uv`` float32 (V, 2): material coordinates [m];
* ``fps`` float64 scalar; ``seeds``, ``labels`` (class id, -1 if none), ``wind_levels`` int64 (B,);
* ``capsules`` float32 (B, K, C, 7), only for scenes with kinematic obstacles (the arm): the
  capsules ``[p0 (3), p1 (3), radius]`` [m] at every recorded frame, so a renderer draws what
  was simulated without rebuilding the scene;
* ``meta_json``: UTF-8 JSON with the scene, scenario parameters, effects, solver
  settings and per-instance material values (``schema_version`` inside).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from common.errors import InputError
from common.files import atomic_write_bytes

__all__ = ["SCHEMA_VERSION", "MeshSequence"]

SCHEMA_VERSION = 1


@dataclasses.dataclass(frozen=True)
class MeshSequence:
    """Recorded frames of B simulated cloth instances."""

    pos: np.ndarray
    """Vertex positions [m], float32, shape (B, K, V, 3)."""
    tri_indices: np.ndarray
    """Triangles, int64, shape (F, 3)."""
    uv: np.ndarray
    """Material coordinates [m], float32, shape (V, 2)."""
    fps: float
    seeds: list[int]
    labels: list[int]
    wind_levels: list[int]
    meta: dict
    capsules: np.ndarray | None = None
    """Kinematic obstacles per frame ``[p0, p1, radius]`` [m], float32, shape (B, K, C, 7);
    ``None`` for scenes without any."""

    @property
    def frame_count(self) -> int:
        """K."""
        return int(self.pos.shape[1])

    def first_frames(self, count: int) -> MeshSequence:
        """The first ``count`` frames.

        Stepping is causal, so a longer recording of a simulation starts with the shorter
        one's frames: the mesh cache serves a short request from a long recording.
        """
        if not 1 <= count <= self.frame_count:
            raise ValueError(f"count must be in [1, {self.frame_count}], got {count}")
        capsules = None if self.capsules is None else self.capsules[:, :count]
        return dataclasses.replace(self, pos=self.pos[:, :count], capsules=capsules)

    def save(self, path: str | Path) -> Path:
        """Write the ``.npz`` atomically; refuses non-finite positions."""
        if not np.isfinite(self.pos).all():
            raise ValueError("MeshSequence.pos contains NaN/inf; refusing to write it")
        extra = {}
        if self.capsules is not None:
            if self.capsules.shape[:2] != self.pos.shape[:2] or self.capsules.shape[-1] != 7:
                raise ValueError(
                    f"MeshSequence.capsules must have shape (B, K, C, 7) = "
                    f"{(*self.pos.shape[:2], 'C', 7)}, got {self.capsules.shape}"
                )
            if not np.isfinite(self.capsules).all():
                raise ValueError("MeshSequence.capsules contains NaN/inf; refusing to write it")
            extra["capsules"] = self.capsules.astype(np.float32)
        import io

        buffer = io.BytesIO()
        meta = dict(self.meta, schema_version=SCHEMA_VERSION)
        np.savez_compressed(
            buffer,
            pos=self.pos.astype(np.float32),
            tri_indices=self.tri_indices.astype(np.int64),
            uv=self.uv.astype(np.float32),
            fps=np.float64(self.fps),
            seeds=np.asarray(self.seeds, dtype=np.int64),
            labels=np.asarray(self.labels, dtype=np.int64),
            wind_levels=np.asarray(self.wind_levels, dtype=np.int64),
            meta_json=np.frombuffer(json.dumps(meta, sort_keys=True).encode(), dtype=np.uint8),
            **extra,
        )
        path = Path(path)
        atomic_write_bytes(path, buffer.getvalue())
        return path

    @staticmethod
    def load(path: str | Path) -> MeshSequence:
        """Read a file written by :meth:`save` (arrays only: nothing pickled is loaded).

        Raises:
            FileNotFoundError: ``path`` does not exist.
            InputError: it is not a mesh sequence of this schema (damaged, another file).
        """
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"{path} does not exist (a sequence.npz of the simulator)")
        try:
            return MeshSequence._read(path)
        except InputError:
            raise
        except Exception as error:  # whatever a damaged or foreign file made numpy raise
            text = " ".join(str(error).split())[:160] or type(error).__name__
            if "pickled" in text or "zip file" in text:
                text = "not an .npz archive of arrays"
            raise InputError(
                f"{path} is not a mesh sequence written by the simulator ({text})"
            ) from None

    @staticmethod
    def _read(path: Path) -> MeshSequence:
        with np.load(path, allow_pickle=False) as data:
            meta = json.loads(bytes(data["meta_json"]).decode())
            if meta.get("schema_version") != SCHEMA_VERSION:
                raise InputError(
                    f"{path}: schema_version {meta.get('schema_version')} != {SCHEMA_VERSION}"
                )
            return MeshSequence(
                pos=data["pos"],
                tri_indices=data["tri_indices"],
                uv=data["uv"],
                fps=float(data["fps"]),
                seeds=data["seeds"].tolist(),
                labels=data["labels"].tolist(),
                wind_levels=data["wind_levels"].tolist(),
                meta=meta,
                capsules=data["capsules"] if "capsules" in data.files else None,
            )

    def export(self, out_dir: str | Path, *, instance: int = 0, fmt: str = "obj") -> list[Path]:
        """Write one ``.obj``/``.ply`` per frame of ``instance`` (with uv), return the paths."""
        import trimesh

        if fmt not in ("obj", "ply"):
            raise ValueError(f"format must be 'obj' or 'ply', got {fmt!r}")
        if not 0 <= instance < self.pos.shape[0]:
            raise ValueError(f"instance must be in [0, {self.pos.shape[0] - 1}], got {instance}")
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        uv_unit = (self.uv - self.uv.min(0)) / np.maximum(np.ptp(self.uv, axis=0), 1e-12)
        paths = []
        for k in range(self.frame_count):
            mesh = trimesh.Trimesh(
                vertices=self.pos[instance, k],
                faces=self.tri_indices,
                visual=trimesh.visual.TextureVisuals(uv=uv_unit),
                process=False,
            )
            path = out / f"frame_{k:05d}.{fmt}"
            data = mesh.export(file_type=fmt)
            atomic_write_bytes(path, data.encode() if isinstance(data, str) else data)
            paths.append(path)
        return paths
