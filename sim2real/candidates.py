"""The candidate library: every effect switch and scene parameter the diagnosis can try.

Candidates are read from the registries' dataclass fields, so a switch added to
:class:`simulator.cloth.effects.PhysicsEffects` or :class:`render.effects.VisualEffects` becomes a
candidate with no change here:

* a ``bool`` field is a switch; the candidate sets it to the opposite of its default (most
  effects are off by default; ``strain_dependent_stiffness`` and ``anisotropic_stiffness``
  are on, so their candidate is "the real cloth lacks it");
* a field whose metadata says ``strength_of=<switch>`` and ``plausible=(low, high)`` is that
  switch's strength, fitted within the plausible range; a switch without one is binary;
* a scenario field with ``plausible`` (a number) or ``choices`` metadata is a **scene**
  candidate: something the user may not have matched when filming;
* a :class:`~datasets.spec.DatasetSpec` field with ``choices`` metadata is a **look**
  candidate: a choice the training data fixed and real footage varies (the cloth's texture
  family ``texture_mode``, the ``backdrop``); it re-renders the cached meshes.

Stages (where in the pipeline the effect acts): ``scene``, ``physics`` (the simulator),
``appearance`` (the renderer's lighting and shading, the cloth's texture and the backdrop) and
``camera`` (the image pipeline), the visual switches' from their ``stage`` metadata.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable

import numpy as np

from common.commands import hydra_command
from datasets.spec import DatasetSpec
from render.effects import IMAGE_EFFECT_ORDER, VisualEffects
from simulator.cloth.effects import PhysicsEffects

__all__ = ["STAGES", "Candidate", "candidate_library", "select_candidates"]

STAGES = ("scene", "physics", "appearance", "camera")
"""Pipeline stages in data-flow order."""


@dataclasses.dataclass(frozen=True)
class Candidate:
    """One unmodelled effect the diagnosis can add to the simulated domain.

    ``strengths`` of a binary candidate are ``(None,)``; of a choice candidate the
    non-default choices; else a grid over the plausible range.
    """

    name: str
    """``physics.<switch>``, ``visual.<switch>``, ``scene.<field>`` or ``look.<field>``."""
    stage: str
    """One of :data:`STAGES`."""
    registry: str
    """``physics``, ``visual``, ``scene`` or ``look``: the spec entry it changes (``look``:
    the spec's own fields)."""
    field: str
    """The switch (physics/visual), scenario field (scene) or spec field (look) it sets."""
    value: object = None
    """Value the switch takes when the candidate is added (the opposite of its default)."""
    param: str | None = None
    """The strength field (``None``: binary or a scene field itself)."""
    low: float | None = None
    high: float | None = None
    integer: bool = False
    choices: tuple = ()
    default: object = None
    """The nominal value of the strength / scene or look field."""
    neutral: float | None = None
    """The strength at which the effect changes nothing, when it is not below the range: a
    scene field's nominal value, a frame-rate ratio of 1, a JPEG quality of 100."""
    doc: str = ""

    @property
    def needs_simulation(self) -> bool:
        """True when the candidate changes the meshes (physics, scene), not only the pixels."""
        return self.registry in ("physics", "scene")

    @property
    def binary(self) -> bool:
        """True when there is nothing to fit."""
        return self.low is None and not self.choices

    @property
    def log_scale(self) -> bool:
        """True when strengths are spaced (and fitted) in log scale: a range over a factor 4."""
        return self.low is not None and self.low > 0 and self.high / self.low > 4

    def strengths(self, count: int) -> tuple:
        """The strengths tried, in increasing order.

        ``count`` points over the plausible range (log-spaced when it spans more than a
        factor 4; a scene field's nominal value left out), the non-default choices, or
        ``(None,)`` for a binary switch. Where the neutral strength lies inside the range (a
        frame-rate ratio of 1, a scene field's nominal value), ``count`` points on each side
        of it, log-spaced for ratios (range over a factor 4 or more): one grid over the
        whole range put a frame rate of 0.72 between 0.5 and 1.25, both of which scored
        below zero, so it was never refined.
        """
        if self.choices:
            return tuple(c for c in self.choices if c != self.default)
        if self.low is None:
            return (None,)
        if count == 1:
            grid = np.array([math.sqrt(self.low * self.high) if self.low > 0 else self.high])
        elif self.neutral is not None and self.low < self.neutral < self.high:
            space = np.geomspace if self.low > 0 and self.high / self.low >= 4 else np.linspace
            grid = np.concatenate(
                [
                    space(self.low, self.neutral, count + 1)[:-1],
                    space(self.neutral, self.high, count + 1)[1:],
                ]
            )
        elif self.log_scale:
            grid = np.geomspace(self.low, self.high, count)
        else:
            grid = np.linspace(self.low, self.high, count)
        values = [round(v) for v in grid] if self.integer else [float(f"{v:.6g}") for v in grid]
        if self.registry == "scene":  # the nominal value itself would add nothing
            values = [v for v in values if not math.isclose(v, self.default, rel_tol=1e-9)]
        return tuple(dict.fromkeys(values))

    def check_strength(self, value) -> None:
        """Raise a ValueError naming the candidate and the allowed values unless ``value`` fits."""
        if self.choices:
            if value not in self.choices:
                raise ValueError(
                    f"strength of {self.name} must be one of {self.choices}, got {value!r}"
                )
        elif self.low is None:
            if value is not None:
                raise ValueError(f"{self.name} is a switch without strength, got {value!r}")
        elif not (isinstance(value, int | float) and self.low <= value <= self.high):
            raise ValueError(
                f"strength of {self.name} ({self.param}) must be in "
                f"[{self.low}, {self.high}], got {value!r}"
            )

    def apply(self, spec: DatasetSpec, strength=None) -> DatasetSpec:
        """``spec`` with this effect added at ``strength`` (validated)."""
        self.check_strength(strength)
        if self.registry == "scene":
            return dataclasses.replace(
                spec, scenario=dataclasses.replace(spec.scenario, **{self.field: strength})
            )
        if self.registry == "look":
            return dataclasses.replace(spec, **{self.field: strength})
        changes = {self.field: self.value}
        if self.param is not None:
            changes[self.param] = int(strength) if self.integer else strength
        group = "physics" if self.registry == "physics" else "visual"
        return dataclasses.replace(
            spec, **{group: dataclasses.replace(getattr(spec, group), **changes)}
        )

    def label(self, strength=None) -> str:
        """Short text for reports, e.g. ``visual.sensor_noise(noise_read_sigma=2)``."""
        if strength is None:
            return self.name
        key = self.param or self.field
        return (
            f"{self.name}({key}={strength:g})"
            if isinstance(strength, float)
            else f"{self.name}({key}={strength})"
        )


def _visual_stage(field: dataclasses.Field) -> str:
    stage = field.metadata.get("stage")
    if stage is None:  # an undocumented new switch: image effects are the camera's
        stage = "camera" if field.name in IMAGE_EFFECT_ORDER else "appearance"
    if stage not in STAGES:
        raise ValueError(
            f"VisualEffects.{field.name}: stage must be one of {STAGES}, got {stage!r}"
        )
    return stage


def _switch_candidates(cls, registry: str) -> list[Candidate]:
    fields = dataclasses.fields(cls)
    defaults = cls()
    strengths = {f.metadata["strength_of"]: f for f in fields if "strength_of" in f.metadata}
    out = []
    for field in fields:
        if field.type not in ("bool", bool):
            continue
        stage = "physics" if registry == "physics" else _visual_stage(field)
        default = getattr(defaults, field.name)
        kwargs = {}
        if (param := strengths.get(field.name)) is not None:
            low, high = param.metadata["plausible"]
            kwargs = {
                "param": param.name,
                "low": low,
                "high": high,
                "integer": bool(param.metadata.get("integer", False)),
                "default": getattr(defaults, param.name),
                "neutral": param.metadata.get("neutral"),
            }
        out.append(
            Candidate(
                name=f"{registry}.{field.name}",
                stage=stage,
                registry=registry,
                field=field.name,
                value=not default,
                **kwargs,
            )
        )
    return out


def _scene_candidates(spec: DatasetSpec) -> list[Candidate]:
    out = []
    for field in dataclasses.fields(spec.scenario):
        if "choices" in field.metadata:
            kwargs = {"choices": tuple(field.metadata["choices"])}
        elif "plausible" in field.metadata:
            kwargs = dict(zip(("low", "high"), field.metadata["plausible"], strict=True))
            kwargs["neutral"] = getattr(spec.scenario, field.name)
        else:
            continue
        out.append(
            Candidate(
                name=f"scene.{field.name}",
                stage="scene",
                registry="scene",
                field=field.name,
                default=getattr(spec.scenario, field.name),
                **kwargs,
            )
        )
    return out


def _look_candidates(spec: DatasetSpec) -> list[Candidate]:
    """The spec's own fields with ``choices`` metadata: texture family and backdrop."""
    return [
        Candidate(
            name=f"look.{field.name}",
            stage=field.metadata.get("stage", "appearance"),
            registry="look",
            field=field.name,
            choices=tuple(field.metadata["choices"]),
            default=getattr(spec, field.name),
        )
        for field in dataclasses.fields(spec)
        if "choices" in field.metadata
    ]


def candidate_library(
    spec: DatasetSpec,
    physics_cls: type = PhysicsEffects,
    visual_cls: type = VisualEffects,
) -> dict[str, Candidate]:
    """Every candidate for data made like ``spec``, by name, in stage order.

    ``physics_cls`` / ``visual_cls`` exist for tests that plant a new switch; the
    diagnosis always uses the project's registries.
    """
    found = _scene_candidates(spec) + _look_candidates(spec)
    found += _switch_candidates(physics_cls, "physics") + _switch_candidates(visual_cls, "visual")
    found.sort(key=lambda c: STAGES.index(c.stage))
    return {c.name: c for c in found}


def select_candidates(
    library: dict[str, Candidate], names: Iterable[str] | str | None
) -> list[Candidate]:
    """The chosen candidates, in library order.

    ``names`` holds candidate names and/or stage names (a stage stands for all of its
    candidates); ``None`` or ``"all"``: every candidate. Unknown names raise, listing the
    allowed ones.
    """
    if names is None or isinstance(names, str):
        names = [names or "all"]
    names = list(names)
    unknown = [n for n in names if n not in library and n not in STAGES and n != "all"]
    if unknown:
        raise ValueError(
            f"candidates: unknown {unknown}; allowed: 'all', a stage {list(STAGES)} or "
            f"{sorted(library)}"
        )
    if not names:
        raise ValueError("candidates: the list is empty; give 'all', a stage or candidate names")
    wanted = set(names)
    return [c for c in library.values() if "all" in wanted or c.name in wanted or c.stage in wanted]


def _command(cfg) -> None:
    """``python -m sim2real.candidates [motion=arm] [texture=grid]``: list a scene's library."""
    from hydra.utils import instantiate

    from common.configs import config_errors
    from datasets.spec import PRESETS

    with config_errors():
        spec = DatasetSpec(
            motion=str(cfg.motion),
            scenario=instantiate(cfg.scenario),
            preset=PRESETS["small"],
            texture_mode=cfg.texture,
            backdrop=cfg.backdrop,
        )
    for c in candidate_library(spec).values():
        strengths = (
            "switch"
            if c.binary
            else ", ".join(f"{s:g}" if isinstance(s, float) else str(s) for s in c.strengths(3))
        )
        print(f"{c.name:40s} {c.stage:11s} {c.param or c.field:24s} {strengths}")


main = hydra_command(_command, config_name="candidate_library")


if __name__ == "__main__":
    main()
