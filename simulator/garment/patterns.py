"""Parametric sewing patterns (*thesis* §6.5.2, Fig. 6.3): skirt, pants and t-shirt.

A pattern is a set of flat panels (2D, metres) and the seams that join their edges. Each
garment type has a few sizing parameters G (:func:`param_specs`: unit, plausible range,
default, meaning); the panel outlines are closed-form functions of G.

Meshing (the project's own, no meshing library): every panel is a four-sided region whose
sides are polylines made of named *segments*. Each segment is sampled uniformly by arc length
with a fixed number of edges, and the panel is meshed as the transfinite (Coons) interpolation
of its four sides on a structured grid, triangulated with alternating diagonals. The counts
depend only on the garment type and the target edge length (taken at the default G), never on
G itself, so every pattern of a type shares one topology and its vertices move smoothly with G:
this is the *thesis*'s Eq. 6.1, ``u(G) = sum_i nu_i(G) u0_i``, with the Coons weights as
``nu``. A batch of particles of a swarm (different G) is then one batch of simulations with
per-instance rest shapes.

Seams pair the vertices of two segments index by index (same count, equal arc-length
fractions). Where a garment is read from the *thesis* only loosely, the choice made here is
documented in ``docs/garment.md``:

* **skirt** ``<l1, r1, r2, alpha>``: front and back each a *yoke* (trapezoid, height
  :data:`SKIRT_YOKE_HEIGHT`, top edge ``l1`` = waist half-girth, bottom edge ``r1 alpha``) and a
  *flared panel*, an annular sector of angle ``alpha``, inner radius ``r1`` and radial length
  ``r2`` (the circle-skirt piece of Fig. 6.3a, morphed);
* **pants** ``<w1..w4, h1..h3>``: four leg panels (front/back x right/left) with waist, seat
  (bottom), knee and ankle girths ``w1..w4``, outseam length ``h1``, back and front rise
  ``h2, h3``;
* **t-shirt** ``<r, w1, w2, h1, h2, l1>``: front, back and two sleeves; neckline radius ``r``,
  sleeve flat width at the cuff ``w1``, body width ``w2``, side length ``h1`` (hem to
  underarm), total length ``h2`` (hem to neck point), sleeve length ``l1``.

Panel frames: ``u`` across, ``v`` up (towards the waist or shoulder); the material's warp runs
along ``u``. Export: :meth:`Pattern.to_svg` (cuttable, millimetres) and :meth:`Pattern.to_json`.
"""

from __future__ import annotations

import dataclasses
import enum
import json
import math
from collections.abc import Mapping

import numpy as np

from common.errors import InputError

__all__ = [
    "GARMENT_TYPES",
    "SIDES",
    "SKIRT_YOKE_HEIGHT",
    "GarmentType",
    "ParamSpec",
    "Pattern",
    "PatternError",
    "PatternTopology",
    "SeamSpec",
    "build_pattern",
    "check_params",
    "closed_form",
    "default_params",
    "param_specs",
    "search_box",
]


class PatternError(InputError):
    """Sizing parameters outside their range, or a combination that makes no garment."""


class GarmentType(enum.StrEnum):
    """The garment templates of the library."""

    SKIRT = "skirt"
    PANTS = "pants"
    TSHIRT = "tshirt"


GARMENT_TYPES = tuple(g.value for g in GarmentType)
"""Names accepted by ``garment=`` on the command line."""

SIDES = ("bottom", "right", "top", "left")
"""Sides of a panel; bottom and top run left to right, left and right run bottom to top."""

SKIRT_YOKE_HEIGHT = 0.15
"""Height of the skirt's yoke, waist to hip line [m] (fixed; not a sizing parameter)."""
TSHIRT_SHOULDER_DROP = 0.04
"""Drop of the t-shirt's shoulder point below the neck point [m]."""
TSHIRT_BACK_NECK_DEPTH = 0.3
"""Back neckline depth as a fraction of the neckline radius (the front's is 1)."""


@dataclasses.dataclass(frozen=True)
class ParamSpec:
    """One sizing parameter of a garment template."""

    name: str
    unit: str
    low: float
    """Smallest plausible value (in ``unit``)."""
    high: float
    """Largest plausible value (in ``unit``)."""
    default: float
    doc: str

    def read(self, values: Mapping) -> tuple[object, float]:
        """The value given in ``values`` (else the default) and it as a float, NaN if none."""
        value = values.get(self.name, self.default)
        try:
            return value, float(value)
        except (TypeError, ValueError):
            return value, math.nan


_SPECS: dict[GarmentType, tuple[ParamSpec, ...]] = {
    GarmentType.SKIRT: (
        ParamSpec("l1", "m", 0.30, 0.55, 0.37, "waist half-girth: top edge of each yoke"),
        ParamSpec(
            "r1",
            "m",
            0.30,
            2.60,
            0.80,
            "inner radius of the flared panel; its top arc r1*alpha is the hip half-girth",
        ),
        ParamSpec(
            "r2",
            "m",
            0.20,
            0.75,
            0.40,
            "radial length of the flared panel (skirt length below the yoke)",
        ),
        ParamSpec("alpha", "rad", 0.30, 1.50, 0.70, "sector angle of the flared panel (flare)"),
    ),
    GarmentType.PANTS: (
        ParamSpec("w1", "m", 0.60, 1.05, 0.80, "waist girth"),
        ParamSpec("w2", "m", 0.85, 1.30, 1.04, "seat (bottom) girth"),
        ParamSpec("w3", "m", 0.32, 0.62, 0.46, "knee girth"),
        ParamSpec("w4", "m", 0.26, 0.58, 0.40, "ankle (hem) girth"),
        ParamSpec("h1", "m", 0.70, 1.12, 0.98, "total length (outseam, waist to hem)"),
        ParamSpec("h2", "m", 0.24, 0.42, 0.33, "back rise (back waist to crotch)"),
        ParamSpec("h3", "m", 0.20, 0.36, 0.27, "front rise (front waist to crotch)"),
    ),
    GarmentType.TSHIRT: (
        ParamSpec("r", "m", 0.06, 0.12, 0.085, "neckline radius"),
        ParamSpec("w1", "m", 0.12, 0.26, 0.18, "sleeve flat width at the cuff (half its girth)"),
        ParamSpec("w2", "m", 0.40, 0.62, 0.52, "body width (shoulder point to shoulder point)"),
        ParamSpec("h1", "m", 0.22, 0.50, 0.36, "side length (hem to underarm)"),
        ParamSpec("h2", "m", 0.52, 0.82, 0.66, "total length (hem to neck point)"),
        ParamSpec("l1", "m", 0.08, 0.40, 0.20, "sleeve length"),
    ),
}


def _garment(garment: GarmentType | str, field: str = "garment") -> GarmentType:
    try:
        return GarmentType(garment)
    except ValueError:
        raise InputError(
            f"{field} must be one of {', '.join(GARMENT_TYPES)}; got {garment!r}"
        ) from None


def param_specs(garment: GarmentType | str) -> tuple[ParamSpec, ...]:
    """The sizing parameters G of a garment type, in their canonical order."""
    return _SPECS[_garment(garment)]


def default_params(garment: GarmentType | str) -> dict[str, float]:
    """Default sizing of a garment type (a plausible adult size)."""
    return {p.name: p.default for p in param_specs(garment)}


def check_params(
    garment: GarmentType | str, values: Mapping[str, float], field: str = "params"
) -> dict[str, float]:
    """All of G as floats, each within its range and the combination valid.

    Missing names take their defaults.

    Raises:
        PatternError: naming ``field.<name>`` and its range, or the violated relation.
    """
    garment = _garment(garment)
    specs = {p.name: p for p in param_specs(garment)}
    unknown = sorted(set(values) - set(specs))
    if unknown:
        raise PatternError(
            f"{field}: unknown {unknown} for garment={garment.value}; allowed: {list(specs)}"
        )
    out = {}
    for name, spec in specs.items():
        value, number = spec.read(values)
        if isinstance(value, bool) or not math.isfinite(number):
            raise PatternError(f"{field}.{name} must be a number [{spec.unit}], got {value!r}")
        # A relative slack: values read back from JSON or produced by scaling stay valid.
        slack = 1e-9 * max(abs(spec.low), abs(spec.high))
        if not spec.low - slack <= number <= spec.high + slack:
            raise PatternError(
                f"{field}.{name} ({spec.doc}) must lie in [{spec.low}, {spec.high}] {spec.unit}, "
                f"got {number:g}"
            )
        out[name] = number
    _check_relations(garment, out, field)
    return out


_SKIRT_HIP_RANGE = (0.40, 0.95)
"""Range of the skirt's hip half-girth r1 * alpha [m]."""


def _check_relations(garment: GarmentType, g: dict[str, float], field: str) -> None:
    if garment is GarmentType.SKIRT:
        hip = g["r1"] * g["alpha"]
        lo, hi = _SKIRT_HIP_RANGE
        if not lo - 1e-9 <= hip <= hi + 1e-9:
            raise PatternError(
                f"{field}: the skirt's hip half-girth r1*alpha must lie in [{lo}, {hi}] m, got "
                f"{hip:.3f} (r1={g['r1']:g}, alpha={g['alpha']:g})"
            )
    elif garment is GarmentType.PANTS:
        if g["h2"] < g["h3"]:
            raise PatternError(
                f"{field}: pants back rise h2 must be >= front rise h3, got h2={g['h2']:g} < "
                f"h3={g['h3']:g}"
            )
        if g["w3"] < g["w4"]:
            raise PatternError(
                f"{field}: pants knee girth w3 must be >= ankle girth w4, got w3={g['w3']:g} < "
                f"w4={g['w4']:g}"
            )
    elif garment is GarmentType.TSHIRT:
        armhole = g["h2"] - TSHIRT_SHOULDER_DROP - g["h1"]
        if armhole < 0.12:
            raise PatternError(
                f"{field}: the t-shirt's armhole h2 - h1 - {TSHIRT_SHOULDER_DROP} must be >= "
                f"0.12 m, got {armhole:.3f} (h1={g['h1']:g}, h2={g['h2']:g})"
            )
        if g["w2"] / 2 - g["r"] < 0.08:
            raise PatternError(
                f"{field}: the t-shirt's shoulders w2/2 - r must be >= 0.08 m, got "
                f"{g['w2'] / 2 - g['r']:.3f} (w2={g['w2']:g}, r={g['r']:g})"
            )
        if g["w1"] > armhole:
            raise PatternError(
                f"{field}: the t-shirt's cuff w1 must not exceed the armhole h2 - h1 - "
                f"{TSHIRT_SHOULDER_DROP} = {armhole:.3f} m, got w1={g['w1']:g}"
            )


# ---------------------------------------------------------------------------- search space


def search_box(garment: GarmentType | str) -> tuple[tuple[str, ...], np.ndarray, np.ndarray]:
    """Names and bounds of the box a swarm searches for G (see :func:`from_search`).

    Identical to G except for the skirt, searched as ``(l1, hip = r1 alpha, r2, alpha)`` so
    that the box holds only valid skirts (the hip arc must fit a body).
    """
    garment = _garment(garment)
    specs = param_specs(garment)
    names = tuple(p.name for p in specs)
    lo = np.array([p.low for p in specs])
    hi = np.array([p.high for p in specs])
    if garment is GarmentType.SKIRT:
        names = ("l1", "hip", "r2", "alpha")
        lo[1], hi[1] = _SKIRT_HIP_RANGE
        # r1 = hip / alpha must stay inside r1's own range as well.
        lo[3] = max(lo[3], _SKIRT_HIP_RANGE[1] / specs[1].high)
        hi[3] = min(hi[3], _SKIRT_HIP_RANGE[0] / specs[1].low)
    elif garment is GarmentType.PANTS:
        # Searched as (.., knee - ankle, .., back - front rise) would also be valid; the
        # relation checks are enforced by clamping in from_search instead.
        pass
    return names, lo, hi


def from_search(garment: GarmentType | str, x: np.ndarray) -> dict[str, float]:
    """G from a point of :func:`search_box` (the relations clamped to hold)."""
    garment = _garment(garment)
    x = np.asarray(x, dtype=np.float64).reshape(-1)
    names = [p.name for p in param_specs(garment)]
    if garment is GarmentType.SKIRT:
        l1, hip, r2, alpha = x
        g = {"l1": l1, "r1": hip / alpha, "r2": r2, "alpha": alpha}
    else:
        g = dict(zip(names, x.tolist(), strict=True))
    if garment is GarmentType.PANTS:
        g["h2"] = max(g["h2"], g["h3"])
        g["w3"] = max(g["w3"], g["w4"])
    if garment is GarmentType.TSHIRT:
        armhole = g["h2"] - TSHIRT_SHOULDER_DROP - g["h1"]
        if armhole < 0.12:
            g["h1"] = g["h2"] - TSHIRT_SHOULDER_DROP - 0.12
        g["w1"] = min(g["w1"], g["h2"] - TSHIRT_SHOULDER_DROP - g["h1"])
    specs = {p.name: p for p in param_specs(garment)}
    return {k: float(np.clip(v, specs[k].low, specs[k].high)) for k, v in g.items()}


def to_search(garment: GarmentType | str, g: Mapping[str, float]) -> np.ndarray:
    """The search-box point of G (inverse of :func:`from_search` for valid G)."""
    garment = _garment(garment)
    if garment is GarmentType.SKIRT:
        return np.array([g["l1"], g["r1"] * g["alpha"], g["r2"], g["alpha"]])
    return np.array([g[p.name] for p in param_specs(garment)])


# -------------------------------------------------------------------------------- outlines


def _line(a, b, n: int = 2) -> np.ndarray:
    return np.linspace(np.asarray(a, float), np.asarray(b, float), n)


def _arc(centre, radius: float, start: float, stop: float, n: int = 257) -> np.ndarray:
    t = np.linspace(start, stop, n)
    return np.stack([centre[0] + radius * np.cos(t), centre[1] + radius * np.sin(t)], -1)


def _polar(centre, radius: float, angle: float) -> np.ndarray:
    return np.array([centre[0] + radius * math.cos(angle), centre[1] + radius * math.sin(angle)])


def _chain(*parts: np.ndarray) -> np.ndarray:
    """Concatenate polylines that share their end points."""
    out = [parts[0]]
    for p in parts[1:]:
        out.append(p[1:])
    return np.concatenate(out)


Outline = dict[str, list[tuple[str, np.ndarray]]]
"""A panel's sides: side name -> [(segment name, polyline (N, 2) [m])] in side direction."""


def _skirt_outlines(g: Mapping[str, float]) -> dict[str, Outline]:
    l1, r1, r2, alpha = g["l1"], g["r1"], g["r2"], g["alpha"]
    hip = r1 * alpha
    hy = SKIRT_YOKE_HEIGHT
    yoke: Outline = {
        "bottom": [("hip", _line((-hip / 2, 0.0), (hip / 2, 0.0)))],
        "top": [("waist", _line((-l1 / 2, hy), (l1 / 2, hy)))],
        "left": [("yoke_side_l", _line((-hip / 2, 0.0), (-l1 / 2, hy)))],
        "right": [("yoke_side_r", _line((hip / 2, 0.0), (l1 / 2, hy)))],
    }
    # Sector with apex at (0, r1) above the hip line; the hip arc is its top edge.
    apex = (0.0, r1)
    lo, hi = -math.pi / 2 - alpha / 2, -math.pi / 2 + alpha / 2
    outer = r1 + r2
    flare: Outline = {
        "bottom": [("hem", _arc(apex, outer, lo, hi))],
        "top": [("hip", _arc(apex, r1, lo, hi))],
        "left": [("flare_side_l", _line(_polar(apex, outer, lo), _polar(apex, r1, lo)))],
        "right": [("flare_side_r", _line(_polar(apex, outer, hi), _polar(apex, r1, hi)))],
    }
    return {"yoke_front": yoke, "yoke_back": yoke, "flare_front": flare, "flare_back": flare}


def _pants_panel(g: Mapping[str, float], back: bool) -> Outline:
    w1, w2, w3, w4 = g["w1"], g["w2"], g["w3"], g["w4"]
    h1, h2, h3 = g["h1"], g["h2"], g["h3"]
    crotch_y = h1 - h3
    ext = w2 / 8 if back else w2 / 16
    rise = h2 if back else h3
    waist_c = (w1 / 4, crotch_y + rise)
    knee = (w3 / 2, 0.45 * crotch_y)
    crotch = (w2 / 4 + ext, crotch_y)
    # Crotch curve: a quarter ellipse from the crotch point up to the seat line, then straight
    # to the waist centre.
    centre = (crotch[0], crotch_y + 0.6 * rise)
    t = np.linspace(0.0, math.pi / 2, 17)
    curve = np.stack([centre[0] - ext * np.sin(t), centre[1] - 0.6 * rise * np.cos(t)], -1)
    crotch_line = _chain(curve, _line(curve[-1], waist_c))
    return {
        "bottom": [("hem", _line((0.0, 0.0), (w4 / 2, 0.0)))],
        "top": [("waist", _line((0.0, h1), waist_c))],
        "left": [
            ("out_low", _line((0.0, 0.0), (0.0, crotch_y))),
            ("out_high", _line((0.0, crotch_y), (0.0, h1))),
        ],
        "right": [
            ("inseam", _chain(_line((w4 / 2, 0.0), knee), _line(knee, crotch))),
            ("crotch", crotch_line),
        ],
    }


def _pants_outlines(g: Mapping[str, float]) -> dict[str, Outline]:
    front, back = _pants_panel(g, False), _pants_panel(g, True)
    return {"front_r": front, "back_r": back, "front_l": front, "back_l": back}


def _tshirt_body(g: Mapping[str, float], back: bool) -> Outline:
    r, w2, h1, h2 = g["r"], g["w2"], g["h1"], g["h2"]
    half = w2 / 2
    shoulder_y = h2 - TSHIRT_SHOULDER_DROP
    depth = r * (TSHIRT_BACK_NECK_DEPTH if back else 1.0)
    t = np.linspace(math.pi, 2 * math.pi, 129)
    neck = np.stack([r * np.cos(t), h2 + depth * np.sin(t)], -1)
    return {
        "bottom": [("hem", _line((-half, 0.0), (half, 0.0)))],
        "top": [
            ("shoulder_l", _line((-half, shoulder_y), (-r, h2))),
            ("neck", neck),
            ("shoulder_r", _line((r, h2), (half, shoulder_y))),
        ],
        "left": [
            ("side_l", _line((-half, 0.0), (-half, h1))),
            ("arm_l", _line((-half, h1), (-half, shoulder_y))),
        ],
        "right": [
            ("side_r", _line((half, 0.0), (half, h1))),
            ("arm_r", _line((half, h1), (half, shoulder_y))),
        ],
    }


def _tshirt_sleeve(g: Mapping[str, float]) -> Outline:
    w1, l1 = g["w1"], g["l1"]
    a = g["h2"] - TSHIRT_SHOULDER_DROP - g["h1"]  # armhole length: the cap is twice it
    return {
        "bottom": [("cuff", _line((-w1, 0.0), (w1, 0.0)))],
        "top": [("cap_a", _line((-a, l1), (0.0, l1))), ("cap_b", _line((0.0, l1), (a, l1)))],
        "left": [("under_l", _line((-w1, 0.0), (-a, l1)))],
        "right": [("under_r", _line((w1, 0.0), (a, l1)))],
    }


def _tshirt_outlines(g: Mapping[str, float]) -> dict[str, Outline]:
    sleeve = _tshirt_sleeve(g)
    return {
        "front": _tshirt_body(g, False),
        "back": _tshirt_body(g, True),
        "sleeve_r": sleeve,
        "sleeve_l": sleeve,
    }


_OUTLINES = {
    GarmentType.SKIRT: _skirt_outlines,
    GarmentType.PANTS: _pants_outlines,
    GarmentType.TSHIRT: _tshirt_outlines,
}


@dataclasses.dataclass(frozen=True)
class SeamSpec:
    """Two segments sewn together, vertex by vertex."""

    name: str
    a: tuple[str, str]
    """(panel, segment) of the first side."""
    b: tuple[str, str]
    """(panel, segment) of the second side."""
    reverse: bool = False
    """Pair the first side's vertices with the second's in reverse order."""


_SEAMS: dict[GarmentType, tuple[SeamSpec, ...]] = {
    # Front panels are seen from the front, back panels from behind: a front's left side
    # lies on the wearer's right, as does a back's right side.
    GarmentType.SKIRT: (
        SeamSpec("yoke_side_right", ("yoke_front", "yoke_side_l"), ("yoke_back", "yoke_side_r")),
        SeamSpec("yoke_side_left", ("yoke_front", "yoke_side_r"), ("yoke_back", "yoke_side_l")),
        SeamSpec("side_right", ("flare_front", "flare_side_l"), ("flare_back", "flare_side_r")),
        SeamSpec("side_left", ("flare_front", "flare_side_r"), ("flare_back", "flare_side_l")),
        SeamSpec("hip_front", ("yoke_front", "hip"), ("flare_front", "hip")),
        SeamSpec("hip_back", ("yoke_back", "hip"), ("flare_back", "hip")),
    ),
    GarmentType.PANTS: (
        SeamSpec("outseam_low_right", ("front_r", "out_low"), ("back_r", "out_low")),
        SeamSpec("outseam_high_right", ("front_r", "out_high"), ("back_r", "out_high")),
        SeamSpec("outseam_low_left", ("front_l", "out_low"), ("back_l", "out_low")),
        SeamSpec("outseam_high_left", ("front_l", "out_high"), ("back_l", "out_high")),
        SeamSpec("inseam_right", ("front_r", "inseam"), ("back_r", "inseam")),
        SeamSpec("inseam_left", ("front_l", "inseam"), ("back_l", "inseam")),
        SeamSpec("crotch_front", ("front_r", "crotch"), ("front_l", "crotch")),
        SeamSpec("crotch_back", ("back_r", "crotch"), ("back_l", "crotch")),
    ),
    GarmentType.TSHIRT: (
        SeamSpec("side_right", ("front", "side_l"), ("back", "side_r")),
        SeamSpec("side_left", ("front", "side_r"), ("back", "side_l")),
        SeamSpec("shoulder_right", ("front", "shoulder_l"), ("back", "shoulder_r"), True),
        SeamSpec("shoulder_left", ("front", "shoulder_r"), ("back", "shoulder_l"), True),
        SeamSpec("underarm_right", ("sleeve_r", "under_l"), ("sleeve_r", "under_r")),
        SeamSpec("underarm_left", ("sleeve_l", "under_l"), ("sleeve_l", "under_r")),
        SeamSpec("armhole_right_front", ("front", "arm_l"), ("sleeve_r", "cap_a")),
        SeamSpec("armhole_right_back", ("back", "arm_r"), ("sleeve_r", "cap_b"), True),
        SeamSpec("armhole_left_front", ("front", "arm_r"), ("sleeve_l", "cap_a")),
        SeamSpec("armhole_left_back", ("back", "arm_l"), ("sleeve_l", "cap_b"), True),
    ),
}


def _length(poly: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(poly, axis=0), axis=1).sum())


def _counts(garment: GarmentType, edge_length: float) -> dict[str, int]:
    """Edges per segment name, from the default G and the target edge length [m]."""
    outlines = _OUTLINES[garment](default_params(garment))
    lengths: dict[str, float] = {}
    for outline in outlines.values():
        for segments in outline.values():
            for name, poly in segments:
                lengths[name] = max(lengths.get(name, 0.0), _length(poly))

    def n(name: str, minimum: int = 1) -> int:
        return max(minimum, round(lengths[name] / edge_length))

    if garment is GarmentType.SKIRT:
        across = max(n("hem", 4), n("waist", 4))
        return {
            "hip": across,
            "waist": across,
            "hem": across,
            "yoke_side_l": n("yoke_side_l", 2),
            "yoke_side_r": n("yoke_side_l", 2),
            "flare_side_l": n("flare_side_l", 2),
            "flare_side_r": n("flare_side_l", 2),
        }
    if garment is GarmentType.PANTS:
        widest = outlines["back_r"]["right"][0][1][-1, 0]  # crotch point of the back
        across = max(3, round(0.5 * (widest + lengths["hem"]) / edge_length))
        low, high = n("out_low", 3), n("crotch", 3)
        return {
            "hem": across,
            "waist": across,
            "out_low": low,
            "inseam": low,
            "out_high": high,
            "crotch": high,
        }
    # t-shirt
    neck = n("neck", 2)
    shoulder = n("shoulder_l", 1)
    arm = n("arm_l", 2)
    return {
        "hem": 2 * shoulder + neck,
        "neck": neck,
        "shoulder_l": shoulder,
        "shoulder_r": shoulder,
        "side_l": n("side_l", 2),
        "side_r": n("side_l", 2),
        "arm_l": arm,
        "arm_r": arm,
        "cap_a": arm,
        "cap_b": arm,
        "cuff": 2 * arm,
        "under_l": n("under_l", 2),
        "under_r": n("under_l", 2),
    }


# ---------------------------------------------------------------------------------- meshing


def _resample(poly: np.ndarray, edges: int) -> np.ndarray:
    """``edges + 1`` points uniformly spaced by arc length along a polyline."""
    seg = np.linalg.norm(np.diff(poly, axis=0), axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    t = np.linspace(0.0, cum[-1], edges + 1)
    return np.stack([np.interp(t, cum, poly[:, 0]), np.interp(t, cum, poly[:, 1])], -1)


def _side_points(segments: list[tuple[str, np.ndarray]], counts: Mapping[str, int]):
    pts = [_resample(poly, counts[name]) for name, poly in segments]
    return _chain(*pts)


def _coons(bottom, top, left, right) -> np.ndarray:
    """Transfinite interpolation of four sides, grid (nv + 1, nu + 1, 2)."""
    nu, nv = bottom.shape[0] - 1, left.shape[0] - 1
    s = np.linspace(0.0, 1.0, nu + 1)[None, :, None]
    t = np.linspace(0.0, 1.0, nv + 1)[:, None, None]
    # Parameters follow the sides' own (arc-length) spacing, so seams stay uniform.
    p00, p10, p01, p11 = bottom[0], bottom[-1], top[0], top[-1]
    return (
        (1 - t) * bottom[None]
        + t * top[None]
        + (1 - s) * left[:, None]
        + s * right[:, None]
        - ((1 - s) * (1 - t) * p00 + s * (1 - t) * p10 + (1 - s) * t * p01 + s * t * p11)
    )


def _grid_triangles(nu: int, nv: int, offset: int) -> np.ndarray:
    tris = []
    for j in range(nv):
        for i in range(nu):
            a, b = offset + i + j * (nu + 1), offset + i + 1 + j * (nu + 1)
            c, d = a + nu + 1, b + nu + 1
            tris += [(a, b, d), (a, d, c)] if (i + j) % 2 == 0 else [(a, b, c), (b, d, c)]
    return np.asarray(tris, dtype=np.int64)


def _side_vertex_ids(nu: int, nv: int, offset: int) -> dict[str, np.ndarray]:
    grid = offset + np.arange((nu + 1) * (nv + 1)).reshape(nv + 1, nu + 1)
    return {"bottom": grid[0], "top": grid[-1], "left": grid[:, 0], "right": grid[:, -1]}


@dataclasses.dataclass(frozen=True)
class PatternTopology:
    """Everything about a garment's mesh that does not depend on G (shared by a batch)."""

    garment: GarmentType
    edge_length: float
    """Target edge length at the default G [m]."""
    counts: dict[str, int]
    """Edges per segment name."""
    panel_names: tuple[str, ...]
    panel_grid: dict[str, tuple[int, int, int]]
    """Per panel: (first vertex id, nu, nv); the panel's vertices form a (nv+1, nu+1) grid."""
    tri_indices: np.ndarray
    """Triangles, int64, shape (F, 3), counter-clockwise in every panel's (u, v) frame."""
    vert_panel: np.ndarray
    """Panel index of every vertex, int64, shape (V,)."""
    segment_vertices: dict[tuple[str, str], np.ndarray]
    """Vertex ids along each (panel, segment), in the segment's direction."""
    seam_pairs: dict[str, np.ndarray]
    """Vertex id pairs of each seam, int64, shape (n, 2)."""

    @property
    def vert_count(self) -> int:
        """V."""
        return int(self.vert_panel.shape[0])

    @staticmethod
    def build(garment: GarmentType | str, edge_length: float = 0.04) -> PatternTopology:
        """Counts, grids and seams of a garment type meshed at ``edge_length`` [m]."""
        garment = _garment(garment)
        if not (math.isfinite(edge_length) and 0.005 <= edge_length <= 0.2):
            raise InputError(f"edge_length must lie in [0.005, 0.2] m, got {edge_length!r}")
        counts = _counts(garment, edge_length)
        outlines = _OUTLINES[garment](default_params(garment))
        offset = 0
        grids, tris, panels, seg_verts = {}, [], [], {}
        for p, (name, outline) in enumerate(outlines.items()):
            nu = sum(counts[s] for s, _ in outline["bottom"])
            nv = sum(counts[s] for s, _ in outline["left"])
            top = sum(counts[s] for s, _ in outline["top"])
            right = sum(counts[s] for s, _ in outline["right"])
            if (nu, nv) != (top, right):
                raise AssertionError(f"{garment}: panel {name} sides do not match")
            grids[name] = (offset, nu, nv)
            tris.append(_grid_triangles(nu, nv, offset))
            panels.append(np.full((nu + 1) * (nv + 1), p, dtype=np.int64))
            side_ids = _side_vertex_ids(nu, nv, offset)
            for side, segments in outline.items():
                pos = 0
                for seg, _ in segments:
                    k = counts[seg]
                    seg_verts[(name, seg)] = side_ids[side][pos : pos + k + 1]
                    pos += k
            offset += (nu + 1) * (nv + 1)
        pairs = {}
        for seam in _SEAMS[garment]:
            a, b = seg_verts[seam.a], seg_verts[seam.b]
            if seam.reverse:
                b = b[::-1]
            pairs[seam.name] = np.stack([a, b], -1)
        return PatternTopology(
            garment,
            float(edge_length),
            counts,
            tuple(outlines),
            grids,
            np.concatenate(tris),
            np.concatenate(panels),
            seg_verts,
            pairs,
        )

    def coords(self, params: Mapping[str, float]) -> np.ndarray:
        """Panel-frame vertex coordinates [m] for G (already checked), shape (V, 2)."""
        outlines = _OUTLINES[self.garment](params)
        out = np.empty((self.vert_count, 2))
        for name in self.panel_names:
            offset, nu, nv = self.panel_grid[name]
            side = {k: _side_points(v, self.counts) for k, v in outlines[name].items()}
            grid = _coons(side["bottom"], side["top"], side["left"], side["right"])
            out[offset : offset + (nu + 1) * (nv + 1)] = grid.reshape(-1, 2)
        return out

    def outlines(self, params: Mapping[str, float]) -> dict[str, Outline]:
        """The panels' exact outlines (segments as dense polylines) for G."""
        return _OUTLINES[self.garment](params)


@dataclasses.dataclass(frozen=True)
class Pattern:
    """One garment's pattern: topology, sizing G and the meshed panels."""

    topology: PatternTopology
    params: dict[str, float]
    """G, by name (units in :func:`param_specs`)."""
    coords: np.ndarray
    """Panel-frame vertex coordinates [m], shape (V, 2)."""

    @property
    def garment(self) -> GarmentType:
        """The garment type."""
        return self.topology.garment

    def atlas_uv(self, gap: float = 0.05) -> np.ndarray:
        """Vertex coordinates with the panels laid side by side [m], shape (V, 2)."""
        return atlas(self.topology, self.coords, gap)

    def seam_lengths(self) -> dict[str, tuple[float, float]]:
        """Length of both sides of every seam as meshed [m]."""
        out = {}
        for name, pairs in self.topology.seam_pairs.items():
            a, b = self.coords[pairs[:, 0]], self.coords[pairs[:, 1]]
            out[name] = (
                float(np.linalg.norm(np.diff(a, axis=0), axis=1).sum()),
                float(np.linalg.norm(np.diff(b, axis=0), axis=1).sum()),
            )
        return out

    def panel_areas(self) -> dict[str, float]:
        """Meshed area of each panel [m²]."""
        tri = self.topology.tri_indices
        x = self.coords
        d1, d2 = x[tri[:, 1]] - x[tri[:, 0]], x[tri[:, 2]] - x[tri[:, 0]]
        area = 0.5 * (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])
        panel = self.topology.vert_panel[tri[:, 0]]
        return {
            name: float(area[panel == p].sum()) for p, name in enumerate(self.topology.panel_names)
        }

    def to_json(self, material: Mapping | None = None) -> dict:
        """JSON form: garment, G with units, panels' outlines [m], seams, optional material."""
        specs = {p.name: p for p in param_specs(self.garment)}
        outlines = self.topology.outlines(self.params)
        return {
            "garment": self.garment.value,
            "params": {
                k: {"value": v, "unit": specs[k].unit, "doc": specs[k].doc}
                for k, v in self.params.items()
            },
            "material": dict(material) if material is not None else None,
            "edge_length": self.topology.edge_length,
            "panels": {
                name: {
                    "cut": 1,
                    "outline": _outline_loop(outlines[name]).round(5).tolist(),
                    "segments": {
                        seg: poly.round(5).tolist()
                        for segments in outlines[name].values()
                        for seg, poly in segments
                    },
                }
                for name in self.topology.panel_names
            },
            "seams": [
                {"name": s.name, "a": list(s.a), "b": list(s.b), "reverse": s.reverse}
                for s in _SEAMS[self.garment]
            ],
        }

    def to_svg(self, *, margin: float = 0.03) -> str:
        """A cuttable SVG in millimetres: outlines, seam segments dashed, labels, grain arrows."""
        outlines = self.topology.outlines(self.params)
        loops = {n: _outline_loop(outlines[n]) for n in self.topology.panel_names}
        offsets, width, height = _layout(loops, margin)
        mm = 1000.0
        seam_segments = {s for seam in _SEAMS[self.garment] for s in (seam.a, seam.b)}
        parts = [
            '<?xml version="1.0" encoding="UTF-8"?>',
            f'<svg xmlns="http://www.w3.org/2000/svg" width="{width * mm:.1f}mm" '
            f'height="{height * mm:.1f}mm" viewBox="0 0 {width * mm:.1f} {height * mm:.1f}">',
            f"<title>{self.garment.value} pattern: "
            + ", ".join(f"{k}={v:.4g}" for k, v in self.params.items())
            + "</title>",
        ]
        for name in self.topology.panel_names:
            off = offsets[name]

            def xy(p, off=off):
                # SVG's y runs down; the pattern's v runs up.
                return (p[:, 0] + off[0]) * mm, (height - (p[:, 1] + off[1])) * mm

            x, y = xy(loops[name])
            path = " ".join(f"{a:.2f},{b:.2f}" for a, b in zip(x, y, strict=True))
            parts.append(
                f'<polygon points="{path}" fill="none" stroke="black" stroke-width="0.6"/>'
            )
            for segments in outlines[name].values():
                for seg, poly in segments:
                    if (name, seg) not in seam_segments:
                        continue
                    sx, sy = xy(poly)
                    pts = " ".join(f"{a:.2f},{b:.2f}" for a, b in zip(sx, sy, strict=True))
                    parts.append(
                        f'<polyline points="{pts}" fill="none" stroke="#c03030" '
                        'stroke-width="0.8" stroke-dasharray="4,3"/>'
                    )
            cx, cy = xy(loops[name].mean(axis=0, keepdims=True))
            parts.append(
                f'<text x="{cx[0]:.1f}" y="{cy[0]:.1f}" font-size="14" text-anchor="middle">'
                f"{name} (cut 1)</text>"
            )
            parts.append(
                f'<line x1="{cx[0] - 40:.1f}" y1="{cy[0] + 20:.1f}" x2="{cx[0] + 40:.1f}" '
                f'y2="{cy[0] + 20:.1f}" stroke="black" stroke-width="0.5"/>'
            )
        parts.append("</svg>")
        return "\n".join(parts) + "\n"


def _outline_loop(outline: Outline) -> np.ndarray:
    """Closed boundary polygon of a panel, counter-clockwise [m], shape (N, 2)."""
    bottom = _chain(*(p for _, p in outline["bottom"]))
    right = _chain(*(p for _, p in outline["right"]))
    top = _chain(*(p for _, p in outline["top"]))
    left = _chain(*(p for _, p in outline["left"]))
    return _chain(bottom, right, top[::-1], left[::-1])[:-1]


def _layout(loops: Mapping[str, np.ndarray], margin: float):
    """Offsets placing panels side by side (one row), total width and height [m]."""
    offsets, x = {}, margin
    height = max(float(np.ptp(p[:, 1])) for p in loops.values()) + 2 * margin
    for name, loop in loops.items():
        lo = loop.min(axis=0)
        offsets[name] = (x - lo[0], margin - lo[1])
        x += float(np.ptp(loop[:, 0])) + margin
    return offsets, x, height


def atlas(topology: PatternTopology, coords: np.ndarray, gap: float = 0.05) -> np.ndarray:
    """Panel coordinates shifted so that panels lie side by side without overlap [m], (V, 2)."""
    out = np.array(coords, dtype=np.float64, copy=True)
    x = 0.0
    for p, _ in enumerate(topology.panel_names):
        mask = topology.vert_panel == p
        lo = out[mask].min(axis=0)
        out[mask] -= lo
        out[mask, 0] += x
        x += float(out[mask, 0].max() - x) + gap
    return out


def build_pattern(
    garment: GarmentType | str,
    params: Mapping[str, float] | None = None,
    *,
    edge_length: float = 0.04,
    topology: PatternTopology | None = None,
) -> Pattern:
    """Check G and mesh the garment's panels (``topology`` reuses a built one)."""
    garment = _garment(garment)
    g = check_params(garment, params or {})
    if topology is None:
        topology = PatternTopology.build(garment, edge_length)
    elif topology.garment is not garment:
        raise InputError(f"topology is for {topology.garment.value}, not {garment.value}")
    return Pattern(topology, g, topology.coords(g))


# --------------------------------------------------------------------- closed-form geometry


def closed_form(garment: GarmentType | str, params: Mapping[str, float]) -> dict:
    """Exact panel areas [m²] and seam lengths [m] of G (the tests' reference).

    Returns ``{"areas": {panel: area}, "seams": {seam: (length_a, length_b)}}``; only the
    panels and seams with a simple closed form are listed.
    """
    garment = _garment(garment)
    g = check_params(garment, params)
    if garment is GarmentType.SKIRT:
        l1, r1, r2, alpha = g["l1"], g["r1"], g["r2"], g["alpha"]
        hy = SKIRT_YOKE_HEIGHT
        hip = r1 * alpha
        yoke = 0.5 * (l1 + hip) * hy
        flare = 0.5 * alpha * ((r1 + r2) ** 2 - r1**2)
        side = math.hypot(hy, 0.5 * (hip - l1))
        return {
            "areas": {
                "yoke_front": yoke,
                "yoke_back": yoke,
                "flare_front": flare,
                "flare_back": flare,
            },
            "seams": {
                "yoke_side_right": (side, side),
                "side_right": (r2, r2),
                "hip_front": (hip, hip),
            },
        }
    if garment is GarmentType.TSHIRT:
        a = g["h2"] - TSHIRT_SHOULDER_DROP - g["h1"]
        sleeve = 0.5 * (2 * a + 2 * g["w1"]) * g["l1"]
        under = math.hypot(g["l1"], a - g["w1"])
        shoulder = math.hypot(g["w2"] / 2 - g["r"], TSHIRT_SHOULDER_DROP)
        return {
            "areas": {"sleeve_r": sleeve, "sleeve_l": sleeve},
            "seams": {
                "side_right": (g["h1"], g["h1"]),
                "underarm_right": (under, under),
                "shoulder_right": (shoulder, shoulder),
                "armhole_right_front": (a, a),
            },
        }
    # pants: outseam pieces are straight; the front waist is a horizontal line.
    crotch_y = g["h1"] - g["h3"]
    return {
        "areas": {},
        "seams": {
            "outseam_low_right": (crotch_y, crotch_y),
            "outseam_high_right": (g["h3"], g["h3"]),
        },
    }


def pattern_json_text(pattern: Pattern, material: Mapping | None = None) -> str:
    """:meth:`Pattern.to_json` as indented text with a trailing newline."""
    return json.dumps(pattern.to_json(material), indent=2) + "\n"
