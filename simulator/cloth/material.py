"""Measured Wang et al. (2011) fabrics, the thesis's 54-class subspace and batched materials.

How the numbers become forces (see also :mod:`simulator.energies.membrane` and
:mod:`simulator.energies.bending`):

* ``stretching`` (6 x 4, N/m): row 0 is the stiffness vector ``k = (k0, k1, k2, k3)``
  at zero strain, rows 1-5 the stiffness at a principal stretch of 7/6 for the
  principal direction at 0, 22.5, 45, 67.5 and 90 degrees to the warp. The
  membrane energy density is ``W = 1/2 (k0 G00^2 + k2 G11^2 + 2 k1 G00 G11 + k3 G01^2)``
  with the Green strain ``G`` in the (warp, weft) frame, and ``k`` blended from
  row 0 towards the angle-interpolated row by the largest principal Green strain.
  Because a few measured rows are not positive definite (negative shear, strong
  coupling), :func:`stabilize_stretching` clamps every row once at load time so
  that each row's 3 x 3 stiffness matrix is positive definite; every blend is a
  convex combination of rows, so the energy stays convex in ``G`` everywhere.
* ``bending`` (3 x 5, N*m): bending stiffness for the bend axis (edge) at 0, 45 and
  90 degrees to the warp (rows) and at curvatures 0, 10, 20, 30, 40 1/m (columns,
  ArcSim's sampling). Interpolated bilinearly per edge.
* ``density`` (kg/m^2): areal density, lumped to the vertices.

The thesis's subspace (section 7.4.2.2) multiplies the basis ``camel-ponte-roma``
stretching by ``p`` and bending by ``k``. Class ids run stretch-major,
``class_id = stretch_index * 9 + bend_index``, so a larger id is generally stiffer,
as the thesis's correlation study assumes. A :class:`MaterialSet` is such a class grid (basis
fabric and the two multiplier lists); :data:`WANG54` is the thesis's, and the module-level
functions (:func:`multipliers_from_class`, :func:`class_summary`, ...) are its methods. A
generated dataset carries its set in its spec and manifest, so training and evaluation learn
the classes from the data (``configs/material_set/``).
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
from collections.abc import Iterable, Mapping
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import torch

from common.errors import InputError
from common.grid import ClassGrid
from simulator.energies.bending import BEND_SAMPLE_CURVATURES
from simulator.energies.membrane import STRETCH_SAMPLE_STRAIN
from simulator.errors import MaterialError

__all__ = [
    "BASIS_MATERIAL",
    "BEND_MULTIPLIERS",
    "BEND_SAMPLE_CURVATURES",
    "CLASS_COUNT",
    "STRETCH_MULTIPLIERS",
    "STRETCH_SAMPLE_STRAIN",
    "WANG54",
    "ClothMaterial",
    "MaterialError",
    "MaterialSet",
    "WangMaterial",
    "check_class_ids",
    "class_from_multipliers",
    "class_summary",
    "load_wang_material",
    "multipliers_from_class",
    "nearest_class",
    "stabilize_stretching",
    "wang_material_names",
]

BASIS_MATERIAL = "camel-ponte-roma"
STRETCH_MULTIPLIERS: tuple[float, ...] = (0.5, 1.0, 2.0, 3.0, 10.0, 20.0)
BEND_MULTIPLIERS: tuple[float, ...] = (0.5, 1.0, 2.0, 3.0, 4.0, 5.0, 10.0, 15.0, 20.0)
CLASS_COUNT = len(STRETCH_MULTIPLIERS) * len(BEND_MULTIPLIERS)

_COUPLING_LIMIT = 0.95  # |k1| <= limit * sqrt(k0 k2)
_SHEAR_FLOOR = 0.05  # k3 >= floor * min(k0, k2)


@dataclasses.dataclass(frozen=True)
class WangMaterial:
    """One measured fabric, unchanged from its JSON file."""

    name: str
    density: float
    """Areal density [kg/m²]."""
    stretching: np.ndarray
    """Membrane stiffness rows [N/m], shape (6, 4)."""
    bending: np.ndarray
    """Bending stiffness samples [N·m], shape (3, 5)."""


def _data_dir() -> Path:
    return Path(str(resources.files("simulator") / "data" / "wang2011_materials"))


def wang_material_names() -> tuple[str, ...]:
    """Names of the ten shipped fabrics, sorted."""
    return tuple(sorted(p.stem for p in _data_dir().glob("*.json")))


def load_wang_material(name_or_path: str | Path) -> WangMaterial:
    """Load a fabric by shipped name or from a JSON file path, validating every field.

    Raises:
        MaterialError: unknown name, unreadable/malformed JSON, missing field,
            wrong shape, non-finite numbers, non-positive density.
    """
    path = Path(name_or_path)
    if path.suffix != ".json":
        names = wang_material_names()
        if str(name_or_path) not in names:
            raise MaterialError(f"material: unknown name {name_or_path!r}; allowed: {names}")
        path = _data_dir() / f"{name_or_path}.json"
    try:
        raw = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as err:
        raise MaterialError(f"material file {path}: cannot read JSON ({err})") from err
    if not isinstance(raw, dict):
        raise MaterialError(f"material file {path}: top level must be an object")
    for key, shape in (("stretching", (6, 4)), ("bending", (3, 5))):
        if key not in raw:
            raise MaterialError(f"material file {path}: missing field {key!r}")
        try:
            arr = np.asarray(raw[key], dtype=np.float64)
        except (TypeError, ValueError) as err:
            raise MaterialError(f"material file {path}: field {key!r} is not numeric") from err
        if arr.shape != shape:
            raise MaterialError(
                f"material file {path}: field {key!r} must have shape {shape}, got {arr.shape}"
            )
        if not np.isfinite(arr).all():
            raise MaterialError(f"material file {path}: field {key!r} has non-finite values")
    density = raw.get("density")
    if not isinstance(density, int | float) or not math.isfinite(density) or density <= 0:
        raise MaterialError(
            f"material file {path}: field 'density' must be > 0 kg/m², got {density!r}"
        )
    stretching = np.asarray(raw["stretching"], dtype=np.float64)
    if np.any(stretching[:, [0, 2]] <= 0):
        raise MaterialError(f"material file {path}: field 'stretching' needs k0, k2 > 0 N/m")
    bending = np.asarray(raw["bending"], dtype=np.float64)
    if np.any(bending < 0):
        raise MaterialError(f"material file {path}: field 'bending' must be >= 0 N·m")
    return WangMaterial(path.stem, float(density), stretching, bending)


def stabilize_stretching(stretching: np.ndarray) -> np.ndarray:
    """Clamp each stiffness row so its membrane stiffness matrix is positive definite.

    ``|k1| <= 0.95 sqrt(k0 k2)`` and ``k3 >= 0.05 min(k0, k2)``; other entries unchanged.
    """
    out = np.array(stretching, dtype=np.float64, copy=True)
    limit = _COUPLING_LIMIT * np.sqrt(out[:, 0] * out[:, 2])
    out[:, 1] = np.clip(out[:, 1], -limit, limit)
    out[:, 3] = np.maximum(out[:, 3], _SHEAR_FLOOR * np.minimum(out[:, 0], out[:, 2]))
    return out


def _nearest_log(value: float, choices: tuple[float, ...]) -> float:
    return min(choices, key=lambda c: abs(math.log(value) - math.log(c)))


def _effective_stretch(stretching: np.ndarray) -> float:
    """Mean warp/weft tension stiffness over all six rows [N/m]."""
    return float(0.5 * (stretching[:, 0] + stretching[:, 2]).mean())


MATERIAL_SET_FIELDS = ("name", "basis", "stretch_multipliers", "bend_multipliers")
OPTIONAL_FIELDS = ("density_multipliers",)
"""Fields a set may leave out: one density (the basis's) without ``density_multipliers``."""
GRID_FIELDS = ("num_classes", "stretch_count", "bend_count", "density_count")
"""The grid's counts, written by :meth:`MaterialSet.to_json` beside the fields (checked when
read back)."""


def _multiplier_list(values: Any, field: str) -> tuple[float, ...]:
    """``values`` as floats if they form a non-empty, strictly increasing list of numbers > 0."""
    numbers: tuple[float, ...] = ()
    if isinstance(values, Iterable) and not isinstance(values, str | bytes | Mapping):
        items = list(values)
        if all(isinstance(v, int | float | np.number) and not isinstance(v, bool) for v in items):
            numbers = tuple(float(v) for v in items)
    valid = bool(numbers) and all(math.isfinite(v) and v > 0 for v in numbers)
    if not valid or any(a >= b for a, b in itertools.pairwise(numbers)):
        raise MaterialError(
            f"{field} must be a non-empty, strictly increasing list of numbers > 0, got {values!r}"
        )
    return numbers


@dataclasses.dataclass(frozen=True)
class MaterialSet:
    """The classes of a dataset: one basis fabric with its stretching x p and bending x k.

    Class ids run stretch-major over the grid of the multiplier lists,
    ``class_id = (stretch_index * bend_count + bend_index) * density_count + density_index``;
    every list is strictly increasing, so a larger id is generally stiffer. The areal density
    is the basis's times each of ``density_multipliers`` (default: the basis's alone, the
    thesis's 54 classes, where ``class_id = stretch_index * bend_count + bend_index``).
    """

    name: str
    """Short name, e.g. ``wang54`` (``configs/material_set/<name>.yaml``)."""
    basis: str
    """A shipped fabric (:func:`wang_material_names`) whose stretching and bending are scaled."""
    stretch_multipliers: tuple[float, ...]
    """p of each stretch index, increasing."""
    bend_multipliers: tuple[float, ...]
    """k of each bend index, increasing."""
    density_multipliers: tuple[float, ...] = (1.0,)
    """q of each density index, increasing: the class's areal density is the basis's x q."""

    def __post_init__(self):
        if not isinstance(self.name, str) or not self.name.strip():
            raise MaterialError(f"material_set.name must be a non-empty name, got {self.name!r}")
        if self.basis not in wang_material_names():
            raise MaterialError(
                f"material_set.basis must be one of {wang_material_names()}, got {self.basis!r}"
            )
        for field in ("stretch_multipliers", "bend_multipliers", "density_multipliers"):
            numbers = _multiplier_list(getattr(self, field), f"material_set.{field}")
            object.__setattr__(self, field, numbers)

    @property
    def grid(self) -> ClassGrid:
        """The stretch x bend x density grid of class ids, as a classifier sees it."""
        return ClassGrid(self.stretch_multipliers, self.bend_multipliers, self.density_multipliers)

    @property
    def stretch_count(self) -> int:
        """Stretch indices (rows of the grid)."""
        return self.grid.stretch_count

    @property
    def bend_count(self) -> int:
        """Bend indices (columns of the grid)."""
        return self.grid.bend_count

    @property
    def density_count(self) -> int:
        """Density indices (1 unless ``density_multipliers`` has more)."""
        return self.grid.density_count

    @property
    def num_classes(self) -> int:
        """Classes: ``stretch_count * bend_count * density_count``."""
        return self.grid.num_classes

    def to_json(self) -> dict:
        """Plain JSON: the fields and the grid's counts (a manifest's ``material_set``)."""
        return {"name": self.name, "basis": self.basis, **self.grid.to_json()}

    @classmethod
    def from_json(cls, data: Any, field: str = "material_set") -> MaterialSet:
        """A set from :meth:`to_json`'s form or a config node's fields (counts optional).

        Raises:
            MaterialError: naming ``field`` and its first missing, unknown or bad entry.
        """
        if not isinstance(data, Mapping):
            raise MaterialError(f"{field} must be a mapping with {list(MATERIAL_SET_FIELDS)}")
        unknown = sorted(set(data) - {*MATERIAL_SET_FIELDS, *OPTIONAL_FIELDS, *GRID_FIELDS})
        missing = [k for k in MATERIAL_SET_FIELDS if k not in data]
        if unknown or missing:
            raise MaterialError(
                f"{field} needs {list(MATERIAL_SET_FIELDS)}; unknown {unknown}, missing {missing}"
            )
        try:
            optional = {k: data[k] for k in OPTIONAL_FIELDS if k in data}
            out = cls(*(data[k] for k in MATERIAL_SET_FIELDS), **optional)
        except MaterialError as err:
            raise MaterialError(str(err).replace("material_set", field, 1)) from None
        stored = {k: data[k] for k in GRID_FIELDS if k in data}
        counts = {**out.to_json(), "density_count": out.density_count}
        grid = {k: v for k, v in counts.items() if k in stored}
        if stored != grid:
            raise MaterialError(f"{field}: counts {stored} do not match its multipliers {grid}")
        return out

    def position(self, class_id: int) -> tuple[int, int, int]:
        """(stretch index, bend index, density index) of a class id."""
        try:
            return self.grid.position(class_id)
        except ValueError as err:
            raise MaterialError(str(err)) from None

    def multipliers(self, class_id: int) -> tuple[float, float]:
        """(stretch multiplier p, bend multiplier k) of a class id."""
        s, b, _ = self.position(class_id)
        return self.stretch_multipliers[s], self.bend_multipliers[b]

    def density_mult(self, class_id: int) -> float:
        """Density multiplier q of a class id (1.0 in a set of one density)."""
        return self.density_multipliers[self.position(class_id)[2]]

    def class_of(self, stretch_mult: float, bend_mult: float, density_mult: float = 1.0) -> int:
        """Class id of an exact (p, k, q) triple of the grid (q = 1 in a set of one density)."""
        try:
            s = self.stretch_multipliers.index(float(stretch_mult))
            b = self.bend_multipliers.index(float(bend_mult))
            d = self.density_multipliers.index(float(density_mult))
        except ValueError as err:
            raise MaterialError(
                f"(stretch_mult, bend_mult, density_mult) = ({stretch_mult}, {bend_mult}, "
                f"{density_mult}) is not in the subspace; allowed stretch "
                f"{self.stretch_multipliers}, bend {self.bend_multipliers}, density "
                f"{self.density_multipliers}"
            ) from err
        return self.grid.class_id(s, b, d)

    def nearest(
        self, stretch_ratio: float, bend_ratio: float, density_ratio: float = 1.0
    ) -> tuple[int, float, float]:
        """Quantise estimated ratios to the grid (nearest in log scale): (class id, p, k)."""
        p = _nearest_log(stretch_ratio, self.stretch_multipliers)
        k = _nearest_log(bend_ratio, self.bend_multipliers)
        q = _nearest_log(density_ratio, self.density_multipliers)
        return self.class_of(p, k, q), p, k

    def summary(self, class_id: int, basis: WangMaterial | None = None) -> dict[str, float]:
        """Physical summary values of a class (see :func:`class_summary`)."""
        basis = basis or load_wang_material(self.basis)
        p, k = self.multipliers(class_id)
        q = self.density_mult(class_id)
        return {
            "class_id": int(class_id),
            "stretch_mult": p,
            "bend_mult": k,
            "density_mult": q,
            "stretch_stiffness": p * _effective_stretch(basis.stretching),
            "bend_stiffness": k * float(basis.bending.mean()),
            "density": q * basis.density,
        }

    def materials(self, class_ids, *, dtype: torch.dtype = torch.float64) -> ClothMaterial:
        """Batch of classes: the basis fabric times each class's (p, k)."""
        # Integral floats (1.0) name a class; others (1.7) are refused, never truncated.
        ids = [
            int(c) if isinstance(c, float) and c.is_integer() else c
            for c in np.atleast_1d(np.asarray(class_ids)).tolist()
        ]
        pk = [self.multipliers(c) for c in ids]
        return ClothMaterial.from_wang(
            load_wang_material(self.basis),
            stretch_mult=[p for p, _ in pk],
            bend_mult=[k for _, k in pk],
            density_mult=[self.density_mult(c) for c in ids],
            dtype=dtype,
        )

    def check_class_ids(self, values: Any, field: str = "classes") -> tuple[int, ...]:
        """Class ids as ints; refuses a non-list, text and non-integral numbers.

        ``1.0`` is class 1; ``1.7`` is refused rather than truncated to class 1.
        """
        top = self.num_classes - 1
        allowed = f"integer class ids in [0, {top}], e.g. {field}=[0,{top // 2},{top}]"
        if isinstance(values, str | bytes | Mapping) or not isinstance(values, Iterable):
            raise InputError(f"{field} must be a list of {allowed}; got {values!r}")
        ids = []
        for position, value in enumerate(values):
            integral = isinstance(value, int) or (isinstance(value, float) and value.is_integer())
            if isinstance(value, bool) or not integral or not 0 <= value <= top:
                raise InputError(
                    f"{field}[{position}] must be an integer class id in [0, {top}], got {value!r}"
                )
            ids.append(int(value))
        if not ids:
            raise InputError(f"{field} must be a non-empty list of {allowed}; got []")
        return tuple(ids)


WANG54 = MaterialSet("wang54", BASIS_MATERIAL, STRETCH_MULTIPLIERS, BEND_MULTIPLIERS)
"""The thesis's 54 classes (``configs/material_set/wang54.yaml``); also the set of every
dataset and checkpoint written before the sets travelled with the data."""


def multipliers_from_class(class_id: int) -> tuple[float, float]:
    """(stretch multiplier p, bend multiplier k) of a class id in [0, 53]."""
    return WANG54.multipliers(class_id)


def class_from_multipliers(stretch_mult: float, bend_mult: float) -> int:
    """Class id of an exact (p, k) pair of the subspace."""
    return WANG54.class_of(stretch_mult, bend_mult)


def nearest_class(stretch_ratio: float, bend_ratio: float) -> tuple[int, float, float]:
    """Quantise estimated ratios to the subspace (nearest in log scale).

    Returns:
        (class id, p, k).
    """
    return WANG54.nearest(stretch_ratio, bend_ratio)


def class_summary(class_id: int, basis: WangMaterial | None = None) -> dict[str, float]:
    """Physical summary values of a class, for correlation with real measurements.

    ``stretch_stiffness`` [N/m] is p times the basis's mean warp/weft tension
    stiffness over its six rows; ``bend_stiffness`` [N·m] is k times the mean of
    its fifteen bending samples; ``density`` [kg/m²] is the basis's (the subspace
    does not vary density).
    """
    return WANG54.summary(class_id, basis)


@dataclasses.dataclass(frozen=True)
class ClothMaterial:
    """Per-instance cloth material parameters (the batch lives here)."""

    stretching: torch.Tensor
    """Stabilised membrane stiffness rows [N/m], shape (B, 6, 4)."""
    bending: torch.Tensor
    """Bending stiffness samples [N·m], shape (B, 3, 5)."""
    density: torch.Tensor
    """Areal density [kg/m²], shape (B,)."""

    @property
    def batch_size(self) -> int:
        """B."""
        return int(self.density.shape[0])

    def to(self, device=None, dtype=None) -> ClothMaterial:
        """Copy to ``device`` / ``dtype``."""
        return ClothMaterial(*(t.to(device=device, dtype=dtype) for t in dataclasses.astuple(self)))

    @staticmethod
    def from_wang(
        materials: list[WangMaterial] | WangMaterial,
        *,
        stretch_mult: list[float] | float = 1.0,
        bend_mult: list[float] | float = 1.0,
        density_mult: list[float] | float = 1.0,
        dtype: torch.dtype = torch.float64,
    ) -> ClothMaterial:
        """Batch fabrics with per-instance multipliers (broadcast to a common length)."""
        mats = [materials] if isinstance(materials, WangMaterial) else list(materials)
        ps = np.atleast_1d(np.asarray(stretch_mult, dtype=np.float64))
        ks = np.atleast_1d(np.asarray(bend_mult, dtype=np.float64))
        qs = np.atleast_1d(np.asarray(density_mult, dtype=np.float64))
        batch = max(len(mats), len(ps), len(ks), len(qs))
        for name, n in (
            ("materials", len(mats)),
            ("stretch_mult", len(ps)),
            ("bend_mult", len(ks)),
            ("density_mult", len(qs)),
        ):
            if n not in (1, batch):
                raise MaterialError(f"{name}: length {n} does not broadcast to batch {batch}")
        for name, arr in (("stretch_mult", ps), ("bend_mult", ks), ("density_mult", qs)):
            if not np.all(np.isfinite(arr)) or np.any(arr <= 0):
                raise MaterialError(f"{name} must be > 0, got {arr.tolist()}")
        mats = mats * batch if len(mats) == 1 else mats
        ps = np.broadcast_to(ps, (batch,))
        ks = np.broadcast_to(ks, (batch,))
        qs = np.broadcast_to(qs, (batch,))
        pairs = zip(mats, ps, strict=True)
        stretching = np.stack([stabilize_stretching(m.stretching) * p for m, p in pairs])
        bending = np.stack([m.bending * k for m, k in zip(mats, ks, strict=True)])
        density = np.array([m.density * q for m, q in zip(mats, qs, strict=True)])
        return ClothMaterial(
            torch.as_tensor(stretching, dtype=dtype),
            torch.as_tensor(bending, dtype=dtype),
            torch.as_tensor(density, dtype=dtype),
        )

    @staticmethod
    def from_classes(class_ids, *, dtype: torch.dtype = torch.float64) -> ClothMaterial:
        """Batch of subspace classes (basis ``camel-ponte-roma`` times (p, k))."""
        return WANG54.materials(class_ids, dtype=dtype)


def check_class_ids(values: Any, field: str = "classes") -> tuple[int, ...]:
    """Subspace class ids as ints; refuses a non-list, text and non-integral numbers.

    ``1.0`` is class 1; ``1.7`` is refused rather than truncated to class 1.
    """
    return WANG54.check_class_ids(values, field)
