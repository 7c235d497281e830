"""Dataset generation: simulate each work unit, render its clips, write shards, resume.

Data flow per unit: :class:`~datasets.plan.WorkUnit` -> one batched rollout
(:func:`simulator.cloth.rollout.simulate`; cached as a mesh sequence keyed by the physics hash,
so datasets that differ only in rendering reuse it) -> :class:`render.ClothRenderer` clips
-> one tar shard per split -> the unit's index file. :func:`generate_dataset` runs the
pending units in parallel with joblib and merges the manifest once every unit exists.
Clusters split the units between jobs with ``worker_index`` / ``worker_count`` (a Hydra
multirun over ``worker.index`` with the submitit launcher, see the README).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import shutil
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from common.errors import InputError
from common.processes import run_in_workers, start_manager
from render.backgrounds import backdrop_kinds, make_background
from render.textures import make_texture
from simulator.cloth.material import WANG54, ClothMaterial, load_wang_material
from simulator.cloth.rollout import simulate, with_capsules
from simulator.sequence import MeshSequence
from simulator.threads import torch_threads

from .manifest import Manifest, clip_record, read_json, write_json
from .plan import SimulationPlan, WorkUnit, plan_units
from .shards import ShardError, frames_sha256, verify_shard, write_shard
from .spec import SPLITS, DatasetSpec, check_int

__all__ = [
    "generate_dataset",
    "render_frames",
    "render_unit",
    "renderer_for",
    "run_unit",
    "sim_look",
    "simulate_unit",
]

log = logging.getLogger(__name__)

_TEXTURE_STREAM, _BACKGROUND_STREAM, _CLIP_STREAM = 1, 2, 3
_RENDERER: dict = {}
"""One renderer per process (an EGL context does not survive fork), keyed by its settings."""


def renderer_for(spec: DatasetSpec):
    """This process's :class:`render.renderer.ClothRenderer` for ``spec``'s render settings."""
    from render.renderer import ClothRenderer

    key = (spec.camera, spec.lights, spec.visual, spec.supersample)
    if _RENDERER.get("key") != key:
        old = _RENDERER.pop("renderer", None)
        if old is not None:
            old.close()
        _RENDERER["renderer"] = ClothRenderer(
            spec.camera, spec.lights, spec.visual, supersample=spec.supersample
        )
        _RENDERER["key"] = key
    return _RENDERER["renderer"]


def simulate_unit(
    spec: DatasetSpec,
    unit: WorkUnit,
    cache_dir: Path | None,
    *,
    on_step: Callable[[int, int], None] | None = None,
    multipliers: tuple[Sequence[float], ...] | None = None,
) -> MeshSequence:
    """The unit's mesh sequence: from the cache when present, else simulated (and cached).

    ``on_step(step, total)`` follows the rollout (see :func:`simulator.cloth.rollout.simulate`).
    ``multipliers`` = (stretch, bend[, density]) per simulation of the spec's basis fabric,
    instead of the simulations' classes of its material set (the sim-to-real diagnosis draws
    continuous materials); they are part of the cache key (density only when it is not 1
    everywhere, so the keys of the two-list form stand).
    """
    if multipliers is not None and len(multipliers) == 3:
        if all(float(v) == 1.0 for v in multipliers[2]):
            multipliers = multipliers[:2]  # density 1 everywhere: the two-list form and its key
    path = None
    if cache_dir is not None:
        folder = spec.physics_key()
        if multipliers is not None:
            text = json.dumps([[float(v) for v in m] for m in multipliers])
            folder += "-m" + hashlib.sha256(text.encode()).hexdigest()[:12]
        path = Path(cache_dir) / folder / f"{unit.name}.npz"
        if path.is_file():
            try:
                seq = with_capsules(MeshSequence.load(path))  # older files lack them
                # A longer recording serves a shorter request (a slower camera needs more).
                if seq.pos.shape[0] == len(unit.sims) and seq.frame_count >= spec.frames_per_sim:
                    return seq.first_frames(spec.frames_per_sim)
            except (OSError, ValueError, KeyError) as err:
                log.warning("ignoring unreadable mesh cache %s (%s)", path, err)
    classes = [s.class_id for s in unit.sims]
    if multipliers is None:
        material = spec.material_set.materials(classes)
    else:
        material = ClothMaterial.from_wang(
            load_wang_material(spec.material_set.basis),
            stretch_mult=list(multipliers[0]),
            bend_mult=list(multipliers[1]),
            density_mult=list(multipliers[2]) if len(multipliers) > 2 else 1.0,
        )
    seq = simulate(
        spec.scenario,
        material,
        seeds=[s.seed for s in unit.sims],
        wind_levels=[s.wind_level for s in unit.sims],
        fps=spec.preset.fps,
        record_time=spec.record_time,
        effects=spec.physics,
        settings=spec.sim,
        labels=classes,
        on_step=on_step,
    )
    if path is not None:
        seq.save(path)
    return seq


def sim_look(spec: DatasetSpec, sim: SimulationPlan) -> tuple[np.ndarray, np.ndarray]:
    """The simulation's cloth texture (uint8 (s, s, 3)) and background (uint8 (H, W, 3)).

    Both come from the simulation's seed alone, so every rendering of it (a dataset clip, a
    sim-to-real candidate set) shows the same cloth in front of the same background; the
    texture is of ``spec.texture_mode``'s family and the background of ``spec.backdrop``'s
    kinds (``bank``: the whole background bank).
    """
    texture = make_texture(
        spec.texture_mode, np.random.default_rng([sim.seed, _TEXTURE_STREAM]), spec.texture_size
    )
    background = make_background(
        np.random.default_rng([sim.seed, _BACKGROUND_STREAM]),
        spec.camera.width,
        spec.camera.height,
        kinds=backdrop_kinds(spec.backdrop),
    )
    return texture, background


def render_frames(
    spec: DatasetSpec,
    seq: MeshSequence,
    b: int,
    sim: SimulationPlan,
    start: int,
    stop: int,
    *,
    rng: np.random.Generator,
    capsules: np.ndarray | None = None,
    look: tuple[np.ndarray, np.ndarray] | None = None,
    passes: bool = False,
):
    """Render frames ``[start, stop)`` of instance ``b`` of ``seq`` as ``spec`` renders them.

    Returns ``(frames, coverage[, passes])`` as :meth:`render.renderer.ClothRenderer.
    render_clip` does (a rolling shutter also reads the frames beside them); ``look`` is the
    simulation's (texture, background) when the caller has it already (default:
    :func:`sim_look`), ``capsules`` the whole sequence's arm capsules (``seq.capsules``).
    """
    texture, background = look if look is not None else sim_look(spec, sim)
    lead, trail = rolling_shutter_margins(spec, start, stop, seq.frame_count)
    frames = slice(start - lead, stop + trail)
    return renderer_for(spec).render_clip(
        seq.pos[b, frames],
        seq.tri_indices,
        seq.uv,
        texture,
        background,
        capsules=None if capsules is None else capsules[b, frames],
        rng=rng,
        coverage=True,
        passes=passes,
        lead=lead,
        trail=trail,
    )


def rolling_shutter_margins(
    spec: DatasetSpec, start: int, stop: int, recorded: int
) -> tuple[int, int]:
    """Recorded frames just before and after ``[start, stop)`` that a rolling shutter reads.

    Its readout spans up to half a frame interval either side of a frame's time, so a clip
    cut from a longer recording gets its neighbours (0 or 1 each) and every frame of it is
    skewed alike; only a recording's first and last frames are clamped.
    """
    if not spec.visual.rolling_shutter:
        return 0, 0
    return int(start >= 1), int(stop < recorded)


def _sim_clips(spec: DatasetSpec, seq: MeshSequence, b: int, sim: SimulationPlan, capsules, look):
    """``(frames, coverage[, passes])`` of each clip of one simulation, in order.

    Each clip is rendered on its own (its own random stream); a camera with another frame
    rate (``frame_rate``) resamples the whole recorded video once, which is then cut, so
    its clips lie back to back in time as a real camera's do.
    """
    preset = spec.preset
    if spec.visual.frame_rate:
        frames, coverage = render_frames(
            spec,
            seq,
            b,
            sim,
            spec.lead_in_frames,
            spec.frames_per_sim,
            capsules=capsules,
            look=look,
            rng=np.random.default_rng([sim.seed, _CLIP_STREAM, 0]),
        )
        for k in range(preset.clips_per_sim):
            clip = slice(k * preset.frames_per_clip, (k + 1) * preset.frames_per_clip)
            yield frames[clip], coverage[clip]
        return
    for k in range(preset.clips_per_sim):
        start = spec.lead_in_frames + k * preset.frames_per_clip
        yield render_frames(
            spec,
            seq,
            b,
            sim,
            start,
            start + preset.frames_per_clip,
            capsules=capsules,
            look=look,
            rng=np.random.default_rng([sim.seed, _CLIP_STREAM, k]),
            passes=spec.store_passes,
        )


def render_unit(
    spec: DatasetSpec,
    unit: WorkUnit,
    seq: MeshSequence,
    *,
    on_clip: Callable[[], None] | None = None,
) -> dict[str, list]:
    """Render every clip of the unit: ``{split: [(key, record, frames, coverage, layers)]}``.

    ``layers`` holds the render passes and the clip's background when ``store_passes``;
    ``on_clip()`` is called after each clip (progress).
    """
    capsules = seq.capsules
    out: dict[str, list] = {split: [] for split in SPLITS}
    for b, sim in enumerate(unit.sims):
        texture, background = sim_look(spec, sim)
        for k, (frames, coverage, *passes) in enumerate(
            _sim_clips(spec, seq, b, sim, capsules, (texture, background))
        ):
            coverage = coverage if spec.store_coverage else None
            layers = {**passes[0], "background": background[None]} if passes else None
            shard = f"{sim.split}-{unit.name}.tar"
            record = clip_record(
                spec,
                sim,
                k,
                shard,
                frames.shape,
                frames_sha256(frames),
                coverage is not None,
                passes=layers is not None,
            )
            out[sim.split].append((record["key"], record, frames, coverage, layers))
            if on_clip is not None:
                on_clip()
    return out


def run_unit(
    spec: DatasetSpec,
    unit: WorkUnit,
    out_dir: Path,
    cache_dir: Path | None,
    threads: int,
    report: Callable[..., None] | None = None,
) -> dict:
    """Simulate, render and write one unit; returns its index (also written to disk).

    ``report`` receives the unit's progress as it happens (it may live in another process):
    ``report("sim", unit_index, step, total)`` about 50 times over the rollout and
    ``report("clip", unit_index)`` after each rendered clip.
    """
    on_step = on_clip = None
    if report is not None:

        def on_step(step: int, total: int) -> None:
            if step == total or step % max(1, total // 50) == 0:
                report("sim", unit.index, step, total)

        def on_clip() -> None:
            report("clip", unit.index)

    start = time.perf_counter()
    with torch_threads(threads, name="threads_per_job"):  # part of what fixes the bytes
        seq = simulate_unit(spec, unit, cache_dir, on_step=on_step)
    sim_seconds = time.perf_counter() - start
    rendered = render_unit(spec, unit, seq, on_clip=on_clip)
    shards, clips = [], []
    for split in SPLITS:
        samples = rendered[split]
        if not samples:
            continue
        name = samples[0][1]["shard"]
        info = write_shard(Path(out_dir) / "shards" / name, samples)
        shards.append({"name": name, "split": split, "unit": unit.index, **info})
        clips.extend(sample[1] for sample in samples)
    index = {"spec_key": spec.key(), "unit": unit.index, "shards": shards, "clips": clips}
    write_json(_unit_path(out_dir, unit), index)
    seconds = time.perf_counter() - start
    return {
        "index": index,
        "sim_seconds": sim_seconds,
        "render_seconds": seconds - sim_seconds,
        "frames": sum(c["frame_count"] for c in clips),
    }


def _unit_path(out_dir: Path, unit: WorkUnit) -> Path:
    return Path(out_dir) / "units" / f"{unit.name}.json"


def _finished_index(out_dir: Path, unit: WorkUnit, spec_key: str) -> dict | None:
    """The unit's index if the unit is complete and intact, else ``None``."""
    path = _unit_path(out_dir, unit)
    if not path.is_file():
        return None
    try:
        index = read_json(path)
        if index.get("spec_key") != spec_key:
            return None
        for shard in index["shards"]:
            verify_shard(Path(out_dir) / "shards" / shard["name"], shard["sha256"], shard["bytes"])
    except (ShardError, KeyError) as err:
        log.warning("%s will be regenerated: %s", unit.name, err)
        return None
    return index


def _prepare_dir(spec: DatasetSpec, out_dir: Path, overwrite: bool) -> None:
    spec_path = out_dir / "spec.json"
    if spec_path.is_file():
        existing = read_json(spec_path)
        if existing.get("key") != spec.key():
            if not overwrite:
                raise InputError(
                    f"out_dir {out_dir} holds a dataset of a different config "
                    f"(key {existing.get('key')} != {spec.key()}); choose another out_dir or "
                    "set overwrite=true"
                )
            for name in ("shards", "units"):
                shutil.rmtree(out_dir / name, ignore_errors=True)
            for name in ("manifest.json", "manifest.csv"):
                (out_dir / name).unlink(missing_ok=True)
    for sub in ("shards", "units"):
        (out_dir / sub).mkdir(parents=True, exist_ok=True)
        for stale in (out_dir / sub).glob(".*.tmp"):
            stale.unlink(missing_ok=True)  # left by a killed writer; never counted
    write_json(spec_path, {"key": spec.key(), "spec": spec.to_json()})


def _merge(spec: DatasetSpec, out_dir: Path, indices: list[dict]) -> Manifest:
    """Write the manifest of all units (with the spec's material set).

    A finished dataset's manifest from before the material set was recorded is kept as it is
    when it lists the same shards and clips of the default set: its bytes are the identity
    that training runs recorded (``train.py``), and it reads as that set anyway.
    """
    indices = sorted(indices, key=lambda index: index["unit"])
    manifest = Manifest(
        root=out_dir,
        spec=spec.to_json(),
        spec_key=spec.key(),
        shards=tuple(s for index in indices for s in index["shards"]),
        clips=tuple(c for index in indices for c in index["clips"]),
        material_set=spec.material_set,
    )
    path = Manifest.path(out_dir)
    if spec.material_set == WANG54 and path.is_file():
        try:
            if "material_set" not in read_json(path) and Manifest.load(out_dir) == manifest:
                return manifest
        except (ShardError, KeyError, TypeError) as err:
            log.warning("rewriting unreadable %s (%s)", path, err)
    manifest.save()
    return manifest


def generate_dataset(
    spec: DatasetSpec,
    out_dir: str | Path,
    *,
    n_jobs: int = 1,
    threads_per_job: int = 1,
    worker_index: int = 0,
    worker_count: int = 1,
    mesh_cache: str | Path | None = None,
    overwrite: bool = False,
    max_units: int | None = None,
    progress: bool = True,
) -> Manifest | None:
    """Generate (or finish) the dataset of ``spec`` in ``out_dir``.

    Args:
        spec: What to generate.
        out_dir: Dataset directory (created; an unfinished one of the same spec is resumed).
        n_jobs: Parallel worker processes (joblib); 1 runs in this process.
        threads_per_job: Torch threads per worker (part of what fixes the bytes: keep it when
            resuming).
        worker_index: This job takes the units with ``index % worker_count == worker_index``
            (cluster sharding).
        worker_count: Number of jobs sharing the units.
        mesh_cache: Directory of cached mesh sequences (``None``: ``out_dir/meshes``).
        overwrite: Replace a dataset of a different spec in ``out_dir`` instead of failing.
        max_units: Stop after this many new units (a deliberate partial run).
        progress: Show a progress bar with ETA.

    Returns:
        The manifest once every unit of the dataset exists, else ``None``.
    """
    for name, value, low in (
        ("n_jobs", n_jobs, 1),
        ("threads_per_job", threads_per_job, 1),
        ("worker_count", worker_count, 1),
        ("worker_index", worker_index, 0),
    ):
        check_int(name, value, low)
    if worker_index >= worker_count:
        raise ValueError(f"worker_index must be in [0, {worker_count - 1}], got {worker_index}")
    out_dir = Path(out_dir)
    _prepare_dir(spec, out_dir, overwrite)
    cache_dir = Path(mesh_cache) if mesh_cache is not None else out_dir / "meshes"
    units = plan_units(spec)
    key = spec.key()
    done = {u.index: idx for u in units if (idx := _finished_index(out_dir, u, key)) is not None}
    pending = [u for u in units if u.index not in done and u.index % worker_count == worker_index]
    if max_units is not None:
        pending = pending[:max_units]
    log.info(
        "%s: %d units (%d clips), %d finished, %d to run here with %d job(s)",
        out_dir,
        len(units),
        spec.clip_count,
        len(done),
        len(pending),
        n_jobs,
    )
    if pending:
        _run_pending(spec, pending, out_dir, cache_dir, n_jobs, threads_per_job, done, progress)
    for unit in units:  # other workers (cluster jobs) may have finished units meanwhile
        if unit.index not in done and (index := _finished_index(out_dir, unit, key)) is not None:
            done[unit.index] = index
    if len(done) < len(units):
        log.info("%d of %d units finished; run again to continue", len(done), len(units))
        return None
    manifest = _merge(spec, out_dir, list(done.values()))
    log.info(
        "wrote %s (%d clips, %d shards)",
        Manifest.path(out_dir),
        len(manifest.clips),
        len(manifest.shards),
    )
    return manifest


class _Progress:
    """The generation's progress bar: one tick per rendered clip, ETA over the whole run.

    A unit simulates all its simulations in one rollout before its first clip is rendered
    (minutes for a full-size unit), so the bar also shows how far each unit's rollout is.
    The ETA uses the average rate since the start (``smoothing=0``): clips arrive in bursts.
    """

    def __init__(self, spec: DatasetSpec, pending: list[WorkUnit], enabled: bool):
        from tqdm import tqdm

        clips = sum(len(u.sims) for u in pending) * spec.preset.clips_per_sim
        self.bar = tqdm(
            total=clips,
            desc=f"generate {spec.motion}",
            unit="clip",
            smoothing=0.0,
            disable=not enabled,
        )
        self.rollouts: dict[int, float] = {}

    def __call__(self, kind: str, unit: int, step: int = 0, total: int = 0) -> None:
        """One report of :func:`run_unit`."""
        if kind == "sim":
            self.rollouts[unit] = step / max(total, 1)
            if step >= total:
                del self.rollouts[unit]
            self._show_rollouts()
        else:
            self.bar.update(1)

    def _show_rollouts(self) -> None:
        text = ", ".join(
            f"unit {unit} simulating {fraction:.0%}"
            for unit, fraction in sorted(self.rollouts.items())
        )
        self.bar.set_postfix_str(text, refresh=True)

    def close(self) -> None:
        """Close the bar."""
        self.bar.close()


def _queue_reports(queue, progress: _Progress) -> None:
    """Forward the workers' reports from ``queue`` to ``progress`` until a ``None``."""
    while (message := queue.get()) is not None:
        progress(*message)


class _QueueReport:
    """A picklable ``report`` for :func:`run_unit` in a worker process: puts on a queue."""

    def __init__(self, queue):
        self.queue = queue

    def __call__(self, *message) -> None:
        """Send one report."""
        self.queue.put(message)


def _run_pending(spec, pending, out_dir, cache_dir, n_jobs, threads, done, progress) -> None:
    bar = _Progress(spec, pending, progress)
    timing = {"sim_seconds": 0.0, "render_seconds": 0.0, "frames": 0}
    with contextlib.ExitStack() as stack:
        stack.callback(bar.close)
        if n_jobs == 1:
            report = bar if progress else None
            results = (run_unit(spec, u, out_dir, cache_dir, threads, report) for u in pending)
        else:
            from joblib import delayed

            report = None
            if progress:  # workers report through a queue that a thread here reads
                manager = start_manager()
                stack.callback(manager.shutdown)
                queue = manager.Queue()
                reader = threading.Thread(target=_queue_reports, args=(queue, bar), daemon=True)
                reader.start()
                stack.callback(reader.join)
                stack.callback(queue.put, None)
                report = _QueueReport(queue)
            os.environ.setdefault("LP_NUM_THREADS", "1")  # llvmpipe: one raster thread per job
            results = run_in_workers(
                n_jobs,
                (delayed(run_unit)(spec, u, out_dir, cache_dir, threads, report) for u in pending),
            )
        for result in results:
            index = result["index"]
            done[index["unit"]] = index
            for name in timing:
                timing[name] += result[name]
    log.info(
        "worker time: simulate %.1f s, render+write %.1f s (%.0f frames/s)",
        timing["sim_seconds"],
        timing["render_seconds"],
        timing["frames"] / max(timing["render_seconds"], 1e-9),
    )
