"""The one rollout an application records: its frame rate, length and lead-in, checked.

The demo and material cloning each simulate one rollout per class, record ``record_time``
seconds at ``fps`` and show what follows the ``lead_in`` (while the wind or the arm starts).
:func:`check_app_fields` checks the fields both commands begin with.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from common.checks import check_float, check_int, check_threads
from common.configs import config_errors
from common.errors import InputError
from datasets.generation import render_frames
from datasets.plan import WorkUnit
from datasets.spec import DatasetSpec, SizePreset
from simulator.cloth.rollout import check_recording_memory

__all__ = ["Recording", "check_app_fields", "render_shown"]

RENDER_STREAM = 4
"""Random stream of a rollout's render (camera noise, light jitter), after its seed."""


@dataclasses.dataclass(frozen=True)
class Recording:
    """What one application rollout records."""

    fps: float
    """Recorded frames per second [1/s]."""
    record_time: float
    """Recorded time after settling [s]."""
    lead_in: float
    """Recorded time dropped before the first shown frame [s]."""

    @classmethod
    def from_config(cls, cfg) -> Recording:
        """The config's ``fps``, ``record_time`` and ``lead_in``, refused unless a frame shows."""
        fps = check_float(cfg.fps, "fps", 0, low_open=True)
        record_time = check_float(cfg.record_time, "record_time", 0, low_open=True)
        lead_in = check_float(cfg.lead_in, "lead_in", 0)
        recording = cls(fps, record_time, lead_in)
        if recording.frame_count < 2 or recording.shown < 1:
            raise InputError(
                f"record_time must span at least one frame interval (1/fps = {1 / fps:g} s) "
                f"more than lead_in ({lead_in:g} s), got {record_time:g} s"
            )
        return recording

    @property
    def frame_count(self) -> int:
        """Frames recorded, as :func:`simulator.cloth.rollout.simulate` records them."""
        return round(self.record_time * self.fps) + 1

    @property
    def shown(self) -> int:
        """Frames after the lead-in."""
        return self.frame_count - round(self.lead_in * self.fps)

    def preset(self, name: str) -> SizePreset:
        """One simulation per class in one rollout, nothing held out (no splits)."""
        return SizePreset(
            name,
            sims_per_class=1,
            clips_per_sim=1,
            val_sims_per_class=0,
            test_sims_per_class=0,
            frames_per_clip=self.shown,
            fps=self.fps,
        )

    def check_memory(self, spec: DatasetSpec, instances: int) -> None:
        """Refuse a recording of ``instances`` cloths of ``spec`` that memory cannot hold."""
        check_recording_memory(
            self.record_time, self.fps, instances, spec.scenario.mesh().vert_count
        )


def check_app_fields(cfg) -> tuple[int, Recording, int]:
    """The config's ``threads``, recording and ``sheet_frames``, checked in that order.

    Raises:
        InputError: naming the first bad field and its allowed values.
    """
    with config_errors():
        threads = check_threads(cfg.threads, "threads")
    recording = Recording.from_config(cfg)
    return threads, recording, check_int(cfg.sheet_frames, "sheet_frames", 1)


def render_shown(
    spec: DatasetSpec,
    seq,
    unit: WorkUnit,
    on_frames: Callable[[int, int], None] | None = None,
) -> list[np.ndarray]:
    """Each rollout of ``unit``'s shown frames (after the lead-in), rendered as ``spec`` says.

    ``seq`` is the unit's simulated :class:`~simulator.cloth.rollout.MeshSequence`;
    ``on_frames(done, total)`` is told the frames rendered so far.
    """
    first, stop = spec.lead_in_frames, spec.frames_per_sim
    clips = []
    for b, sim in enumerate(unit.sims):
        frames, _ = render_frames(
            spec,
            seq,
            b,
            sim,
            first,
            stop,
            capsules=seq.capsules,
            rng=np.random.default_rng([sim.seed, RENDER_STREAM]),
        )
        clips.append(frames)
        if on_frames is not None:
            on_frames(len(frames) * (b + 1), len(frames) * len(unit.sims))
    return clips
