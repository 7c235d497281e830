"""Monocular reconstruction of elastic surfaces (Haouchine et al., the paper §4-§9).

Edge-based St Venant-Kirchhoff sheet (:mod:`.stvk`), image fitting through a pinhole camera
(:mod:`.image_fit`, :mod:`.camera`), features and eq. 21 selection (:mod:`.features`), the
per-frame warm-started solve (:mod:`.solve`, :mod:`.reconstruct`), baselines (:mod:`.linear`)
and the synthetic ground truth (:mod:`.synthetic`). The paper's Table 1 benchmark is
:mod:`benchmarks.thesis.monocular_benchmark`.
"""

from .camera import PinholeCamera, look_at
from .features import FeatureSet, locate_features, select_features
from .image_fit import EnergyImageFit
from .linear import EnergySheetLinear, sheet_mass_spring
from .material import SheetMaterial
from .reconstruct import ElasticModelKind, MonocularReconstructor, ReconstructionResult
from .sheet import crossed_grid
from .stvk import EnergySheetStVK

__all__ = [
    "ElasticModelKind",
    "EnergyImageFit",
    "EnergySheetLinear",
    "EnergySheetStVK",
    "FeatureSet",
    "MonocularReconstructor",
    "PinholeCamera",
    "ReconstructionResult",
    "SheetMaterial",
    "crossed_grid",
    "locate_features",
    "look_at",
    "select_features",
    "sheet_mass_spring",
]
