"""Clip sets of every domain, cut the same way: nominal simulation S, S + effect, real R.

Simulated sets go through the dataset generator's own pieces (mesh cache keyed by the physics
hash, :func:`datasets.generation.simulate_unit`, the generator's renderer, each simulation's
texture and background), so a visual or look candidate (texture family, backdrop) re-renders
cached meshes and only a physical or scene candidate re-simulates. Each simulation is
rendered as one video (image effects such as a frame-rate change act on the whole video, as
a camera would) and cut into clips exactly
as :class:`datasets.real_video.RealVideoDataset` cuts a real video: ``clip_len`` frames every
``clip_stride`` frames at the preset's frame rate. Groups (for every resampling in the
statistics) are simulations in S and videos in R. Simulated cloths take continuous materials
from the training span (:func:`prior_materials`), labelled with the nearest class.
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import time
from pathlib import Path

import numpy as np

from common.files import atomic_write_bytes
from datasets.generation import render_frames, simulate_unit
from datasets.plan import SimulationPlan, WorkUnit, plan_units
from datasets.real_video import RealVideoDataset, clip_starts
from datasets.spec import DatasetSpec, SizePreset
from render.effects import IMAGE_EFFECT_ORDER, apply_image_effects
from simulator.cloth.material import load_wang_material
from simulator.sequence import MeshSequence

__all__ = ["ClipSet", "diagnosis_spec", "prior_materials", "real_clips", "simulated_clips"]

_VIDEO_STREAM = 3  # the generator's clip stream; clip 0 of a simulation = its video
_MATERIAL_STREAM = 11
_DENSITY_STREAM = 12  # its own stream: adding density left the stretch and bend draws as they were


@dataclasses.dataclass(frozen=True)
class ClipSet:
    """Clips of one domain with their groups and labels (one row per clip)."""

    frames: np.ndarray
    """uint8 RGB, shape (N, T, H, W, 3)."""
    groups: np.ndarray
    """Simulation or video id, str, shape (N,)."""
    class_id: np.ndarray
    """Subspace class, int, shape (N,); -1 for real clips."""
    stiffness: np.ndarray
    """Bending multiplier (simulated) or measured stiffness (real), shape (N,)."""
    density: np.ndarray
    """Areal density [kg/m²] (simulated) or measured density (real), shape (N,)."""
    coverage: np.ndarray | None = None
    """Cloth coverage, uint8, shape (N, T, H, W) (simulated sets only)."""
    skipped: tuple[str, ...] = ()
    """Videos too short for one clip (real sets), reported, never silently dropped."""

    def __len__(self) -> int:
        return int(self.frames.shape[0])

    @property
    def group_count(self) -> int:
        """Distinct groups."""
        return len(set(self.groups.tolist()))


def diagnosis_spec(
    train: DatasetSpec,
    *,
    classes: tuple[int, ...] | None = None,
    sims_per_class: int = 1,
    clips_per_sim: int = 3,
    seed_offset: int = 1000,
) -> DatasetSpec:
    """The nominal simulated domain S: the training data's settings on fresh simulations.

    Same scene, mesh level, texture mode, effects, camera and frame rate as ``train``;
    ``classes`` (default: every third class of the training set, spanning the grid),
    ``sims_per_class`` simulations each, with seeds never used in training
    (``train.seed + seed_offset``), all in one work unit: one batched rollout per set
    (a batch of 18 costs about half as much per simulation as batches of 5; sets run in
    parallel instead).
    """
    chosen = tuple(train.classes[::3]) if classes is None else tuple(classes)
    preset = SizePreset(
        "diagnose",
        sims_per_class=sims_per_class,
        clips_per_sim=clips_per_sim,
        val_sims_per_class=0,
        test_sims_per_class=0,
        frames_per_clip=train.preset.frames_per_clip,
        fps=train.preset.fps,
    )
    return dataclasses.replace(
        train,
        preset=preset,
        classes=chosen,
        seed=train.seed + seed_offset,
        sims_per_unit=len(chosen) * sims_per_class,
        store_passes=False,
        store_coverage=True,
    )


def prior_materials(spec: DatasetSpec, unit: WorkUnit) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stretch, bend and density multipliers (p, k, q) of the unit's simulations, from the prior.

    The prior is log-uniform over the span of the training classes' multipliers (density: of
    the material set's densities; q = 1 in a set of one density), one draw per simulation
    from its seed alone (so S and every S_e hold the same cloths). The training classes are
    a grid over that span; a diagnosis set drawn from a grid is a lumpy distribution that no
    real set of fabrics spread over the span matches, and the difference shows up on the
    motion rung as a gap that damping-like candidates "close" (measured on a sealed set with
    no effect at all).
    """
    materials = spec.material_set
    stretch_bend = np.log([materials.multipliers(c) for c in spec.classes])
    densities = np.log(materials.density_multipliers)

    def draw(stream: int, low, high) -> np.ndarray:
        """Log-uniform draws, one per simulation from its seed alone."""
        rng = [np.random.default_rng([s.seed, stream]) for s in unit.sims]
        return np.exp(np.array([r.uniform(low, high) for r in rng]))

    p, k = draw(_MATERIAL_STREAM, stretch_bend.min(axis=0), stretch_bend.max(axis=0)).T
    q = np.ones(len(unit.sims))
    if materials.density_count > 1:
        q = draw(_DENSITY_STREAM, densities.min(), densities.max())
    return p, k, q


def _nearest_class(spec: DatasetSpec, p: float, k: float, q: float) -> int:
    """The training class whose multipliers lie nearest (p, k, q) in log space."""
    materials = spec.material_set
    grid = np.log([(*materials.multipliers(c), materials.density_mult(c)) for c in spec.classes])
    return int(spec.classes[int(np.argmin(((grid - np.log([p, k, q])) ** 2).sum(axis=1)))])


def simulated_clips(
    spec: DatasetSpec,
    mesh_cache,
    *,
    clip_len: int | None = None,
    clip_stride: int | None = None,
    render_cache=None,
    timing: dict[str, float] | None = None,
) -> ClipSet:
    """Simulate (or load cached meshes) and render every simulation of ``spec`` as clips.

    Args:
        spec: What to simulate and render.
        mesh_cache: Mesh-cache folder (shared with ``datasets.generate``).
        clip_len: Frames per clip (default: the preset's).
        clip_stride: Frames between clip starts (default: ``clip_len``).
        render_cache: Folder of rendered frames before the image effects
            (:data:`render.effects.IMAGE_EFFECT_ORDER`), or ``None``. A set with image
            effects on then renders its meshes without them (or reads that render) and
            applies its image effects on top: the same bytes as rendering it whole, and the
            sets that differ only in those effects (noise, compression, white balance,
            defocus, vignetting and their strengths) share one render. Not with a frame-rate
            change, which sets how many frames are simulated.
        timing: Where to add the seconds spent simulating (or reading the mesh cache) and
            rendering (image effects included), as ``simulate`` and ``render``; ``None``:
            not timed.

    Returns:
        The clips; groups are simulation ids.
    """
    clip_len = clip_len or spec.preset.frames_per_clip
    clip_stride = clip_stride or clip_len
    basis_density = load_wang_material(spec.material_set.basis).density
    base = None
    shared = render_cache is not None and not spec.visual.frame_rate
    if shared and any(getattr(spec.visual, n) for n in IMAGE_EFFECT_ORDER):
        base = dataclasses.replace(spec, visual=spec.visual.before_image_effects())
    names = ("frames", "coverage", "groups", "class_id", "k", "q")
    rows: dict[str, list] = {name: [] for name in names}
    seconds = {"simulate": 0.0, "render": 0.0}
    for unit in plan_units(spec):
        p, k, q = prior_materials(spec, unit)
        tick = time.perf_counter()
        seq = simulate_unit(spec, unit, mesh_cache, multipliers=(p, k, q))  # cached by physics
        seconds["simulate"] += time.perf_counter() - tick
        # key and materials: a visual or look candidate re-renders the nominal meshes
        q = q * spec.physics.density_factors([s.seed for s in unit.sims])  # as simulated
        capsules = seq.capsules
        start, stop = spec.lead_in_frames, spec.frames_per_sim
        for b, sim in enumerate(unit.sims):
            tick = time.perf_counter()
            rng = np.random.default_rng([sim.seed, _VIDEO_STREAM, 0])
            if base is None:
                frames, coverage = render_frames(
                    spec, seq, b, sim, start, stop, capsules=capsules, rng=rng
                )
            else:
                frames, coverage = _base_render(
                    base, seq, b, sim, start, stop, capsules, Path(render_cache)
                )
                # render_clip draws its effect streams from the clip's Generator once, first:
                # a fresh Generator of the same seed gives the image effects the same streams.
                frames, coverage = apply_image_effects(frames, spec.visual, rng, coverage)
            seconds["render"] += time.perf_counter() - tick
            for first in clip_starts(len(frames), clip_len, clip_stride):
                rows["frames"].append(frames[first : first + clip_len])
                rows["coverage"].append(coverage[first : first + clip_len])
                rows["groups"].append(sim.sim_id)
                rows["class_id"].append(_nearest_class(spec, p[b], k[b], q[b]))
                rows["k"].append(k[b])
                rows["q"].append(q[b])
    if timing is not None:
        for name, value in seconds.items():
            timing[name] = timing.get(name, 0.0) + value
    if not rows["frames"]:
        raise ValueError(
            f"the simulated videos ({spec.frames_per_sim - spec.lead_in_frames} frames) are "
            f"too short for one clip of {clip_len} frames"
        )
    return ClipSet(
        frames=np.stack(rows["frames"]),
        groups=np.array(rows["groups"], dtype=str),
        class_id=np.array(rows["class_id"], dtype=np.int64),
        stiffness=np.array(rows["k"], dtype=np.float64),
        density=basis_density * np.array(rows["q"], dtype=np.float64),
        coverage=np.stack(rows["coverage"]),
    )


def _base_render(
    base: DatasetSpec,
    seq: MeshSequence,
    b: int,
    sim: SimulationPlan,
    start: int,
    stop: int,
    capsules,
    folder: Path,
) -> tuple[np.ndarray, np.ndarray]:
    """Frames and coverage of one simulation as ``base`` (no image effect) renders them.

    Read from ``folder`` when a set with the same meshes and render settings put them there
    (keyed by ``base``'s content key, the simulation and the frame range), else rendered and
    written there atomically (compressed: about 0.8 MB a simulation at 112 px).
    """
    text = f"{base.key()}|{sim.sim_id}|{start}|{stop}"
    path = folder / f"{hashlib.sha256(text.encode()).hexdigest()[:20]}.npz"
    if path.is_file():
        with np.load(path) as stored:
            return stored["frames"], stored["coverage"]
    rng = np.random.default_rng([sim.seed, _VIDEO_STREAM, 0])
    frames, coverage = render_frames(base, seq, b, sim, start, stop, capsules=capsules, rng=rng)
    buffer = io.BytesIO()
    np.savez_compressed(buffer, frames=frames, coverage=coverage)
    atomic_write_bytes(path, buffer.getvalue())
    return frames, coverage


def real_clips(
    real_dir,
    *,
    size: int,
    clip_len: int,
    clip_stride: int,
    fps: float,
    max_clips_per_video: int | None = None,
) -> ClipSet:
    """Every clip of a real folder (the layout :class:`RealVideoDataset` reads).

    Videos too short for one clip are listed in ``skipped``; a folder where no video gives a
    clip raises (``RealVideoDataset`` names the folder).
    """
    dataset = RealVideoDataset(
        real_dir,
        clip_len=clip_len,
        clip_stride=clip_stride,
        target_fps=fps,
        size=size,
        max_clips_per_video=max_clips_per_video,
    )
    used = {v for v, _ in dataset.clips}
    skipped = tuple(video.name for v, video in enumerate(dataset.videos) if v not in used)
    frames = np.stack([dataset.read_frames(i) for i in range(len(dataset))])
    videos = [dataset.videos[v] for v, _ in dataset.clips]
    return ClipSet(
        frames=frames,
        groups=np.array([v.name for v in videos], dtype=str),
        class_id=np.full(len(videos), -1, dtype=np.int64),
        stiffness=np.array([v.stiffness for v in videos], dtype=np.float64),
        density=np.array([v.density for v in videos], dtype=np.float64),
        skipped=skipped,
    )
