"""What a generated dataset is: one frozen, validated spec (thesis 7.6-7.7.1, Table 7.2).

A :class:`DatasetSpec` fixes everything that decides the bytes of a dataset: the motion
(scene), mesh resolution, texture mode, backdrop, physical and visual effect switches, size,
solver settings, image size, seed and the material set (the class grid). Its JSON form goes
into the manifest; its hashes decide whether an existing output directory or mesh cache
belongs to the same dataset.

Size. The thesis generates 2,592 ten-frame clips per (motion, remeshing, texture) setting
and tests on 432 of them. Our ``full`` preset makes the same numbers with splits that hold
out whole simulations: 12 simulations per class x 4 clips each = 48 clips per class; per
class 9 simulations train, 1 validates, 2 test (2 x 4 x 54 = 432 test clips).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import typing
from typing import Any

import numpy as np

from render.backgrounds import BACKDROPS
from render.camera import CameraSpec
from render.effects import VisualEffects, source_frame_count
from render.lights import LightSpec
from render.textures import TextureMode
from simulator.cloth.effects import PhysicsEffects
from simulator.cloth.material import WANG54, MaterialSet
from simulator.cloth.rollout import SimSettings
from simulator.cloth.scenes import ScenarioArmBend, ScenarioWind

__all__ = ["MOTIONS", "PRESETS", "DatasetSpec", "SizePreset", "check_int", "physics_key_of"]

MOTIONS = {"wind": ScenarioWind, "arm": ScenarioArmBend}
"""Motion name -> scene class."""

SPLITS = ("train", "val", "test")

_LATER_VISUAL_FIELDS = (
    ("vignetting", "vignetting_strength"),
    ("rolling_shutter", "rolling_shutter_readout", "rolling_shutter_bands"),
)
"""Visual-effect fields added after datasets were made, by the effect they came with:
:meth:`DatasetSpec.to_json` leaves each group out while it is at its defaults, so those
datasets (and sets with the earlier ones on) keep their keys."""
_DEFAULT_VISUAL = VisualEffects()
_LATER_PHYSICS_FIELDS = (
    ("isotropic_drag", "drag_isotropy"),
    ("density_variation", "density_spread"),
)
"""Physical-effect fields added after datasets were made, left out of the JSON likewise."""
_DEFAULT_PHYSICS = PhysicsEffects()


def check_int(name: str, value, low: int = 1) -> int:
    """``value`` if it is an integer >= ``low``; else a ValueError naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")
    return value


@dataclasses.dataclass(frozen=True)
class SizePreset:
    """How many simulations and clips per class, and how clips are cut from a simulation."""

    name: str
    sims_per_class: int
    clips_per_sim: int
    val_sims_per_class: int
    test_sims_per_class: int
    frames_per_clip: int = 10
    """Thesis: each sequence consists of 10 frames."""
    fps: float = 15.0
    """Recorded (and rendered) frames per second: 10 frames span 0.67 s, about one flap of
    the cloth in W2 wind; real footage is resampled to this rate by the real-video loader."""

    def __post_init__(self):
        for name in ("sims_per_class", "clips_per_sim", "frames_per_clip"):
            check_int(f"preset.{name}", getattr(self, name))
        for name in ("val_sims_per_class", "test_sims_per_class"):
            check_int(f"preset.{name}", getattr(self, name), low=0)
        held_out = self.val_sims_per_class + self.test_sims_per_class
        if held_out >= self.sims_per_class:
            raise ValueError(
                f"preset: val_sims_per_class + test_sims_per_class ({held_out}) must be < "
                f"sims_per_class ({self.sims_per_class}) so every class has training simulations"
            )
        if not self.fps > 0:
            raise ValueError(f"preset.fps must be > 0, got {self.fps}")

    @property
    def clips_per_class(self) -> int:
        """Clips of each class over all splits."""
        return self.sims_per_class * self.clips_per_sim


PRESETS = {
    "full": SizePreset(
        "full", sims_per_class=12, clips_per_sim=4, val_sims_per_class=1, test_sims_per_class=2
    ),
    "small": SizePreset(
        "small", sims_per_class=4, clips_per_sim=2, val_sims_per_class=1, test_sims_per_class=1
    ),
}
"""``full`` = the thesis's 2,592 clips per setting; ``small`` = 432 clips for quick runs."""


def _is_integral(value: Any) -> bool:
    """An int, or a float with an integer value (not a bool, not text)."""
    if isinstance(value, bool | np.bool_):
        return False
    if isinstance(value, int | np.integer):
        return True
    return isinstance(value, float | np.floating) and float(value).is_integer()


def _jsonable(value: Any) -> Any:
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        out = {f.name: _jsonable(getattr(value, f.name)) for f in dataclasses.fields(value)}
        return out
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    if isinstance(value, str):
        return str(value)  # StrEnum -> plain str
    return value


def _from_plain(cls, values: Any):
    """Instantiate dataclass ``cls`` from plain JSON, recursing into dataclass-typed fields."""
    if dataclasses.is_dataclass(values):
        return values
    if not isinstance(values, dict):
        raise ValueError(f"{cls.__name__}: expected a mapping, got {values!r}")
    hints = typing.get_type_hints(cls)
    fields = {f.name for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(values) - fields)
    if unknown:
        raise ValueError(f"{cls.__name__}: unknown {unknown}; allowed: {sorted(fields)}")
    kwargs = {}
    for name, value in values.items():
        hint = hints[name]
        if isinstance(hint, type) and dataclasses.is_dataclass(hint):
            value = _from_plain(hint, value)
        elif typing.get_origin(hint) is tuple or hint is tuple:
            value = tuple(value)
        kwargs[name] = value
    return cls(**kwargs)


def _digest(payload: Any) -> str:
    text = json.dumps(_jsonable(payload), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


PHYSICS_KEYS = (
    "motion",
    "scenario",
    "preset",
    "classes",
    "seed",
    "lead_in",
    "sim",
    "physics",
    "sims_per_unit",
)
"""The spec entries that decide the simulated meshes (and so the mesh cache folder); a
``material_set`` other than :data:`~simulator.cloth.material.WANG54` decides them too."""


def physics_key_of(spec_json: dict) -> str:
    """Mesh-cache key of a spec in its JSON form (e.g. a manifest's ``spec``)."""
    keys = (*PHYSICS_KEYS, "material_set") if "material_set" in spec_json else PHYSICS_KEYS
    return _digest({k: spec_json[k] for k in keys})


@dataclasses.dataclass(frozen=True)
class DatasetSpec:
    """Everything that determines a generated dataset's bytes."""

    motion: str
    """``wind`` or ``arm`` (thesis 7.4.3)."""
    scenario: ScenarioWind | ScenarioArmBend
    preset: SizePreset
    texture_mode: str = dataclasses.field(
        default="random", metadata={"choices": tuple(m.value for m in TextureMode)}
    )
    """``grid``, ``color`` or ``random`` (Table 7.2's texture column)."""
    classes: tuple[int, ...] | None = None
    """Class ids of ``material_set`` to simulate (``None``: all of them)."""
    seed: int = 0
    lead_in: float = 0.0
    """Recorded time dropped before the first clip [s] (the wind scene's ramp-in)."""
    sim: SimSettings = dataclasses.field(default_factory=SimSettings)
    physics: PhysicsEffects = dataclasses.field(default_factory=PhysicsEffects)
    camera: CameraSpec = dataclasses.field(default_factory=CameraSpec.wind)
    lights: LightSpec = dataclasses.field(default_factory=LightSpec.default)
    visual: VisualEffects = dataclasses.field(default_factory=VisualEffects)
    supersample: int = 1
    texture_size: int = 256
    store_coverage: bool = True
    """Keep the renderer's cloth coverage (alpha) of every frame in the shards, so that
    training can swap backgrounds (:class:`datasets.augment.BackgroundSwap`)."""
    store_passes: bool = False
    """Also keep the render passes (:mod:`render.passes`) and each clip's background, so that
    training can re-texture the cloth (:class:`datasets.augment.TextureSwap`); rendering
    takes four times as long and the shards grow about fourfold."""
    sims_per_unit: int = 0
    """Simulations batched into one work unit (one rollout, one set of shards); 0 = all
    classes of one simulation index."""
    material_set: MaterialSet = WANG54
    """The classes: basis fabric and the stretch x bend multiplier grid (the labels' meaning,
    written into the manifest for training and evaluation)."""
    backdrop: str = dataclasses.field(default="bank", metadata={"choices": tuple(BACKDROPS)})
    """What the cloth is filmed in front of, drawn per simulation from its seed
    (:data:`render.backgrounds.BACKDROPS`): ``bank`` (the procedural rooms, gradients and
    shapes of the background bank), ``plain`` (one muted uniform colour), ``dark`` (a dark
    studio backdrop) or ``gradient``."""

    def __post_init__(self):
        if self.motion not in MOTIONS:
            raise ValueError(f"motion must be one of {sorted(MOTIONS)}, got {self.motion!r}")
        expected = MOTIONS[self.motion]
        if not isinstance(self.scenario, expected):
            raise ValueError(
                f"scenario must be a {expected.__name__} for motion {self.motion!r}, "
                f"got {type(self.scenario).__name__}"
            )
        try:
            TextureMode(self.texture_mode)
        except ValueError:
            raise ValueError(
                f"texture_mode must be one of {[m.value for m in TextureMode]}, "
                f"got {self.texture_mode!r}"
            ) from None
        if not isinstance(self.backdrop, str) or self.backdrop not in BACKDROPS:
            raise ValueError(f"backdrop must be one of {list(BACKDROPS)}, got {self.backdrop!r}")
        if not isinstance(self.material_set, MaterialSet):
            raise ValueError(f"material_set must be a MaterialSet, got {self.material_set!r}")
        count = self.material_set.num_classes
        classes = tuple(range(count)) if self.classes is None else tuple(self.classes)
        if not all(_is_integral(c) for c in classes):  # 1.7 is refused, never truncated
            raise ValueError(
                f"classes must be integer class ids in [0, {count - 1}], got {list(classes)}"
            )
        classes = tuple(int(c) for c in classes)
        if not classes or len(set(classes)) != len(classes):
            raise ValueError(f"classes must be a non-empty list without repeats, got {classes}")
        bad = [c for c in classes if not 0 <= c < count]
        if bad:
            raise ValueError(f"classes must be in [0, {count - 1}], got {bad}")
        object.__setattr__(self, "classes", classes)
        check_int("seed", self.seed, low=0)
        if not self.lead_in >= 0:
            raise ValueError(f"lead_in must be >= 0 s, got {self.lead_in}")
        check_int("supersample", self.supersample)
        check_int("texture_size", self.texture_size, low=8)
        check_int("sims_per_unit", self.sims_per_unit, low=0)
        if not isinstance(self.store_coverage, bool):
            raise ValueError(
                f"render.store_coverage must be true or false, got {self.store_coverage!r}"
            )
        if not isinstance(self.store_passes, bool):
            raise ValueError(
                f"render.store_passes must be true or false, got {self.store_passes!r}"
            )
        if self.store_passes and not self.store_coverage:
            raise ValueError("render.store_passes=true needs render.store_coverage=true")
        if self.store_passes and self.visual.frame_rate:
            raise ValueError("render.store_passes=true needs render.effects.frame_rate=false")
        for name, cls in (
            ("preset", SizePreset),
            ("sim", SimSettings),
            ("physics", PhysicsEffects),
            ("camera", CameraSpec),
            ("lights", LightSpec),
            ("visual", VisualEffects),
        ):
            if not isinstance(getattr(self, name), cls):
                raise ValueError(f"{name} must be a {cls.__name__}, got {getattr(self, name)!r}")

    # ------------------------------------------------------------------ derived sizes

    @property
    def lead_in_frames(self) -> int:
        """Recorded frames dropped before the first clip."""
        return round(self.lead_in * self.preset.fps)

    @property
    def frames_per_sim(self) -> int:
        """Frames recorded per simulation: the lead-in, then all clips back to back.

        The clips are counted at the camera's frame rate: a slower camera (``frame_rate``)
        needs more recorded frames for its ``clips_per_sim`` x ``frames_per_clip`` frames.
        """
        return self.lead_in_frames + self.video_source_frames

    @property
    def video_source_frames(self) -> int:
        """Recorded frames after the lead-in that the camera turns into all clips."""
        frames = self.preset.clips_per_sim * self.preset.frames_per_clip
        if self.visual.frame_rate:
            return source_frame_count(frames, self.visual.frame_rate_ratio)
        return frames

    def clip_start_frame(self, clip_index: int) -> int:
        """The recorded frame at (or just before) which clip ``clip_index`` starts."""
        first = clip_index * self.preset.frames_per_clip
        if self.visual.frame_rate:
            return self.lead_in_frames + int(first / self.visual.frame_rate_ratio + 1e-9)
        return self.lead_in_frames + first

    @property
    def record_time(self) -> float:
        """Recorded time per simulation after settling [s] (frame 0 is the rest state)."""
        return (self.frames_per_sim - 1) / self.preset.fps

    @property
    def unit_size(self) -> int:
        """Simulations per work unit."""
        return self.sims_per_unit or len(self.classes)

    @property
    def clip_count(self) -> int:
        """Clips in the whole dataset."""
        return len(self.classes) * self.preset.clips_per_class

    # ------------------------------------------------------------------ identity

    def to_json(self) -> dict:
        """Plain-JSON form (goes into the manifest).

        ``store_passes`` appears only when on, ``backdrop`` only when it is not ``bank`` and
        ``material_set`` only when it is not :data:`~simulator.cloth.material.WANG54` (its
        ``density_multipliers`` only when they are not the basis's density alone), so
        datasets made before they existed keep their keys (and resume); :meth:`from_json`
        reads a missing backdrop as ``bank`` and a missing set as ``WANG54``. The
        Newton loop's ``whole_step`` (same arithmetic, one compiled call) appears only when
        off, and each group of effect fields added later (:data:`_LATER_VISUAL_FIELDS`,
        :data:`_LATER_PHYSICS_FIELDS`) only when one of its fields is off its default, for the
        same reason.
        """
        out = _jsonable(self) | {"scenario_class": type(self.scenario).__name__}
        if not self.store_passes:
            del out["store_passes"]
        if self.backdrop == "bank":
            del out["backdrop"]
        if out["sim"]["newton"].get("whole_step", True):
            del out["sim"]["newton"]["whole_step"]
        if self.material_set == WANG54:
            del out["material_set"]
        elif self.material_set.density_multipliers == (1.0,):  # the keys of a 2-axis set
            del out["material_set"]["density_multipliers"]
        for part, groups, default in (
            ("visual", _LATER_VISUAL_FIELDS, _DEFAULT_VISUAL),
            ("physics", _LATER_PHYSICS_FIELDS, _DEFAULT_PHYSICS),
        ):
            for group in groups:  # absent while all default
                if all(out[part][n] == _jsonable(getattr(default, n)) for n in group):
                    for name in group:
                        del out[part][name]
        return out

    @classmethod
    def from_json(cls, data: dict) -> DatasetSpec:
        """Rebuild a spec from :meth:`to_json`'s form (e.g. a manifest's or ``spec.json``'s).

        Round trip: ``DatasetSpec.from_json(spec.to_json()) == spec`` (same :meth:`key`), so a
        tool can regenerate (variants of) the data a model was trained on.
        """
        data = dict(data)
        scenario_class = data.pop("scenario_class", None)
        known = {type_.__name__: type_ for type_ in MOTIONS.values()}
        if scenario_class not in known:
            raise ValueError(
                f"spec.scenario_class must be one of {sorted(known)}, got {scenario_class!r}"
            )
        data["scenario"] = _from_plain(known[scenario_class], data.get("scenario", {}))
        return _from_plain(cls, data)

    def physics_key(self) -> str:
        """Hash of what decides the simulated meshes (not the rendering)."""
        return physics_key_of(self.to_json())

    def key(self) -> str:
        """Hash of the whole spec (decides the shards' bytes)."""
        return _digest(self.to_json())

    def enabled_effects(self) -> list[str]:
        """Names of the effect switches that differ from their defaults, physical then visual."""
        out = []
        for group, obj in (("physics", self.physics), ("visual", self.visual)):
            default = type(obj)()
            for name, on in obj.enabled().items():
                if on != getattr(default, name):
                    out.append(f"{group}.{name}={'on' if on else 'off'}")
        return out
