"""Dataclass fields that make an effect switch a candidate of the sim-to-real diagnosis.

The physical effects (:mod:`simulator.cloth.effects`) and the visual ones
(:mod:`render.effects`) declare their strengths with :func:`strength`; the diagnosis
(:mod:`sim2real.candidates`) reads the metadata, flips the switch and fits the strength.
"""

from __future__ import annotations

import dataclasses

__all__ = ["strength"]


def strength(
    default: float,
    of: str,
    low: float,
    high: float,
    *,
    integer: bool = False,
    neutral: float | None = None,
):
    """A dataclass field that is the strength of switch ``of``, plausible in [low, high].

    The diagnosis fits the strength within this range (narrower than the validity range the
    dataclass checks); a switch with no strength field is a binary candidate. ``neutral``:
    the strength at which the switch changes nothing, when it is not below the range (a
    frame-rate ratio of 1, a JPEG quality of 100, the matte roughness 1).
    """
    meta = {"strength_of": of, "plausible": (low, high), "integer": integer}
    if neutral is not None:
        meta["neutral"] = neutral
    return dataclasses.field(default=default, metadata=meta)
