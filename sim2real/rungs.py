"""The ladder's hand-made rungs: one registry that every step of the diagnosis reads.

The features, the localisation, the residual stage and the counterfactuals read it. A rung is
one entry of :data:`HAND_RUNGS`: its name, the names of its features, the function that
measures one clip inside the cloth's box, and what kind of difference it reveals: ``image``
(how the picture is formed: appearance or camera) or ``dynamics`` (how the cloth moves: physics
or scene). The trained network's layers are rungs too, after these ones, named by the net
(:mod:`sim2real.network`). Adding a rung is adding an entry here (and raising
:data:`sim2real.ladder.FEATURE_VERSION`, so that cached features are rebuilt): see "How to add
a rung" in docs/sim2real.md.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable, Sequence

import numpy as np

from .features import (
    MOTION_FEATURE_NAMES,
    PIXEL_FEATURE_NAMES,
    is_int,
    motion_features,
    pixel_features,
)
from .tracks import TRACK_FEATURE_NAMES, track_features

__all__ = [
    "HAND_RUNGS",
    "KINDS",
    "Rung",
    "clip_features",
    "hand_rung",
    "hand_rung_names",
    "image_proof_rungs",
    "rungs_revealing",
]

KINDS = ("image", "dynamics")
"""What a hand-made rung reveals: how the picture is formed, or how the cloth moves."""


@dataclasses.dataclass(frozen=True)
class Rung:
    """A hand-made rung: fixed-length features of one clip inside the cloth's box."""

    name: str
    """The rung's name in reports (``pixel``, ``motion``)."""
    reveals: str
    """``image`` or ``dynamics`` (:data:`KINDS`): the stages a difference on it points to."""
    feature_names: tuple[str, ...]
    """Names of its features, in the order ``measure`` returns them."""
    measure: Callable[[np.ndarray, tuple[int, int, int, int]], np.ndarray]
    """``measure(clip uint8 (K, H, W, 3), box (y0, y1, x0, x1)) -> float64 (features,)``."""
    image_proof: bool = False
    """A ``dynamics`` rung that no change of how the picture is formed moves (texture,
    backdrop, sharpening: ``benchmarks/sim2real_rung_invariance.py``), so a gap on it is the
    cloth's motion; ``motion``'s dense flow is not."""

    def __post_init__(self):
        if self.reveals not in KINDS:
            raise ValueError(f"rung {self.name}: reveals must be in {KINDS}, got {self.reveals!r}")


HAND_RUNGS: tuple[Rung, ...] = (
    Rung("pixel", "image", PIXEL_FEATURE_NAMES, pixel_features),
    Rung("motion", "dynamics", MOTION_FEATURE_NAMES, motion_features),
    Rung("tracks", "dynamics", TRACK_FEATURE_NAMES, track_features, image_proof=True),
)
"""The hand-made rungs, in ladder order. ``tracks`` reads only followed points of the cloth,
so a texture, backdrop or sharpening change that moves ``motion``'s dense flow leaves it
be (:mod:`sim2real.tracks`)."""


def hand_rung_names() -> tuple[str, ...]:
    """Names of :data:`HAND_RUNGS`, in ladder order (every other rung is a network layer)."""
    return tuple(rung.name for rung in HAND_RUNGS)


def hand_rung(name: str) -> Rung:
    """The hand-made rung called ``name``."""
    for rung in HAND_RUNGS:
        if rung.name == name:
            return rung
    raise KeyError(f"no hand-made rung {name!r}; there are {', '.join(hand_rung_names())}")


def rungs_revealing(kind: str) -> tuple[str, ...]:
    """Names of the hand-made rungs that reveal ``kind`` (``image`` or ``dynamics``)."""
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {KINDS}, got {kind!r}")
    return tuple(rung.name for rung in HAND_RUNGS if rung.reveals == kind)


def image_proof_rungs() -> tuple[str, ...]:
    """Names of the ``dynamics`` rungs that image changes cannot move (:attr:`Rung.image_proof`)."""
    return tuple(rung.name for rung in HAND_RUNGS if rung.image_proof)


def _boxes_for(box, count_hint: int | None):
    """One box for all clips, or an iterator of per-clip boxes."""
    array = np.asarray(box, dtype=object)
    if array.ndim == 1 and array.shape == (4,) and all(is_int(v) for v in array):
        return None
    if array.ndim == 2 and array.shape[1] == 4:
        if count_hint is not None and len(array) != count_hint:
            raise ValueError(
                f"box must be one (y0, y1, x0, x1) or one per clip; got {len(array)} boxes "
                f"for {count_hint} clips"
            )
        return [tuple(row) for row in array]
    raise ValueError(
        f"box must be one (y0, y1, x0, x1) of integers or a sequence of them, one per clip; "
        f"got {box!r}"
    )


def clip_features(
    clips: Iterable[np.ndarray],
    box: tuple[int, int, int, int] | Sequence[tuple[int, int, int, int]],
    *,
    progress: bool = False,
) -> dict[str, np.ndarray]:
    """Every hand-made rung's features of many clips, stacked, for callers that compare sets.

    Args:
        clips: Clips, each uint8 RGB, shape (K, H, W, 3), K >= 3 (an array (N, K, H, W, 3)
            works too).
        box: One ``(y0, y1, x0, x1)`` for every clip, or one per clip (N of them).
        progress: Show a tqdm progress bar.

    Returns:
        ``{rung name: float64 (N, feature count)}`` for every rung of :data:`HAND_RUNGS`
        (``pixel`` (N, 35), ``motion`` (N, 56) and ``tracks`` (N, 6) today).

    Raises:
        ValueError: For a bad clip or box (see the rungs' ``measure`` functions) or a count of
            boxes that differs from the count of clips.
    """
    count = len(clips) if hasattr(clips, "__len__") else None
    boxes = _boxes_for(box, count)
    iterator: Iterable = clips
    if progress:
        from tqdm.auto import tqdm  # only callers that ask for a bar pay for tqdm

        iterator = tqdm(clips, total=count, desc="clip features")
    rows: dict[str, list[np.ndarray]] = {rung.name: [] for rung in HAND_RUNGS}
    measured = 0
    for index, clip in enumerate(iterator):
        if boxes is None:
            clip_box = box
        elif index < len(boxes):
            clip_box = boxes[index]
        else:
            raise ValueError(f"box gives {len(boxes)} boxes but clips has more than that")
        for rung in HAND_RUNGS:
            rows[rung.name].append(rung.measure(clip, clip_box))
        measured += 1
    if boxes is not None and measured != len(boxes):
        raise ValueError(f"box gives {len(boxes)} boxes but clips has {measured}")
    return {
        rung.name: np.asarray(rows[rung.name], np.float64).reshape(-1, len(rung.feature_names))
        for rung in HAND_RUNGS
    }
