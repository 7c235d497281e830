"""How far the gap shrinks: retrain with the identified effect, measure before and after.

``python -m sim2real.shrink report=outputs/sim2real/<name> [epochs=8] [data_preset=small]
[control=true]`` reads a diagnosis (``report.json``), regenerates the training data of its run
with every factor of the calibrated simulator S* (or, without a joint fit, the named effect) at
its fitted strength (``datasets.generation``, same scene, seeds and settings;
``use_effects=name=strength,...`` overrides the choice), fine-tunes the run's model on it from its
weights (``models.training.train`` with the run's own config, ``init_from`` = its checkpoint),
and, with ``control``, fine-tunes it as long on the nominal data too (so that what the extra
training alone changes is told from what the calibrated simulator changes), and reports on the
real set: Pearson and Spearman of the material score with measured stiffness
and density before vs after, with bootstrap intervals (``models.evaluate.evaluate_real``), and,
per rung, the floor-corrected gap before (S vs R, old network) and after (S_e vs R, new
network) beside the closure section 2 predicted, and the sim-to-real predictivity (SRCC,
:mod:`sim2real.predictivity`) over the run's checkpoints and every fine-tuned epoch, with the
nominal simulator and with the effect added. The diagnosis report is rewritten with a section
3.

``retrain_material_set=NAME`` (a set of ``configs/material_set/``, e.g. ``wang162``) also
changes the classes the model after learns: the run's stretch x bend cells at every density of
that set (a density axis is what lets a score follow measured density). It needs
``init=scratch`` (the run's model predicts the run's classes); the gap after is measured on S_e
whose cloths draw their densities over that set's span.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path

from common.checks import check_bool, check_choice, check_int
from common.commands import hydra_command
from common.errors import InputError
from common.paths import check_output_dir
from datasets.real_video import DEFAULT_COLUMNS
from datasets.runs import find_run
from datasets.spec import PRESETS, DatasetSpec
from simulator.cloth.material import MaterialSet

from .candidates import candidate_library
from .diagnosis import rung_gaps
from .domains import real_clips, simulated_clips
from .ladder import LadderFeatures, file_digest
from .pipeline import SetContext, SetJob, build_set, real_ladder
from .predictivity import predictivity
from .report import json_safe, read_report, write_report
from .result import Diagnosis

__all__ = ["INITS", "chosen_effects", "on_material_set", "shrink"]

CALIBRATED = "calibrated"
"""``use_effects`` value: every factor of the calibrated simulator, named or not."""

INITS = ("weights", "scratch")
"""How the model after starts: the run's weights (fine-tuned) or a fresh initialisation."""


def chosen_effects(result: Diagnosis, override: str | None = None) -> list[tuple[str, object]]:
    """(candidate, strength) pairs to add to the training data.

    ``override`` ("a=1,b=2"; ``calibrated``: every factor of the calibrated simulator S*,
    named or not, :attr:`JointFit.strengths`), else every factor the joint calibration names
    (:attr:`JointFit.named`), else the explained top.
    """
    if override == CALIBRATED:
        if result.joint is None or not result.joint.strengths:
            raise ValueError(
                "use_effects=calibrated: the diagnosis has no calibrated simulator (no factor "
                "was chosen); pass use_effects=name=strength,..."
            )
        return list(result.joint.strengths.items())
    if override:
        pairs = []
        for item in override.split(","):
            name, _, value = item.partition("=")
            pairs.append((name.strip(), None if value == "" else _number(value)))
        return pairs
    if result.joint is not None and result.joint.named:
        return list(result.joint.named.items())
    ranking = result.ranking
    if not ranking.explained:
        calibrated = result.joint is not None and result.joint.strengths
        raise ValueError(
            "the diagnosis named no effect (unexplained residual); pass "
            + (
                "use_effects=calibrated (its calibrated simulator, unnamed) or "
                if calibrated
                else ""
            )
            + "use_effects=name=strength,..."
        )
    top = result.candidates[ranking.top]
    return [(ranking.top, top["best_strength"])]


def on_material_set(
    spec: DatasetSpec, material_set: MaterialSet, *, every_density: bool = True
) -> DatasetSpec:
    """``spec`` with ``material_set``'s classes at its classes' stretch x bend cells.

    ``material_set`` must share the spec's basis and stretch and bend multipliers (it may add
    densities); each class becomes its cell at every density (``every_density``) or at the
    first (a diagnosis set, whose cloths draw their densities from the prior anyway).
    """
    old = spec.material_set
    same = (old.basis, old.stretch_multipliers, old.bend_multipliers)
    new = (material_set.basis, material_set.stretch_multipliers, material_set.bend_multipliers)
    if same != new:
        raise ValueError(
            f"retrain_material_set: {material_set.name} must keep the run's basis and stretch x "
            f"bend grid ({old.name}: {old.basis}, stretch {list(old.stretch_multipliers)}, bend "
            f"{list(old.bend_multipliers)}); it may add densities"
        )
    densities = range(material_set.density_count if every_density else 1)
    cells = sorted({old.position(c)[:2] for c in spec.classes})
    classes = tuple(material_set.grid.class_id(s, b, d) for s, b in cells for d in densities)
    return dataclasses.replace(spec, material_set=material_set, classes=classes)


def _number(text: str):
    try:
        value = float(text)
    except ValueError:
        return text  # a choice (e.g. scene.pose=edge)
    return int(value) if value.is_integer() and "." not in text else value


def _apply(spec: DatasetSpec, effects: list[tuple[str, object]]) -> DatasetSpec:
    library = candidate_library(spec)
    for name, strength in effects:
        if name not in library:
            raise ValueError(f"use_effects: unknown {name!r}; allowed: {sorted(library)}")
        spec = library[name].apply(spec, strength)
    return spec


def _run_config(run: Path):
    """The run's training config, refused unless it builds only allow-listed targets."""
    from models.checkpoint import read_run_config

    config = run / ".hydra" / "config.yaml"
    if not config.is_file():
        raise FileNotFoundError(
            f"run: {run} has no .hydra/config.yaml; fine-tuning needs the run's training config"
        )
    return read_run_config(config, "run")


def _fine_tune(
    cfg, data_dir: Path, checkpoint: Path | None, out: Path, epochs: int, lr_scale: float
) -> Path:
    """Train the run's model on ``data_dir`` from ``checkpoint``, or afresh without one.

    From a checkpoint at ``lr_scale`` of the run's rate; afresh at its own rate and recipe.

    At the training rate a fresh optimizer undoes a converged model (measured: held-out
    accuracy 0.46 -> 0.14 in the first epoch on the run's own data).
    """
    from omegaconf import OmegaConf, open_dict

    lr = OmegaConf.select(cfg, "model.optimizer.lr")
    if lr is None:
        raise InputError("run: its config has no model.optimizer.lr to scale for fine-tuning")

    for key, value in {
        "dataset.dir": str(data_dir),
        "paths.output_dir": str(out),
        "paths.log_dir": str(out.parent),
        "paths.work_dir": str(out),
        "init_from": None if checkpoint is None else str(checkpoint),
        "trainer.max_epochs": epochs,
        "model.optimizer.lr": float(lr) * (1.0 if checkpoint is None else lr_scale),
        "test": False,
        "ckpt_path": "auto",
    }.items():
        OmegaConf.update(cfg, key, value, force_add=True)
    OmegaConf.update(cfg, "data.data_dirs", [str(data_dir)], force_add=True)
    if checkpoint is None:  # a fresh model takes its classes from the data, whatever the run's
        with open_dict(cfg):
            cfg.model.net.pop("num_classes", None)
            cfg.model.pop("class_grid", None)
    snapshots = {  # one checkpoint per epoch: the models whose ranking section 3 compares
        "_target_": "lightning.pytorch.callbacks.ModelCheckpoint",
        "dirpath": str(out / "checkpoints"),
        "filename": "epoch{epoch:02d}",
        "monitor": None,
        "save_top_k": -1,
        "every_n_epochs": 1,
        "auto_insert_metric_name": False,
        "enable_version_counter": False,
        "mode": "max",  # unused without a monitor; tells its state key from last.ckpt's
    }
    OmegaConf.update(cfg, "callbacks.epoch_snapshots", snapshots, force_add=True)
    from models.training import train

    train(cfg)
    best = out / "checkpoints" / "best.ckpt"
    if not best.is_file():
        raise FileNotFoundError(f"fine-tuning wrote no {best}")
    return best


def _correlations(
    module, real_dir, out, spec: DatasetSpec, clip_len, clip_stride, columns, group
) -> dict:
    """The real set's evaluation (:func:`models.evaluate.evaluate_real`).

    Every score against every column, pooled and per wind, with grouped bootstrap intervals.
    """
    from models.evaluate import evaluate_real

    return evaluate_real(
        module,
        real_dir,
        out,
        columns=columns,
        group=group,
        clip_len=clip_len,
        clip_stride=clip_stride,
        target_fps=spec.preset.fps,
        size=spec.camera.height,
    )


def shrink(
    report_dir: str | Path,
    *,
    epochs: int = 8,
    preset: str = "small",
    effects: str | None = None,
    n_jobs: int = 2,
    seed: int = 0,
    columns: Sequence[str] = DEFAULT_COLUMNS,
    group: str | None = None,
    control: bool = False,
    lr_scale: float = 0.1,
    init: str = "weights",
    material_set: MaterialSet | None = None,
) -> dict:
    """Retrain with the identified effect and measure the gap and correlations after.

    ``columns``: the measured ``labels.csv`` columns each score is correlated with (the
    first two, as in the thesis's Table 7.3, lead the report); ``group``: the column whose
    equal values form one fabric for the grouped intervals; ``control``: also train as
    long on the nominal data (the run's own training data at ``preset="same"``) and evaluate it;
    ``lr_scale``: the fine-tuning rate as a fraction of the run's training rate; ``init``:
    ``weights`` fine-tunes the run's model, ``scratch`` trains a fresh one with the run's
    recipe (its control is the run itself when it was trained as long on the same data);
    ``material_set``: the classes of the model after (:func:`on_material_set`; with
    ``init="scratch"`` only).

    Returns the section-3 dict (also stored in ``report.json`` and the rewritten reports).
    """
    from omegaconf import OmegaConf

    from datasets.generation import generate_dataset
    from models.material_classifier import load_classifier

    report_dir = Path(report_dir)
    result = read_report(report_dir, "report")
    inputs = result.inputs
    if preset != "same" and preset not in PRESETS:
        raise ValueError(f"preset must be 'same' or one of {sorted(PRESETS)}, got {preset!r}")
    chosen = chosen_effects(result, effects)
    run = Path(inputs.run)
    trained = find_run(run, inputs.data_dir)
    train_spec, checkpoint = trained.spec, trained.checkpoint
    run_config = _run_config(run)  # checked before any data is generated
    size = train_spec.preset if preset == "same" else PRESETS[preset]
    if init not in INITS:
        raise ValueError(f"init must be one of {', '.join(INITS)}, got {init!r}")
    retrain_base = dataclasses.replace(train_spec, preset=size)
    if material_set is not None and material_set != train_spec.material_set:
        if init != "scratch":
            raise ValueError(
                f"retrain_material_set: {material_set.name} has {material_set.grid.describe()} "
                f"and the run's model predicts {train_spec.material_set.num_classes}; give "
                "init=scratch"
            )
        retrain_base = on_material_set(retrain_base, material_set)
    else:
        material_set = None
    retrain_spec = _apply(retrain_base, chosen)
    out = report_dir / "shrink"
    data = out / "data"
    start = checkpoint if init == "weights" else None
    # a run trained from scratch as long on the same data is the scratch retrain's control
    run_is_control = (
        init == "scratch"
        and material_set is None
        and size == train_spec.preset
        and OmegaConf.select(run_config, "trainer.max_epochs") == epochs
    )
    generate_dataset(retrain_spec, data, n_jobs=n_jobs, mesh_cache=inputs.mesh_cache)
    after_ckpt = _fine_tune(run_config, data, start, out / "train", epochs, lr_scale)
    if control and run_is_control:
        nominal_data, control_ckpt = trained.data_dir, checkpoint
    elif control:
        nominal_data = trained.data_dir
        if size != train_spec.preset:
            nominal_data = out / "control_data"
            generate_dataset(
                dataclasses.replace(train_spec, preset=size),
                nominal_data,
                n_jobs=n_jobs,
                mesh_cache=inputs.mesh_cache,
            )
        control_ckpt = _fine_tune(
            _run_config(run), nominal_data, start, out / "control_train", epochs, lr_scale
        )

    clip_len, clip_stride = inputs.clip_len, inputs.clip_stride
    real_dir = Path(inputs.real_dir)
    before = _correlations(
        load_classifier(checkpoint),
        real_dir,
        out / "before",
        train_spec,
        clip_len,
        clip_stride,
        columns,
        group,
    )
    after = _correlations(
        load_classifier(after_ckpt),
        real_dir,
        out / "after",
        train_spec,
        clip_len,
        clip_stride,
        columns,
        group,
    )
    evaluated = {"before": before, "after": after}
    if control:
        evaluated["control"] = _correlations(
            load_classifier(control_ckpt),
            real_dir,
            out / "control",
            train_spec,
            clip_len,
            clip_stride,
            columns,
            group,
        )

    # The gap after: S with the effect vs R, both seen by the fine-tuned network.
    nominal = DatasetSpec.from_json(inputs.nominal_spec)
    if material_set is not None:
        nominal = on_material_set(nominal, material_set, every_density=False)
    context = SetContext(
        box=tuple(inputs.box),
        checkpoint=str(after_ckpt),
        checkpoint_digest=file_digest(after_ckpt),
        mesh_cache=inputs.mesh_cache,
        cache_dir=inputs.cache_dir,
        clip_len=clip_len,
        clip_stride=clip_stride,
        device=inputs.device,
    )
    path, _ = build_set(SetJob("S_e", _apply(nominal, chosen)), context)
    sim_after = LadderFeatures.load(Path(path))
    budget = inputs.budget_settings
    clips = real_clips(
        real_dir,
        size=nominal.camera.height,
        clip_len=clip_len,
        clip_stride=clip_stride,
        fps=nominal.preset.fps,
        max_clips_per_video=budget["clips_per_sim"],
    )
    real_after = real_ladder(
        real_dir, clips, context, fps=nominal.preset.fps, max_clips=budget["clips_per_sim"]
    )
    gaps_after = rung_gaps(
        sim_after,
        real_after,
        n_perm=budget["n_perm"],
        n_boot=budget["n_boot"],
        n_floor=budget["n_floor"],
        seed=seed,
    )
    # Sim-to-real predictivity over the run's checkpoints and the fine-tuned epochs.
    checkpoints = [
        checkpoint,
        *[p for p in (run / "checkpoints" / "last.ckpt",) if p.is_file() and p != checkpoint],
    ]
    checkpoints += sorted((out / "train" / "checkpoints").glob("epoch*.ckpt"))
    cut = {"clip_len": clip_len, "clip_stride": clip_stride}
    srcc = predictivity(
        checkpoints,
        simulated_clips(nominal, inputs.mesh_cache, **cut),
        simulated_clips(_apply(nominal, chosen), inputs.mesh_cache, **cut),
        clips,
        device=inputs.device,
        seed=seed,
    )
    top = chosen[0][0]
    predicted = result.candidates.get(top) if len(chosen) == 1 else None
    rungs = {}
    for name, gap in gaps_after.items():
        before_auc = result.rungs[name]["corrected_auc"]
        after_auc = gap.corrected_auc
        realised = None
        if before_auc and before_auc > 0 and after_auc == after_auc:
            realised = (before_auc - after_auc) / before_auc
        entry = {
            "corrected_auc_before": before_auc,
            "corrected_auc_after": after_auc,
            "closure_realised": realised,
        }
        if predicted is not None:  # the classifier closure where scored, else the MMD² one
            source = {**predicted["closure"], **(predicted.get("closure_auc") or {})}
            if name in source:
                entry["closure_predicted"] = source[name][predicted["best"]]
        rungs[name] = entry
    section = {
        "effects": [{"name": n, "strength": s} for n, s in chosen],
        "preset": preset,
        "epochs": epochs,
        "init": init,
        "lr_scale": lr_scale if init == "weights" else 1.0,
        "material_set": retrain_spec.material_set.name,
        "classes_after": retrain_spec.material_set.grid.describe(),
        "retrain_spec_key": retrain_spec.key(),
        "checkpoint_after": str(after_ckpt),
        "correlations": {k: v["correlations"]["all"] for k, v in evaluated.items()},
        "score_correlations": {k: v["score_correlations"] for k, v in evaluated.items()},
        "control": (
            {
                "data": str(nominal_data),
                "checkpoint": str(control_ckpt),
                "is_the_run": run_is_control,
            }
            if control
            else None
        ),
        "rungs": rungs,
        "predictivity": srcc,
        "closure_predicted_total": (
            result.joint.closure if result.joint is not None and len(chosen) > 1 else None
        ),
    }
    result = dataclasses.replace(result, shrink=json_safe(section))
    write_report(result, report_dir, extra_figures=("clips.png",))
    return result.shrink


MATERIAL_SETS = Path(__file__).resolve().parents[1] / "configs" / "material_set"
"""The sets ``retrain_material_set`` may name."""


def _material_set(name) -> MaterialSet | None:
    """The set of ``configs/material_set/<name>.yaml`` (``None``: the run's own)."""
    from omegaconf import OmegaConf

    from datasets.generate import material_set_from_config

    if name is None:
        return None
    allowed = sorted(p.stem for p in MATERIAL_SETS.glob("*.yaml"))
    if not isinstance(name, str) or name not in allowed:
        raise InputError(f"retrain_material_set must be null or one of {allowed}, got {name!r}")
    return material_set_from_config(OmegaConf.load(MATERIAL_SETS / f"{name}.yaml"))


def run(cfg) -> dict:
    """The configured shrink (``configs/shrink.yaml``), every field checked first."""
    from omegaconf import OmegaConf

    if OmegaConf.is_missing(cfg, "report"):
        raise InputError("report is required: give report=<a diagnosis folder>")
    epochs = check_int(cfg.epochs, "epochs", 1)
    n_jobs = check_int(cfg.n_jobs, "n_jobs", 1)
    check_choice(cfg.data_preset, "data_preset", ["same", *sorted(PRESETS)])
    effects = cfg.use_effects
    if effects is not None and (not isinstance(effects, str) or not effects.strip()):
        raise InputError(
            f"use_effects must be name=strength,..., calibrated or null, got {effects!r}"
        )
    columns = cfg.columns
    if (
        not OmegaConf.is_list(columns)
        or not columns
        or not all(isinstance(c, str) and c for c in columns)
    ):
        raise InputError(f"columns must be a non-empty list of labels.csv columns, got {columns!r}")
    if cfg.group is not None and not isinstance(cfg.group, str):
        raise InputError(f"group must be a labels.csv column or null, got {cfg.group!r}")
    check_bool(cfg.control, "control")
    lr_scale = cfg.lr_scale
    if isinstance(lr_scale, bool) or not isinstance(lr_scale, int | float) or not 0 < lr_scale <= 1:
        raise InputError(f"lr_scale must be a number in (0, 1], got {lr_scale!r}")
    init = check_choice(cfg.init, "init", INITS)
    material_set = _material_set(cfg.get("retrain_material_set"))
    check_output_dir(cfg.report, "report")  # the retrained model and data go in there
    try:
        return shrink(
            cfg.report,
            epochs=epochs,
            preset=str(cfg.data_preset),
            effects=effects,
            n_jobs=n_jobs,
            columns=list(columns),
            group=cfg.group,
            control=cfg.control,
            lr_scale=float(lr_scale),
            init=init,
            material_set=material_set,
        )
    except ValueError as err:  # the command's own checks name the field
        raise InputError(str(err)) from None


def _command(cfg) -> None:
    """Hydra wrapper around :func:`run`: prints the correlations before and after."""
    section = run(cfg)
    for label, c in section["correlations"].items():
        print(label, {k: (v["pearson"], v["spearman"]) for k, v in c.items()})
    print(f"report: {Path(cfg.report) / 'report.html'}")


main = hydra_command(_command, config_name="shrink")


if __name__ == "__main__":
    main()
