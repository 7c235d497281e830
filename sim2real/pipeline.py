"""Run one diagnosis end to end: inputs checked, sets built and cached, report written.

``run_diagnosis`` is what ``python -m sim2real.diagnose`` calls. Every input is checked
before anything is written; every expensive set (simulated or real clips on every rung) is
cached under a content key, so a rerun, or a run with one more candidate, only builds what
is new; the report folder receives complete files only.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import hashlib
import itertools
import logging
import time
from pathlib import Path

import numpy as np

from datasets.runs import find_run
from datasets.spec import DatasetSpec, check_int
from simulator.cloth.material import WANG54, MaterialSet
from simulator.threads import use_process_threads

from .candidates import Candidate, candidate_library, select_candidates
from .counterfactuals import batchnorm_swap, camera_signatures, match_camera, swap_closure
from .detectability import candidate_detectability
from .diagnosis import (
    CandidateResult,
    Ranking,
    best_subset_values,
    explains_together,
    fit_strength,
    kernel_closure,
    localise,
    probe_transfer,
    rank_candidates,
    rung_gaps,
    shapley_values,
    stage_of_residual,
)
from .diagnosis.joint import (
    Assignment,
    Factor,
    closure_values,
    divergence_closure,
    fit_jointly,
    midpoint,
    nominal_scores,
    point_closures,
)
from .diagnosis.reference import Reference, compare_domains
from .domains import ClipSet, diagnosis_spec, real_clips, simulated_clips
from .features import roi_box
from .ladder import LadderFeatures, content_key, file_digest, ladder_features
from .network import adapt_batchnorm, layer_features
from .report import contact_sheet, json_safe, write_report
from .result import Diagnosis, DiagnosisInputs, Location
from .stacking import STACK_MIN_LEADER, explained_by_stack, stacked_fit

__all__ = [
    "Budget",
    "DiagnosisRequest",
    "SetContext",
    "SetJob",
    "build_set",
    "explained_together",
    "load_run",
    "real_ladder",
    "run_diagnosis",
    "spanning_classes",
]

log = logging.getLogger(__name__)

SIM_SEED_OFFSET, SIM_SEED_STEP = 1000, 10_000
"""S's seeds: training seed + SIM_SEED_OFFSET + SIM_SEED_STEP x ``sim_seed`` (never trained on;
another ``sim_seed`` draws every simulated set afresh: the ranking-stability check)."""

NULL_SEED_OFFSET = 500
"""S' = the nominal set re-drawn with seeds this far from S's (the chance level of closure)."""


@dataclasses.dataclass(frozen=True)
class Budget:
    """How much the diagnosis simulates and resamples (``configs/budget/``)."""

    name: str = "quick"
    class_grid: tuple[int, int] | None = (3, 3)
    """(stretch, bend) counts of the class sub-grid whose simulations make S
    (:func:`spanning_classes`; ``None``: every training class). With ``sims_per_class`` it
    sets how many simulations S holds; each draws its own continuous material over the
    training span (:func:`sim2real.domains.prior_materials`)."""
    sims_per_class: int = 6
    """Simulations per class of the sub-grid (the quick budget's 9 x 6 = 54). Doubled from 3
    after a power study (``python -m sim2real.study.power``): on the validation's sets whose effect
    left no gap, pooling more nominal draws found the gap of most of them, so the limit was
    the number of simulations, not of real videos (docs/sim2real.md)."""
    clips_per_sim: int = 3
    """Clips per simulation in S, and the first this many clips of each real video in R: both
    domains cover the same time after the wind starts. (A cloth's motion changes over its
    first seconds; cut longer, R held a later clip that S never had, which made a significant
    motion gap on a sealed set with no effect at all, and damping-like candidates "closed"
    it.)"""
    strengths: int = 3
    """Strengths tried per candidate with a strength parameter."""
    n_perm: int = 200
    n_boot: int = 200
    n_floor: int = 10
    shapley_top: int = 3
    """Candidates (best first, closing some of the gap) whose coalitions get Shapley values;
    0 = none. Costs 2^n - n - 1 more sets."""
    refine: str = "all"
    """Densify the strength grid around the best strength of the top candidates: ``none``,
    ``visual`` (re-rendered candidates only: no simulation) or ``all``."""
    joint_top: int = 4
    """Most factors of the calibrated simulator S*, chosen one at a time with the others in
    place (:mod:`sim2real.diagnosis.joint`); 0 = no joint fit. Costs ``joint_verify`` sets a
    factor, about ``joint_rounds x (strengths + 1)`` a factor for the refit, then 2^k for
    attribution."""
    joint_verify: int = 4
    """Screened additions (best first) built and measured at each step of the selection."""
    joint_rounds: int = 2
    """Rounds of the joint coordinate ascent (it stops early when a round moves nothing)."""
    joint_strengths: int = 4
    """Strengths each factor tries in the joint fit (spread over those it was scored at)."""
    joint_interval_refine: int = 2
    """Bisections of each end of a calibrated strength's interval (:func:`strength_intervals
    <sim2real.diagnosis.joint.strength_intervals>`); 0 = the ascent's grid only. Costs up to
    two sets a numeric factor per bisection."""
    joint_refit: int = 1
    """When a step of the selection adds nothing, the additions (most gain first) then tried
    with every chosen strength refitted around them (one ascent round each, about
    ``strengths + 1`` sets a factor); 0 = none."""
    joint_lookahead: int = 0
    """Most lookahead steps of the selection: after a stall that no refit ends, the best
    addition that gained anything goes in provisionally and one more step is taken; both are
    kept when that step adds a factor (:func:`select <sim2real.diagnosis.joint.select>`);
    0 = none. Costs about ``joint_verify`` sets a lookahead."""
    joint_prune: int = 0
    """Most factors the selection drops from S* when it would stop, each one that no longer
    matters with the later factors in place (it was a stand-in for them), freeing its place;
    0 = none. Costs one set a chosen factor per prune step."""

    def __post_init__(self):
        if self.refine not in ("none", "visual", "all"):
            raise ValueError(f"budget.refine must be none, visual or all, got {self.refine!r}")
        for name in ("sims_per_class", "clips_per_sim", "strengths", "n_floor"):
            check_int(f"budget.{name}", getattr(self, name))
        if self.class_grid is not None:
            if len(self.class_grid) != 2:
                raise ValueError(
                    f"budget.class_grid must be [stretch, bend] counts or null, "
                    f"got {self.class_grid!r}"
                )
            object.__setattr__(self, "class_grid", tuple(self.class_grid))
            for count in self.class_grid:
                check_int("budget.class_grid", count)
        check_int("budget.shapley_top", self.shapley_top, low=0)
        check_int("budget.joint_top", self.joint_top, low=0)
        check_int("budget.joint_verify", self.joint_verify)
        check_int("budget.joint_rounds", self.joint_rounds)
        check_int("budget.joint_strengths", self.joint_strengths)
        check_int("budget.joint_interval_refine", self.joint_interval_refine, low=0)
        check_int("budget.joint_refit", self.joint_refit, low=0)
        check_int("budget.joint_prune", self.joint_prune, low=0)
        check_int("budget.joint_lookahead", self.joint_lookahead, low=0)
        for name in ("n_perm", "n_boot"):
            check_int(f"budget.{name}", getattr(self, name), low=19)


def spanning_classes(
    classes, grid: tuple[int, int] | None, material_set: MaterialSet = WANG54
) -> tuple[int, ...]:
    """A sub-grid of ``classes`` that spans the stiffness range, corners included.

    ``grid`` = (stretch count, bend count): that many evenly spaced stretch and bend indices
    of ``material_set`` from the lowest to the highest present in ``classes``; each grid point
    takes the nearest class of ``classes`` (duplicates dropped; in a set of several densities,
    the lightest, as the diagnosis draws each simulation's density from the prior anyway). Every
    n-th class would not do: with 9 bend levels, a stride of 6 or 3 never reaches the stiffest
    bends.
    """
    classes = tuple(int(c) for c in classes)
    if grid is None:
        return classes
    positions = np.array([material_set.position(c)[:2] for c in classes], dtype=float)
    axes = [
        np.linspace(positions[:, k].min(), positions[:, k].max(), count)
        for k, count in enumerate(grid)
    ]
    picked = []
    for point in itertools.product(*axes):
        nearest = classes[int(np.argmin(((positions - point) ** 2).sum(axis=1)))]
        if nearest not in picked:
            picked.append(nearest)
    return tuple(sorted(picked))


@dataclasses.dataclass(frozen=True)
class SetJob:
    """One simulated set to build: the nominal S, S', or S with a candidate at a strength."""

    label: str
    spec: DatasetSpec


@dataclasses.dataclass(frozen=True)
class SetContext:
    """What every set's features depend on besides its spec (picklable, sent to workers)."""

    box: tuple[int, int, int, int]
    checkpoint: str
    checkpoint_digest: str
    mesh_cache: str
    cache_dir: str
    clip_len: int
    clip_stride: int
    device: str


def load_run(run: str | Path, data_dir: str | Path | None = None) -> tuple[DatasetSpec, Path]:
    """The training data's spec and the checkpoint of a training run.

    See :func:`datasets.runs.find_run` (errors name ``run`` or ``data_dir``).
    """
    trained = find_run(run, data_dir)
    return trained.spec, trained.checkpoint


def _load_net(checkpoint: str, device: str, material_set: MaterialSet | None = None):
    """The run's network; with ``material_set``, refused unless it predicts that set's classes."""
    from models.material_classifier import load_classifier

    module = load_classifier(checkpoint, map_location="cpu", field="run")
    classes = module.net.classifier.out_features if hasattr(module.net, "classifier") else None
    if material_set is not None and classes is not None and classes != material_set.num_classes:
        raise ValueError(
            f"run: checkpoint {checkpoint} has {classes} output classes; its training data's "
            f"material set {material_set.name} has {material_set.grid.describe()}"
        )
    return module.net.to(device).eval()


_NETS: dict = {}


def _net(context: SetContext):
    key = (context.checkpoint, context.device)
    if key not in _NETS:
        _NETS.clear()
        _NETS[key] = _load_net(context.checkpoint, context.device)
    return _NETS[key]


def _cache_path(context: SetContext, key: str) -> Path:
    return Path(context.cache_dir) / "features" / f"{key}.npz"


def _sim_key(job: SetJob, context: SetContext) -> str:
    return content_key(
        kind="sim",
        spec=job.spec.key(),
        frames=job.spec.frames_per_sim,
        clip=[context.clip_len, context.clip_stride],
        box=list(context.box),
        net=context.checkpoint_digest,
    )


def null_job(spec: DatasetSpec) -> SetJob:
    """The set S': the nominal spec under simulation seeds :data:`NULL_SEED_OFFSET` away."""
    return SetJob("S'", dataclasses.replace(spec, seed=spec.seed + NULL_SEED_OFFSET))


def nominal_path(spec: DatasetSpec, context: SetContext) -> Path:
    """Where the nominal set S's features are cached."""
    return _cache_path(context, _sim_key(SetJob("S", spec), context))


def assignment_job(spec: DatasetSpec, library: dict[str, Candidate], chosen: Assignment) -> SetJob:
    """The set of S with every candidate of ``chosen`` at its strength (labelled by them)."""
    for name, value in chosen:
        spec = library[name].apply(spec, value)
    return SetJob("joint:" + "+".join(_label(library[n], v) for n, v in chosen), spec)


def build_set(job: SetJob, context: SetContext, threads: int = 1) -> tuple[str, dict]:
    """Features of one simulated set (from the cache when present); returns (path, seconds).

    Runs in a worker process under joblib: one torch thread, its own renderer and net.
    """
    use_process_threads(threads)
    path = _cache_path(context, _sim_key(job, context))
    if path.is_file():
        return str(path), {}
    start = time.perf_counter()
    parts: dict[str, float] = {}
    clips = simulated_clips(
        job.spec,
        context.mesh_cache,
        clip_len=context.clip_len,
        clip_stride=context.clip_stride,
        render_cache=Path(context.cache_dir) / "renders",
        timing=parts,
    )
    middle = time.perf_counter()
    features = ladder_features(clips, context.box, _net(context), device=context.device)
    features.save(path)
    return str(path), {
        "generate": middle - start,
        **{f"generate: {name}": value for name, value in parts.items()},
        "features": time.perf_counter() - middle,
    }


def run_jobs(jobs: list[SetJob], context: SetContext, n_jobs: int, progress: bool, timing: dict):
    """Build the sets of ``jobs`` not yet cached (in ``n_jobs`` worker processes).

    Returns ``({label: features}, how many came from the cache)``; adds seconds per step to
    ``timing``.
    """
    from tqdm.auto import tqdm

    todo = [j for j in jobs if not _cache_path(context, _sim_key(j, context)).is_file()]
    bar = tqdm(total=len(todo), desc="candidate sets", unit="set", disable=not progress)
    try:
        if n_jobs == 1 or len(todo) <= 1:
            results = (build_set(j, context) for j in todo)
        else:
            from joblib import delayed

            from common.processes import run_in_workers

            results = run_in_workers(n_jobs, (delayed(build_set)(j, context) for j in todo))
        for _, seconds in results:
            for name, value in seconds.items():
                timing[name] = timing.get(name, 0.0) + value
            bar.update(1)
    finally:
        bar.close()
    return {
        j.label: LadderFeatures.load(_cache_path(context, _sim_key(j, context))) for j in jobs
    }, len(jobs) - len(todo)


@dataclasses.dataclass
class SetBank:
    """The diagnosis's simulated sets by label, built on demand (read from the cache if there).

    It grows as the diagnosis asks for more sets (refined strengths, coalitions, the joint
    fit's assignments) and counts what it built and what it found cached.
    """

    context: SetContext
    n_jobs: int
    progress: bool
    timing: dict
    sets: dict[str, LadderFeatures] = dataclasses.field(default_factory=dict)
    jobs: list[SetJob] = dataclasses.field(default_factory=list)
    cached: int = 0

    def build(self, jobs: list[SetJob]) -> dict[str, LadderFeatures]:
        """Build (or read) the sets of ``jobs`` not in the bank yet; returns those new sets."""
        todo = [j for j in jobs if j.label not in self.sets]
        built, cached = run_jobs(todo, self.context, self.n_jobs, self.progress, self.timing)
        self.sets.update(built)
        self.jobs.extend(todo)
        self.cached += cached
        return built

    def __getitem__(self, label: str) -> LadderFeatures:
        return self.sets[label]

    def of(self, candidate: Candidate, values) -> list[LadderFeatures]:
        """The candidate's sets at ``values``."""
        return [self.sets[_label(candidate, v)] for v in values]

    def counts(self) -> dict[str, int]:
        """Sets built, read from the cache, and in all (S counted too)."""
        return {
            "built": len(self.jobs) - self.cached,
            "cached": self.cached,
            "total": len(self.jobs) + 1,
        }


def _real_digest(real_dir: Path) -> str:
    parts = [file_digest(real_dir / "labels.csv")]
    for path in sorted(real_dir.rglob("*")):
        if path.is_file() and path.name != "labels.csv":
            stat = path.stat()
            parts.append(f"{path.relative_to(real_dir)}:{stat.st_size}:{stat.st_mtime_ns}")
    return content_key(files=parts)


def real_ladder(
    real_dir: Path, clips: ClipSet, context: SetContext, *, fps: float, max_clips: int | None
) -> LadderFeatures:
    """The real clips on every rung of ``context``'s network (cached by content)."""
    key = content_key(
        kind="real",
        files=_real_digest(Path(real_dir)),
        clip=[context.clip_len, context.clip_stride],
        fps=fps,
        size=int(clips.frames.shape[2]),
        max_clips=max_clips,
        box=list(context.box),
        net=context.checkpoint_digest,
    )
    path = _cache_path(context, key)
    if path.is_file():
        return LadderFeatures.load(path)
    features = ladder_features(clips, context.box, _net(context), device=context.device)
    features.save(path)
    return features


@dataclasses.dataclass(frozen=True)
class DiagnosisRequest:
    """What to diagnose and how: R's folder, the trained run, the budget and the caches.

    Checked when made, so a bad request fails before anything is read or written.
    """

    real_dir: Path
    """The real footage (``docs/datasets.md`` "Real footage")."""
    run: str | Path
    """The trained run whose training data is S."""
    cache_dir: Path
    """Content-keyed cache of every set's features (shared between diagnoses)."""
    mesh_cache: str | Path
    """Cache of the simulated cloth meshes."""
    budget: Budget
    candidates: list[str] | str | None = None
    """Candidate names, a stage name or ``all`` (:func:`select_candidates`)."""
    strengths: dict | None = None
    """Strengths per candidate name, replacing the library's grid."""
    data_dir: str | Path | None = None
    """The run's training data folder, when not the one its config names."""
    clip_len: int = 10
    clip_stride: int = 10
    alpha: float = 0.05
    seed: int = 0
    sim_seed: int = 0
    """Draws the simulations of S (another value: another draw of the same scene)."""
    n_jobs: int = 1
    device: str = "auto"
    name: str | None = None
    """The report's name (default: ``<real_dir name>-<run name>``)."""
    progress: bool = True

    def __post_init__(self):
        object.__setattr__(self, "real_dir", Path(self.real_dir))
        object.__setattr__(self, "cache_dir", Path(self.cache_dir))
        check_int("n_jobs", self.n_jobs)
        if not 0 < self.alpha < 1:
            raise ValueError(f"alpha must be in (0, 1), got {self.alpha}")
        if self.device not in ("auto", "cpu", "cuda"):
            raise ValueError(f"device must be auto, cpu or cuda, got {self.device!r}")

    @property
    def report_name(self) -> str:
        """The report's name."""
        return self.name or f"{self.real_dir.name}-{Path(self.run).name}"


def run_diagnosis(request: DiagnosisRequest, out_dir: str | Path) -> Diagnosis:
    """Diagnose the gap between ``request.real_dir`` and the data its run was trained on.

    Returns the diagnosis (also written as ``out_dir/report.json`` with the Markdown and
    HTML reports and figures). See :mod:`sim2real.diagnosis` for the method.
    """
    timing: dict[str, float] = {}
    start = time.perf_counter()
    out_dir, budget, r = Path(out_dir), request.budget, request
    clip_len, clip_stride, alpha, seed = r.clip_len, r.clip_stride, r.alpha, r.seed
    device = r.device
    if device == "auto":
        import torch

        device = "cuda" if torch.cuda.is_available() else "cpu"
    train_spec, checkpoint = load_run(r.run, r.data_dir)
    net = _load_net(str(checkpoint), device, train_spec.material_set)  # before any work
    if train_spec.camera.width != train_spec.camera.height:
        raise ValueError("the training data's frames are not square; real clips are square crops")
    spec = diagnosis_spec(
        train_spec,
        classes=spanning_classes(train_spec.classes, budget.class_grid, train_spec.material_set),
        sims_per_class=budget.sims_per_class,
        clips_per_sim=budget.clips_per_sim,
        seed_offset=SIM_SEED_OFFSET + SIM_SEED_STEP * check_int("sim_seed", r.sim_seed, low=0),
    )
    library = candidate_library(spec)
    chosen = select_candidates(library, r.candidates)
    plan = _strength_plan(chosen, r.strengths or {}, budget.strengths)
    # Real clips first: a bad real folder fails before any simulation.
    real = real_clips(
        r.real_dir,
        size=spec.camera.height,
        clip_len=clip_len,
        clip_stride=clip_stride,
        fps=spec.preset.fps,
        max_clips_per_video=budget.clips_per_sim,
    )
    if real.group_count < 4:
        raise ValueError(
            f"real_dir: {real.group_count} usable videos; the diagnosis needs at least 4 "
            "(its noise floor splits the videos in halves)"
        )
    timing["read real"] = time.perf_counter() - start

    # Nominal S: simulated here (its coverage fixes the cloth box for every domain).
    tick = time.perf_counter()
    use_process_threads(1)
    nominal_clips = simulated_clips(spec, r.mesh_cache, clip_len=clip_len, clip_stride=clip_stride)
    box = roi_box(nominal_clips.coverage)
    context = SetContext(
        box=tuple(int(v) for v in box),
        checkpoint=str(checkpoint),
        checkpoint_digest=file_digest(checkpoint),
        mesh_cache=str(r.mesh_cache),
        cache_dir=str(r.cache_dir),
        clip_len=clip_len,
        clip_stride=clip_stride,
        device=device,
    )
    _NETS[(context.checkpoint, device)] = net
    timing["generate"] = time.perf_counter() - tick

    tick = time.perf_counter()
    real_features = real_ladder(
        r.real_dir, real, context, fps=spec.preset.fps, max_clips=budget.clips_per_sim
    )
    cached_nominal = nominal_path(spec, context)
    if cached_nominal.is_file():
        nominal = LadderFeatures.load(cached_nominal)
    else:
        nominal = ladder_features(nominal_clips, context.box, net, device=device)
        nominal.save(cached_nominal)
    timing["features"] = time.perf_counter() - tick

    # S': the nominal scene under other simulation seeds (the null candidate, and the gap
    # test's second nominal draw).
    bank = SetBank(context, r.n_jobs, r.progress, timing)
    bank.build([null_job(spec), *_candidate_jobs(spec, plan)])

    tick = time.perf_counter()
    reference = compare_domains(
        nominal,
        bank["S'"],
        real_features,
        n_perm=budget.n_perm,
        n_boot=budget.n_boot,
        n_floor=budget.n_floor,
        seed=seed,
        alpha=alpha,
    )
    detection, location, gaps = reference.detection, reference.location, reference.gaps
    timing["fit"] = time.perf_counter() - tick

    fits = fit_candidates(plan, spec, bank, reference, budget=budget, seed=seed)
    plan, results, null = fits.plan, fits.results, fits.null
    with _timed(timing, "fit"):
        probes = probe_transfer(nominal, real_features)
    with _timed(timing, "detectability"):
        detectability = candidate_detectability(
            plan,
            bank.sets,
            nominal,
            bank["S'"],
            _label,
            alpha=alpha,
            n_perm=budget.n_perm,
            seed=seed,
        )
    decision = decide(fits, spec, bank, reference, budget=budget, alpha=alpha, seed=seed)
    ranking = decision.ranking
    tick = time.perf_counter()
    joint = _joint_fit(
        plan, results, null, spec, library, budget, bank=bank, reference=reference, seed=seed
    )
    timing["joint"] = time.perf_counter() - tick
    swaps = _stage_swaps(spec, library, plan, bank, reference, real, net, budget=budget, seed=seed)
    timing["total"] = time.perf_counter() - start

    kernel = functools.partial(  # as the ranking measures the top candidate's
        kernel_closure, rungs=ranking.kernel_rungs, threshold=ranking.threshold
    )
    draft = Diagnosis(
        name=r.report_name,
        inputs=DiagnosisInputs(
            real_dir=str(r.real_dir),
            run=str(r.run),
            checkpoint=str(checkpoint),
            data_dir=None if r.data_dir is None else str(r.data_dir),
            mesh_cache=str(r.mesh_cache),
            cache_dir=str(r.cache_dir),
            clip_len=clip_len,
            clip_stride=clip_stride,
            real_videos=real.group_count,
            real_clips=len(real),
            real_skipped=list(real.skipped),
            sim_clips=len(nominal),
            sim_groups=len(set(nominal.groups.tolist())),
            budget=budget.name,
            budget_settings=dataclasses.asdict(budget),
            box=list(context.box),
            training_spec_key=train_spec.key(),
            nominal_spec=spec.to_json(),
            alpha=alpha,
            seed=seed,
            sim_seed=r.sim_seed,
            device=device,
            checkpoint_digest=context.checkpoint_digest,
        ),
        rungs={n: g.to_json() for n, g in gaps.items()},
        detection_rungs={n: g.to_json() for n, g in detection.items()},
        location=Location.from_json(location),
        scored_rungs=reference.rungs,
        reference_auc=reference.before.auc,
        reference_classifier=reference.before.to_json(),
        candidates={
            c.name: {**c.to_json(), "best": c.best, "kernel_closure": kernel(c)} for c in results
        },
        null={**null.to_json(), "kernel_closure": kernel(null)},
        ranking=ranking,
        residual=decision.residual,
        shapley=decision.shapley,
        stacked=decision.stacked,
        joint=joint,
        counterfactuals=swaps,
        residual_stage=stage_of_residual(
            location, ranking.stage_scores, {n: g.corrected_auc for n, g in gaps.items()}
        ),
        detectability=detectability,
        probes=probes,
        sets=bank.counts(),
        timing=timing,
    )
    # plain JSON values throughout (numpy scalars to numbers), as a stored report reads back
    diagnosis = Diagnosis.from_json(json_safe(draft.to_json()))
    sheet_rows = {"S (nominal simulation)": nominal_clips.frames[0]}
    sheet_rows.update({f"R: {real.groups[i]}": real.frames[i] for i in _spread(len(real), 3)})
    out_dir.mkdir(parents=True, exist_ok=True)
    contact_sheet(out_dir / "clips.png", sheet_rows, context.box)
    write_report(diagnosis, out_dir, extra_figures=("clips.png",))
    return diagnosis


@contextlib.contextmanager
def _timed(timing: dict, key: str):
    """Adds the seconds the block takes to ``timing[key]``."""
    tick = time.perf_counter()
    try:
        yield
    finally:
        timing[key] = timing.get(key, 0.0) + time.perf_counter() - tick


@dataclasses.dataclass(frozen=True)
class CandidateFits:
    """Every planned candidate scored against R, its strength fitted, beside the null draw."""

    plan: list[tuple]
    """(candidate, the strengths its sets were built at), refined around each best one."""
    results: list[CandidateResult]
    """Each candidate's closures, best strength and fitted strength with its interval."""
    null: CandidateResult
    """S' scored as a candidate: the closure of chance."""


def fit_candidates(
    plan: list[tuple], spec, bank: SetBank, reference: Reference, *, budget: Budget, seed: int
) -> CandidateFits:
    """Score the plan, refine its strengths, fit each, and measure each fit where it landed.

    Refined strengths and fitted ones the budget asks to measure are built in ``bank``.
    """
    timing = bank.timing
    with _timed(timing, "fit"):
        refined = _refine(plan, _score_plan(plan, bank, reference), budget.refine)
    bank.build(_candidate_jobs(spec, refined))
    plan = refined
    with _timed(timing, "fit"):
        results = _fit_plan(plan, bank, reference, n_boot=budget.n_boot, seed=seed)
    for _ in range(FIT_CHECKS):  # measure each top candidate at its fitted strength, refit
        checked = _check_fits(plan, results, budget.refine)
        if checked == plan:
            break
        bank.build(_candidate_jobs(spec, checked))
        plan = checked
        with _timed(timing, "fit"):
            results = _fit_plan(plan, bank, reference, n_boot=budget.n_boot, seed=seed)
    null = reference.score("S'", "null", (None,), [bank["S'"]])
    return CandidateFits(plan, results, null)


@dataclasses.dataclass(frozen=True)
class Decision:
    """Which candidate, or which candidates together, the rules name as the cause."""

    ranking: Ranking
    residual: dict | None
    """The gap tests between R and the top candidate's best set (:func:`_residual_gap`)."""
    shapley: dict | None
    """The top candidates' coalitions and Shapley values (:func:`_shapley`)."""
    stacked: dict | None
    """The fit of a partner on top of the leader (:func:`sim2real.stacking.stacked_fit`)."""


def decide(
    fits: CandidateFits,
    spec,
    bank: SetBank,
    reference: Reference,
    *,
    budget: Budget,
    alpha: float,
    seed: int,
) -> Decision:
    """Rank the candidates, then let a coalition or a stacked pair explain what one cannot.

    Coalition and stacked sets are built in ``bank``.
    """
    plan, results = fits.plan, fits.results
    with _timed(bank.timing, "fit"):
        ranking = rank_candidates(results, fits.null, reference.kernel_rungs)
        residual = _residual_gap(ranking, plan, results, bank, reference.real, budget, alpha, seed)
    coalitions = _coalition_plan(plan, results, budget.shapley_top)
    bank.build([SetJob(label, spec_of(spec)) for label, spec_of in coalitions.items()])
    shapley = _shapley(coalitions, results, bank, reference)
    ranking = explained_together(ranking, shapley, {r.name: r.best_score for r in results})
    ranking, stacked = _stack_on_leader(
        ranking,
        plan,
        results,
        spec,
        budget,
        build=lambda specs: bank.build([SetJob(label, s) for label, s in specs.items()]),
        score=lambda name, stage, values, labels: reference.score(
            name, stage, values, [bank[label] for label in labels]
        ),
    )
    return Decision(ranking, residual, shapley, stacked)


def _stage_swaps(
    spec, library, plan, bank: SetBank, reference: Reference, real: ClipSet, net, *, budget, seed
) -> dict:
    """Counterfactuals (b) camera statistics of R emulated on S and (c) AdaBN on R.

    Camera effects missing from the candidate plan are built here (re-renders only).
    """
    timing = bank.timing
    tick = time.perf_counter()
    nominal, real_features, gaps = reference.nominal, reference.real, reference.gaps
    planned = {c.name: values for c, values in plan}
    camera = [
        (c, planned.get(c.name) or c.strengths(budget.strengths))
        for c in library.values()
        if c.stage == "camera" and not c.binary and not c.choices
    ]
    bank.build(_candidate_jobs(spec, camera))
    rng = np.random.default_rng([seed, 11])
    rivals = {c.name: bank.of(c, values) for c, values in plan}
    signatures = camera_signatures(
        nominal,
        {c.name: (values, bank.of(c, values), c.neutral) for c, values in camera},
        rivals,
        rng=rng,
    )
    matched = match_camera(signatures, real_features, nominal, rng=rng)
    present = [(library[n], m["strength"]) for n, m in matched.items() if m["present"]]
    camera_entry = {"matched": matched, "set": None, "rungs": None}
    if present:
        members = [(c, round(v) if c.integer else float(f"{v:.4g}")) for c, v in present]
        label = "camera-swap:" + "+".join(c.label(v) for c, v in members)
        swapped = spec
        for candidate, value in members:
            swapped = candidate.apply(swapped, value)
        bank.build([SetJob(label, swapped)])
        camera_entry["set"] = label
        camera_entry["rungs"] = swap_closure(
            nominal, real_features, gaps, sim_after=bank[label], rng=rng
        )
    adapted_features = _adapted_real(real, real_features, bank.context, net)
    entry = {
        "camera": camera_entry,
        "batchnorm": batchnorm_swap(
            nominal, real_features, adapted_features, gaps, spec.material_set.grid, rng=rng
        ),
    }
    timing["counterfactuals"] = time.perf_counter() - tick
    return entry


def _adapted_real(real, real_features: LadderFeatures, context: SetContext, net):
    """R's layers through the network with batch-norm statistics re-estimated on R (cached)."""
    key = content_key(
        kind="real-adabn",
        real=_real_digest_of(real),
        net=context.checkpoint_digest,
        box=list(context.box),
    )
    path = _cache_path(context, key)
    if path.is_file():
        return LadderFeatures.load(path)
    adapted = adapt_batchnorm(net, real.frames, device=context.device)
    if adapted is None:
        return None
    layers = layer_features(adapted, real.frames, device=context.device)
    features = dataclasses.replace(real_features, rungs={**real_features.rungs, **layers})
    features.save(path)
    return features


def _real_digest_of(real) -> str:
    """Content hash of a real clip set's frames and groups."""
    digest = hashlib.sha256(np.ascontiguousarray(real.frames).tobytes())
    digest.update("\n".join(real.groups.tolist()).encode())
    return digest.hexdigest()[:20]


def _residual_gap(ranking, plan, results, bank: SetBank, real, budget, alpha, seed) -> dict | None:
    """The gap tests of :func:`localise` between R and the top candidate's best set.

    A cause that is really the missing effect leaves no significant gap behind at its
    fitted strength; a look-alike that closes part of the gap usually does.
    """
    top = ranking.top
    if top is None:
        return None
    i = next(i for i, r in enumerate(results) if r.name == top)
    strength = results[i].best_strength
    after = rung_gaps(
        bank[_label(plan[i][0], strength)],
        real,
        n_perm=budget.n_perm,
        n_boot=budget.n_boot,
        n_floor=budget.n_floor,
        seed=seed,
    )
    location = localise(after, alpha=alpha)
    return {
        "candidate": top,
        "strength": strength,
        "gap_p": location["gap_p"],
        "significant": location["significant"],
        "corrected_auc": {n: g.corrected_auc for n, g in after.items()},
        "p_gap": {n: g.p_gap for n, g in after.items()},
    }


def explained_together(ranking: Ranking, shapley: dict | None, alone: dict[str, float]) -> Ranking:
    """The ranking, explained by the top candidate's best coalition when it alone is not.

    Two effects at once (a sealed pair, a real camera with two faults) each close only part
    of the gap. A coalition explains the gap (``explained_by``, the top candidate named
    first) when it holds the top candidate, reaches the open-set threshold, its kernel
    closure confirms it (:func:`sim2real.diagnosis.agrees`), and every member adds to it:
    the coalition closes more than it does without that member (``alone``: each candidate's
    own closure). Without the last condition a look-alike that lowers the closure rides along.

    The coalition must clear the threshold by :data:`~sim2real.diagnosis.OPEN_SET_MARGIN`,
    the margin a single candidate keeps over a fresh nominal draw: its members' strengths
    are all fitted and it is the best of several coalitions, so it closes more by chance
    (decision record: docs/design/sim2real-coalitions.md).
    """
    if ranking.explained or not shapley or ranking.top is None or ranking.neutral_in_interval:
        return ranking
    measured = {frozenset([n]): v for n, v in alone.items()}
    measured.update({frozenset(k.split("+")): v for k, v in shapley["coalitions"].items()})

    def without(coalition: frozenset) -> list[float]:
        return [measured[coalition - {m}] for m in coalition]

    holding = {
        k: v
        for k, v in shapley["coalitions"].items()
        if ranking.top in k.split("+")
        and explains_together(
            v, shapley["kernel_closure"][k], ranking.threshold, without(frozenset(k.split("+")))
        )
    }
    if not holding:
        return ranking
    best = max(holding, key=holding.get)
    return dataclasses.replace(
        ranking,
        explained=True,
        look_alike=False,
        explained_by=best.split("+"),
        explained_by_score=holding[best],
        explained_by_kernel_closure=shapley["kernel_closure"][best],
    )


def _stack_on_leader(ranking: Ranking, plan, results, spec, budget, *, build, score):
    """The ranking, explained by a partner fitted on top of the leader when it alone is not.

    Runs :func:`sim2real.stacking.stacked_fit` when nothing explains the gap yet and the
    leader closes at least :data:`~sim2real.stacking.STACK_MIN_LEADER`; partners are the
    candidates that re-render, each over its budget grid. Returns (ranking, the fit or
    ``None``).
    """
    top = ranking.top
    if ranking.explained or top is None or ranking.neutral_in_interval:
        return ranking, None
    i = next(i for i, r in enumerate(results) if r.name == top)
    if results[i].best_score < STACK_MIN_LEADER:
        return ranking, None
    partners = [
        (c, c.strengths(budget.strengths), results[j].best_score)
        for j, (c, _) in enumerate(plan)
        if j != i and not c.needs_simulation
    ]
    fit = stacked_fit(
        spec,
        plan[i][0],
        results[i],
        plan[i][1],
        partners,
        build,
        score,
        kernel=lambda r: kernel_closure(r, ranking.kernel_rungs),
        threshold=ranking.threshold,
    )
    return (explained_by_stack(ranking, fit) if fit["explained"] else ranking), fit


def _coalition_plan(plan: list[tuple], results: list, top: int) -> dict:
    """Label -> spec builder of every coalition (2 or more) of the ``top`` best candidates.

    Only candidates that close part of the gap play; each joins at its fitted strength.
    """
    order = sorted(range(len(plan)), key=lambda i: results[i].best_score, reverse=True)
    players = [i for i in order[:top] if results[i].best_score > 0]
    out = {}
    for size in range(2, len(players) + 1):
        for group in itertools.combinations(players, size):
            members = [(plan[i][0], results[i].best_strength) for i in group]
            label = "coalition:" + "+".join(c.name for c, _ in members)

            def spec_of(spec, members=members):
                for candidate, strength in members:
                    spec = candidate.apply(spec, strength)
                return spec

            out[label] = spec_of
    return out


def _shapley(coalitions, results, bank: SetBank, reference: Reference) -> dict | None:
    """Shapley values of the top candidates from the coalition sets (``None``: < 2 players).

    Also each coalition's kernel closure (:func:`sim2real.diagnosis.kernel_closure`), which
    :func:`explained_together` checks.
    """
    if not coalitions:
        return None
    by_name = {r.name: r for r in results}
    players = sorted({n for label in coalitions for n in label.split(":", 1)[1].split("+")})
    on = reference.kernel_rungs
    value = {frozenset(): 0.0}
    value.update({frozenset([n]): by_name[n].best_score for n in players})
    kernel = {}
    for label in coalitions:
        names = label.split(":", 1)[1].split("+")
        scored = reference.score(label, "coalition", (None,), [bank[label]])
        value[frozenset(names)] = scored.best_score
        kernel["+".join(sorted(names))] = kernel_closure(scored, on)
    closure = best_subset_values(value)
    return {
        "players": players,
        "values": shapley_values(players, closure),
        "coalitions": {"+".join(sorted(k)): v for k, v in value.items() if len(k) > 1},
        "closure": {"+".join(sorted(k)): v for k, v in closure.items() if len(k) > 1},
        "kernel_closure": kernel,
    }


def _set_closure(nominal_oof: dict, result, j: int, reference: Reference) -> float:
    """The divergence closure of a scored result's ``j``-th set (its ``j``-th strength)."""
    own = {r: result.scores_oof[r][j] for r in reference.rungs}
    return float(divergence_closure(nominal_oof, own, reference))


def _joint_pool(
    plan: list[tuple], results: list, reference: Reference, budget: Budget, nominal_oof: dict
) -> list[Factor]:
    """Every candidate as a factor the joint fit may choose, with the strengths it tries.

    The strengths are up to ``budget.joint_strengths`` of those the candidate was scored at,
    spread over them, plus the one that alone removed most of S's divergence to R. A
    candidate whose fitted interval holds its neutral strength is left out, as the ranking
    leaves it out (:attr:`CandidateResult.holds_neutral`): the data cannot tell it from its
    absence, and a factor that can be set to "as S" closes the gap only by chance.
    """
    pool = []
    for (candidate, _), result in zip(plan, results, strict=True):
        if result.holds_neutral:
            continue
        values = list(result.strengths)
        closures = [_set_closure(nominal_oof, result, j, reference) for j in range(len(values))]
        best = values[int(np.argmax(closures))]
        picked = {values[k] for k in _spread(len(values), budget.joint_strengths)} | {best}
        options = tuple(v for v in values if v in picked)
        setting = f"{candidate.registry}.{candidate.field}"
        pool.append(
            Factor(
                candidate.name,
                candidate.stage,
                options,
                setting=setting,
                simulated=candidate.needs_simulation,
                log_scale=bool(candidate.log_scale),
                integer=bool(candidate.integer),
            )
        )
    return pool


def _joint_fit(
    plan, results, null, spec, library, budget: Budget, *, bank: SetBank, reference, seed: int
):
    """The joint selection, calibration and attribution (``None`` without a scored rung).

    Additions are screened on S*'s features shifted by each single-candidate set's change
    (:meth:`LadderFeatures.shifted`); what S' closes is the floor a factor that re-simulates
    must beat.
    """
    if budget.joint_top == 0 or not reference.rungs:
        return None
    nominal = reference.nominal

    def features_of(chosen: Assignment) -> LadderFeatures:
        return bank[assignment_job(spec, library, chosen).label] if chosen else nominal

    def evaluate(batch: list[Assignment]) -> list:
        bank.build([assignment_job(spec, library, chosen) for chosen in batch if chosen])
        built = [features_of(chosen) for chosen in batch]
        return closure_values(built, reference, n_boot=budget.n_boot, seed=seed)

    def screen(current: Assignment, additions) -> list[float]:
        base = features_of(current)
        estimates = [base.shifted(bank[_label(library[n], v)], nominal) for n, v in additions]
        return point_closures(estimates, reference)

    nominal_oof = nominal_scores(reference)
    floor = max(_set_closure(nominal_oof, null, 0, reference), 0.0)
    fit = fit_jointly(
        _joint_pool(plan, results, reference, budget, nominal_oof),
        evaluate,
        screen=screen,
        top=budget.joint_top,
        verify=budget.joint_verify,
        floor=floor,
        rounds=budget.joint_rounds,
        interval_refine=budget.joint_interval_refine,
        refit=budget.joint_refit,
        prune=budget.joint_prune,
        lookahead=budget.joint_lookahead,
    )
    return dataclasses.replace(fit, kernel_gap=bool(reference.kernel_rungs))


def _score_plan(plan: list[tuple], bank: SetBank, reference: Reference) -> list:
    """Each planned candidate's sets scored against R (:meth:`Reference.score`)."""
    return [
        reference.score(c.name, c.stage, values, bank.of(c, values), neutral=c.neutral)
        for c, values in plan
    ]


def _fit_plan(
    plan: list[tuple], bank: SetBank, reference: Reference, *, n_boot: int, seed: int
) -> list:
    """Each planned candidate scored, with its strength fitted and the fit's interval."""
    return [
        fit_strength(
            result,
            bank.of(c, values),
            reference.nominal,
            reference.real,
            reference.gaps,
            reference.rungs,
            log_scale=c.log_scale,
            n_boot=n_boot,
            rng=np.random.default_rng([seed, 7, i]),
            before=reference.before,
        )
        for i, (result, (c, values)) in enumerate(
            zip(_score_plan(plan, bank, reference), plan, strict=True)
        )
    ]


def _label(candidate: Candidate, value) -> str:
    return f"{candidate.name}@{value!r}"


def _candidate_jobs(spec: DatasetSpec, plan: list[tuple]) -> list[SetJob]:
    return [SetJob(_label(c, v), c.apply(spec, v)) for c, values in plan for v in values]


REFINE_TOP = 5
"""Candidates (best first) whose strength grid :func:`_refine` densifies."""


def _grow_top(plan: list[tuple], results: list, mode: str, extra_of) -> list[tuple]:
    """The plan with ``extra_of(candidate, values, result)`` added to the top candidates' grids.

    Top: the :data:`REFINE_TOP` best scores. ``mode``: ``none``; ``visual`` (only candidates
    that re-render, which cost no simulation); ``all``. Switches and choices are left alone.
    """
    if mode == "none":
        return plan
    order = sorted(range(len(plan)), key=lambda i: results[i].best_score, reverse=True)
    chosen = set(order[:REFINE_TOP])
    out = []
    for i, (candidate, values) in enumerate(plan):
        grows = (
            i in chosen
            and candidate.low is not None
            and not candidate.choices
            and not (mode == "visual" and candidate.needs_simulation)
        )
        extra = set(extra_of(candidate, values, results[i])) if grows else set()
        out.append((candidate, tuple(sorted(set(values) | extra)) if extra else values))
    return out


def _refine(plan: list[tuple], results: list, mode: str) -> list[tuple]:
    """The plan with midpoints on both sides of the best strength of the top candidates.

    Midpoints are geometric on log-spaced grids, else arithmetic; ``mode`` as in
    :func:`_grow_top`.
    """

    def midpoints(candidate, values, result):
        for j in (result.best - 1, result.best + 1):
            if len(values) >= 2 and 0 <= j < len(values):
                yield midpoint(
                    values[result.best],
                    values[j],
                    log_scale=bool(candidate.log_scale),
                    integer=bool(candidate.integer),
                )

    return _grow_top(plan, results, mode, midpoints)


FIT_CHECKS = 2
"""Rounds of :func:`_check_fits`: each builds the new fitted strengths and refits."""


def _check_fits(plan: list[tuple], results: list, mode: str) -> list[tuple]:
    """The plan with each top candidate's fitted strength added to its grid, to be measured.

    The score of a strength between grid points is not interpolated: the closure can be
    steep, so the fitted strength is built and scored like the others (decision record:
    docs/design/sim2real-strength-fit.md). A fit within 1 % of a strength already tried adds
    nothing. ``mode`` as in :func:`_grow_top`.
    """

    def fitted(candidate, values, result):
        if result.fitted is None:
            return
        value = round(result.fitted) if candidate.integer else float(result.fitted)
        value = min(max(value, candidate.low), candidate.high)
        if all(abs(value - v) > 0.01 * abs(v) for v in values):
            yield value

    return _grow_top(plan, results, mode, fitted)


def _spread(count: int, want: int) -> list[int]:
    return sorted({round(v) for v in np.linspace(0, count - 1, min(want, count))})


def _strength_plan(chosen: list[Candidate], overrides: dict, count: int) -> list[tuple]:
    unknown = sorted(set(overrides) - {c.name for c in chosen})
    if unknown:
        raise ValueError(
            f"strengths: {unknown} are not among the chosen candidates {[c.name for c in chosen]}"
        )
    plan = []
    for candidate in chosen:
        values = overrides.get(candidate.name)
        if values is None:
            values = candidate.strengths(count)
        else:
            values = tuple(values)
            for value in values:
                candidate.check_strength(value)
        plan.append((candidate, tuple(values)))
    return plan
