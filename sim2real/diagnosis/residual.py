"""Where an unexplained gap lies: the stage whose candidates close most, else the rung pattern."""

from __future__ import annotations

from ..rungs import image_proof_rungs, rungs_revealing

__all__ = ["RESIDUAL_MOTION_SHARE", "RESIDUAL_STAGE_MIN_CLOSURE", "stage_of_residual"]


RESIDUAL_STAGE_MIN_CLOSURE = 0.10
"""Least share of the gap that a stage's best candidate must close for that stage to place an
unexplained residual (:func:`stage_of_residual`); below it the rung pattern decides. A fresh
nominal draw closes 10 % or more in about one set of twenty
(docs/design/sim2real-residual-stage.md)."""


RESIDUAL_MOTION_SHARE = 0.5
"""Where no candidate moves S toward R and both the pixel and the motion rung differ, a motion
gap at least this share of the pixel gap places the residual in "physics or scene": the cloth
moves differently, and its pixels follow (docs/design/sim2real-residual-stage.md)."""


_STAGE_PAIR = {
    "scene": "physics or scene",
    "physics": "physics or scene",
    "appearance": "appearance or camera",
    "camera": "appearance or camera",
}
"""The stages an unexplained residual is named by: what the user replicates or simulates
(scene, physics) against what the renderer and camera do (appearance, camera)."""


def stage_of_residual(
    location: dict, stage_scores: dict | None = None, gaps: dict | None = None
) -> str:
    """Stage named by an unexplained gap (no candidate closes enough of it).

    Where some candidate moves S toward R by at least :data:`RESIDUAL_STAGE_MIN_CLOSURE`,
    the stage of the one that closes most places the residual, in the pair it belongs to
    ("physics or scene" or "appearance or camera"): the library's partial closures say which
    way R lies even when none explains it. Only where no candidate moves S that far does the
    rung pattern decide. The pattern alone misleads for motion: a different wind changes the
    cloth's shading and silhouette, so the pixel statistics differ as much as for a camera
    effect (decision record: docs/design/sim2real-residual-stage.md).

    The converse holds: where the motion differs and the pixel statistics do not, the
    appearance candidates' partial closures are not counted. The motion rung is
    appearance-free (optical flow and temporal spectra of the cloth), so a renderer change
    (lighting, texture, shading) cannot make it; what such a candidate closes then lies in the
    network's layers alone. Camera candidates (frame rate, motion blur, shake) do change the
    motion and still count.

    Where the pixel statistics differ and the motion does not, the scene candidates' partial
    closures are not counted: framing, pinning, swatch size and wind direction move the
    cloth, so a scene difference shows a motion gap. Physics candidates still count: a
    physics change can alter the pixels and not the measured motion.

    Where nothing moves S that far and both the pixel statistics and the motion differ, the
    motion's share of the gap decides (``gaps``: floor-corrected AUC per rung; without them
    the pixel statistics decide as before): a motion gap of :data:`RESIDUAL_MOTION_SHARE` of
    the pixel gap or more says the cloth moves differently ("physics or scene"), a smaller one
    that the image is formed differently (see the constant for how far that holds).

    Texture, backdrop and sharpening move the dense flow with the picture. Where an image-proof
    rung (:func:`~sim2real.rungs.image_proof_rungs`: tracked points of the cloth) was measured
    (in ``gaps``), a dense-flow gap that comes with a pixel gap counts as motion only when the
    image-proof rung differs too, and the motion's share above is that rung's gap.
    """
    if not location["significant"] and location["first_significant_layer"] is None:
        return "none (no significant gap)"
    significant = location["significant"]
    moves = any(n in significant for n in rungs_revealing("dynamics"))
    looks = any(n in significant for n in rungs_revealing("image"))
    proof = tuple(n for n in image_proof_rungs() if gaps and gaps.get(n) is not None)
    flow_only = proof and looks and moves and not any(n in significant for n in proof)
    if flow_only:
        moves = False  # the dense flow moved with the picture; the cloth's points did not
    if looks:
        by_pattern, pattern = "appearance or camera", "the pixel statistics differ"
        if flow_only:
            pattern += ", and the dense flow, not the tracked points"
        elif not moves:
            pattern += ", the motion does not"
    elif moves:
        by_pattern, pattern = "physics or scene", "the motion differs, the pixel statistics do not"
    else:
        by_pattern, pattern = "network features only", "pixel and motion statistics agree"
    scores = {k: v for k, v in (stage_scores or {}).items() if v is not None}
    if by_pattern == "physics or scene":
        scores.pop("appearance", None)  # the renderer does not move the cloth
    elif by_pattern == "appearance or camera" and not moves:
        scores.pop("scene", None)  # a scene change moves the cloth
    best = max(scores, key=scores.get) if scores else None
    if best is not None and scores[best] >= RESIDUAL_STAGE_MIN_CLOSURE:
        return (
            f"{_STAGE_PAIR[best]} (the {best} candidates close most of it, "
            f"{100 * scores[best]:.0f} %, too little to name one; {pattern})"
        )
    pixel = _largest(gaps, rungs_revealing("image"))
    motion = _largest(gaps, proof or rungs_revealing("dynamics"))
    if moves and by_pattern == "appearance or camera" and None not in (pixel, motion):
        if motion >= RESIDUAL_MOTION_SHARE * pixel:
            return (
                f"physics or scene (no candidate moves S toward R; the motion differs about "
                f"as much as the pixel statistics: gaps {motion:.2f} and {pixel:.2f})"
            )
    return f"{by_pattern} ({pattern})"


def _largest(gaps: dict[str, float] | None, names: tuple[str, ...]) -> float | None:
    """The largest gap among ``names`` (``None`` when none of them is measured)."""
    values = [gaps[n] for n in names if gaps and gaps.get(n) is not None]
    return max(values) if values else None
