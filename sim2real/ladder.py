"""Features of a clip set on every rung of the representation ladder, cached by content.

Rungs, from the image up: ``pixel`` (image statistics), ``motion`` (appearance-free optical
flow and temporal spectra), ``tracks`` (trajectories of followed cloth points), then every
recorded layer of the trained network
(:mod:`sim2real.network`). A set's features are stored under a key that hashes everything
that decides them (the set's spec or the real folder's files, the clip cut, the cloth box,
the checkpoint's bytes and :data:`FEATURE_VERSION`), so a second diagnosis with one more
candidate computes only the new sets.
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import logging
from pathlib import Path

import numpy as np

from common.files import atomic_write_bytes

from .domains import ClipSet
from .network import layer_features
from .rungs import clip_features

__all__ = ["FEATURE_VERSION", "LadderFeatures", "content_key", "file_digest", "ladder_features"]

log = logging.getLogger(__name__)

FEATURE_VERSION = 4
"""Bump when a feature's definition changes (invalidates every cached feature file)."""

_LABELS = ("groups", "class_id", "stiffness", "density")


@dataclasses.dataclass(frozen=True)
class LadderFeatures:
    """One clip set on every rung: ``rungs[name]`` is float64 (N, D_rung)."""

    rungs: dict[str, np.ndarray]
    groups: np.ndarray
    class_id: np.ndarray
    stiffness: np.ndarray
    density: np.ndarray

    def __len__(self) -> int:
        return len(self.groups)

    def save(self, path: Path) -> None:
        """Write atomically as one ``.npz``."""
        buffer = io.BytesIO()
        arrays = {f"rung/{k}": v for k, v in self.rungs.items()}
        arrays.update({k: getattr(self, k) for k in _LABELS})
        arrays["rung_order"] = np.array(list(self.rungs), dtype=str)
        np.savez(buffer, **arrays)
        atomic_write_bytes(path, buffer.getvalue())

    def shifted(self, effect: LadderFeatures, nominal: LadderFeatures) -> LadderFeatures:
        """These features moved, row by row, as ``effect`` moves ``nominal``.

        The first-order estimate of this set with one more effect on, when all three hold
        the same simulations in the same order: cheap enough to screen every candidate.
        """
        for other in (effect, nominal):
            if other.groups.shape != self.groups.shape or np.any(other.groups != self.groups):
                raise ValueError("shifted: the sets must hold the same simulations, in order")
        rungs = {k: v + (effect.rungs[k] - nominal.rungs[k]) for k, v in self.rungs.items()}
        return dataclasses.replace(self, rungs=rungs)

    @staticmethod
    def pooled(*sets: LadderFeatures) -> LadderFeatures:
        """The rows of ``sets`` as one set (several draws of one domain, for more power).

        Group ids become ``<index>:<id>``, so two draws' simulations never share a group.
        """
        groups = [np.char.add(f"{i}:", s.groups.astype(str)) for i, s in enumerate(sets)]
        return LadderFeatures(
            rungs={n: np.concatenate([s.rungs[n] for s in sets]) for n in sets[0].rungs},
            groups=np.concatenate(groups),
            **{k: np.concatenate([getattr(s, k) for s in sets]) for k in _LABELS[1:]},
        )

    @staticmethod
    def load(path: Path) -> LadderFeatures:
        """Read a file written by :meth:`save`."""
        with np.load(path, allow_pickle=False) as data:
            order = [str(n) for n in data["rung_order"]]
            return LadderFeatures(
                rungs={n: data[f"rung/{n}"] for n in order},
                **{k: data[k] for k in _LABELS},
            )


def file_digest(path: Path, chunk: int = 1 << 20) -> str:
    """sha256 of a file's bytes (hex, first 16 digits)."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        while block := handle.read(chunk):
            digest.update(block)
    return digest.hexdigest()[:16]


def content_key(**parts) -> str:
    """Hash of JSON-able parts (sorted keys): the cache key of one feature file."""
    text = json.dumps({"version": FEATURE_VERSION, **parts}, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:20]


def ladder_features(
    clips: ClipSet,
    box: tuple[int, int, int, int],
    net,
    *,
    device="cpu",
    batch_size: int = 16,
) -> LadderFeatures:
    """Features of every clip on every rung.

    Pixel and motion features look inside the cloth's ``box``; the net sees whole frames, as
    it saw its training clips.
    """
    rungs = clip_features(clips.frames, box)
    if net is not None:
        rungs.update(layer_features(net, clips.frames, batch_size=batch_size, device=device))
    for name, values in rungs.items():
        if not np.all(np.isfinite(values)):
            raise FloatingPointError(f"rung {name} produced non-finite features")
    return LadderFeatures(rungs=rungs, **{k: np.asarray(getattr(clips, k)) for k in _LABELS})
