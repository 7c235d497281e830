"""What a 90-video real set can reveal: planted effects against their effect-free twins.

``python -m benchmarks.detection_limits --run RUN --data-dir DATA [--effect NAME=STRENGTH ...]
[--seeds 3] [--first-seed 40000] [--videos 90] [--budget quick] [--out DIR]``

A sealed set whose withheld effect leaves no trace in the footage cannot be identified by any
diagnosis; the validation counts it as a miss all the same. This measures, for the effects the
blind rounds never found, whether that is the footage's limit or the diagnosis's:

1. For each seed, the *twin*: a sealed set (``sim2real.study.seal``: its nuisances, materials,
   simulations, textures and camera shift) with no withheld effect.
2. For each ``--effect``, the same set with that effect planted at that strength: everything
   else is the twin's, so the two differ by the effect alone.
3. The first twin is diagnosed as real footage (``sim2real.diagnose``'s candidate search;
   this builds the nominal draws S and S' and fixes the cloth box). Every set is then put
   through the diagnosis's gap test (R against S and S' pooled, :func:`sim2real.study.power.
   pooled_detection`: its combined p-value and the rungs whose own tests pass), and each
   planted set is compared with its twin: whether its frames equal the twin's bit for bit
   (an inert effect), and its **effect size**: on every feature of every rung, the mean
   per-video change from the twin over the between-video standard deviation (pooled over the
   two sets: Cohen's d), the largest over all features. An unpaired test of 90 videos against
   108 simulations, on one feature chosen in advance, needs about 0.40 for 80 % power at
   alpha 0.05 (2.80 x sqrt(1/90 + 1/108)): an effect whose largest change stays well below
   it leaves nothing that a test of one feature could find (a classifier over many features
   can combine several smaller shifts: this bounds one feature, not every test). Beside it,
   the same change over the spread left once the labelled materials and wind are regressed
   out (fitted on the twin): what a test conditioned on ``labels.csv`` would have to find.
   ``--diagnose`` also runs the whole diagnosis on every planted set (several minutes each)
   and reports what it names, and the planted effect's rank and closure.

Writes ``results.md`` and ``results.json`` in ``--out`` (resumable: sealed sets and finished
reports are kept); the last line printed is JSON.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from simulator.threads import use_process_threads

DEFAULT_EFFECTS = (
    "visual.rolling_shutter=1.0",
    "scene.wind_yaw_jitter_deg=0",
    "physics.self_collision=0.02",
)
Z_POWER = 1.959964 + 0.841621  # two-sided alpha 0.05, power 0.8


def needed_effect_size(real_videos: int, sim_groups: int) -> float:
    """Standardised shift a two-sample test on one pre-chosen feature finds 80 % of the time."""
    return Z_POWER * math.sqrt(1 / real_videos + 1 / sim_groups)


def parse_effect(text: str, library: dict) -> dict:
    """``NAME=STRENGTH`` (``NAME`` alone for a switch) as a sealed answer's effect entry."""
    name, _, value = text.partition("=")
    if name not in library:
        raise ValueError(f"--effect: {name!r} is not a candidate; allowed: {sorted(library)}")
    candidate = library[name]
    strength = None
    if value:
        try:
            strength = float(value)
        except ValueError:
            strength = value
        if candidate.integer and isinstance(strength, float):
            strength = round(strength)
    candidate.check_strength(strength)
    return {"name": name, "stage": candidate.stage, "strength": strength, "library": True}


def paired_effect_size(planted, twin, covariates: np.ndarray | None = None) -> dict:
    """Largest standardised per-video change between two feature sets of the same videos.

    Both are :class:`~sim2real.ladder.LadderFeatures` of one sealed set with and without an
    effect (same videos, same clip cut). Per rung and feature: |mean over videos of the
    per-video mean change| / (between-video SD of the per-video means, pooled over the two:
    Cohen's d, the shift an unpaired test has to find; infinite where neither varies).

    With ``covariates`` (one row per video in sorted video order, e.g. :func:`label_design`)
    it also gives ``d_adjusted``: the same change over the SD that is left once a least-squares
    fit on the covariates (fitted to the twin) is taken out of both sets, the shift a test
    conditioned on the labelled materials and wind would have to find.
    """
    videos = sorted(set(twin.groups.tolist()))
    if sorted(set(planted.groups.tolist())) != videos:
        raise ValueError("the planted set and its twin hold different videos")

    def per_video(features, rung):
        rows = features.rungs[rung]
        return np.stack([rows[features.groups == v].mean(axis=0) for v in videos])

    def standardised(change, a, b, ddof):
        spread = np.sqrt(0.5 * (a.var(axis=0, ddof=ddof) + b.var(axis=0, ddof=ddof)))
        return np.where(
            spread > 0,
            change / np.where(spread > 0, spread, 1.0),
            np.where(change > 0, np.inf, 0.0),
        )

    if covariates is not None and len(covariates) != len(videos):
        raise ValueError(f"covariates: {len(covariates)} rows for {len(videos)} videos")
    best = {"d": 0.0, "rung": None, "feature": None}
    per_rung, adjusted = {}, 0.0
    for rung in twin.rungs:
        a, b = per_video(planted, rung), per_video(twin, rung)
        change = np.abs((a - b).mean(axis=0))
        d = standardised(change, a, b, 1)
        j = int(np.argmax(d))
        per_rung[rung] = float(d[j])
        if d[j] > best["d"]:
            best = {"d": float(d[j]), "rung": rung, "feature": j}
        if covariates is not None:
            fit = covariates @ np.linalg.lstsq(covariates, b, rcond=None)[0]
            adjusted = max(
                adjusted, float(standardised(change, a - fit, b - fit, covariates.shape[1]).max())
            )
    out = {**best, "per_rung": per_rung}
    if covariates is not None:
        out["d_adjusted"] = adjusted
    return out


def label_design(labels_csv: Path) -> np.ndarray:
    """The labels a material-conditioned test would take out, one row per video by name.

    Intercept, log stiffness and log density, their squares and product, and one column per
    wind level but the first.
    """
    import csv

    with open(labels_csv, newline="") as handle:
        rows = sorted(csv.DictReader(handle), key=lambda r: r["video"])
    winds = sorted({r["wind"] for r in rows})
    out = []
    for r in rows:
        s, d = np.log(float(r["stiffness"])), np.log(float(r["density"]))
        out.append([1.0, s, d, s * s, d * d, s * d] + [float(r["wind"] == w) for w in winds[1:]])
    return np.array(out)


def feature_name(rung: str | None, index: int | None) -> str:
    """A readable name for feature ``index`` of ``rung`` (network units by their index)."""
    from sim2real.rungs import HAND_RUNGS

    names = {r.name: r.feature_names for r in HAND_RUNGS}.get(rung)
    if rung is None:
        return "-"
    return f"{rung}:{names[index]}" if names else f"{rung}:unit {index}"


def frames_digest(folder: Path) -> str:
    """sha256 over every frame file of a sealed set (names and bytes; labels.csv left out)."""
    digest = hashlib.sha256()
    for path in sorted(folder.rglob("*.png")):
        digest.update(str(path.relative_to(folder)).encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()


def _row(
    tag: str,
    seed: int,
    identical: bool,
    detection: dict,
    size: dict,
    result: dict | None = None,
    name: str | None = None,
) -> dict:
    row = {
        "effect": tag,
        "seed": seed,
        "identical_to_twin": identical,
        "gap_p": detection["gap_p"],
        "gap": bool(detection["detected"]),
        "rungs": detection["rungs"],
        "named": None,
        "rank": None,
        "closure": None,
        "effect_size": size.get("d"),
        "effect_size_feature": size.get("name"),
        "effect_size_per_rung": size.get("per_rung"),
        "effect_size_adjusted": size.get("d_adjusted"),
    }
    if result is not None:
        ranking = result.ranking
        row["named"] = ranking.top if ranking.explained else "unexplained"
        if name in ranking.ranking:
            row["rank"] = ranking.ranking.index(name) + 1
            row["closure"] = result.candidates[name]["best_score"]
    return row


def _table(rows: list[dict], needed: float) -> str:
    lines = [
        f"Needed for 80 % power on one pre-chosen feature: effect size (Cohen's d) {needed:.2f}.",
        "",
        "| planted | seed | frames = twin's | gap p | gap | rungs (own p < alpha) | named | rank "
        "| closure | largest effect size (feature) | with materials and wind taken out |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        size = (
            "–"
            if r["effect_size"] is None
            else f"{r['effect_size']:.3f} ({r['effect_size_feature']})"
        )
        closure = "–" if r["closure"] is None else f"{r['closure']:.0%}"
        adjusted = r.get("effect_size_adjusted")
        adjusted = "–" if adjusted is None else f"{adjusted:.3f}"
        lines.append(
            f"| {r['effect']} | {r['seed']} | {'yes' if r['identical_to_twin'] else 'no'} | "
            f"{r['gap_p']:.3g} | {'yes' if r['gap'] else 'no'} | {', '.join(r['rungs']) or '–'} | "
            f"{r['named'] or '–'} | {r['rank'] or '–'} | {closure} | {size} | {adjusted} |"
        )
    return "\n".join(lines) + "\n"


def summarise(rows: list[dict]) -> dict:
    """Per planted effect: sets, gaps found, named first, frames equal to the twin's, sizes."""
    out = {}
    for tag in dict.fromkeys(r["effect"] for r in rows):
        mine = [r for r in rows if r["effect"] == tag]
        sizes = [r["effect_size"] for r in mine if r["effect_size"] is not None]
        adjusted = [
            r["effect_size_adjusted"] for r in mine if r.get("effect_size_adjusted") is not None
        ]
        out[tag] = {
            "sets": len(mine),
            "gap_found": sum(r["gap"] for r in mine),
            "named_first": sum(r["named"] == tag.split("=")[0] for r in mine),
            "diagnosed": sum(r["named"] is not None for r in mine),
            "identical_to_twin": sum(r["identical_to_twin"] for r in mine),
            "gap_p_median": float(np.median([r["gap_p"] for r in mine])),
            "effect_size_median": float(np.median(sizes)) if sizes else None,
            "effect_size_max": float(max(sizes)) if sizes else None,
            "effect_size_adjusted_max": float(max(adjusted)) if adjusted else None,
        }
    return out


def main(argv: list[str] | None = None) -> None:
    """Seal twins and planted sets, diagnose each, print the table and a JSON line."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--run", required=True, help="training run folder or checkpoint")
    parser.add_argument("--data-dir", help="the run's training dataset folder")
    parser.add_argument(
        "--effect", action="append", help=f"NAME=STRENGTH (default: {', '.join(DEFAULT_EFFECTS)})"
    )
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--first-seed", type=int, default=40000)
    parser.add_argument("--videos", type=int, default=90)
    parser.add_argument("--budget", default="quick")
    parser.add_argument("--mesh-cache", default="data/mesh_cache")
    parser.add_argument("--n-jobs", type=int, default=2)
    parser.add_argument("--out", default="outputs/detection_limits")
    parser.add_argument(
        "--diagnose",
        action="store_true",
        help="also run the whole diagnosis on every planted set (slow)",
    )
    args = parser.parse_args(argv)
    use_process_threads(1)
    from sim2real.candidates import candidate_library
    from sim2real.pipeline import load_run
    from sim2real.reopen import report_real_features
    from sim2real.study.power import nominal_draws, pooled_detection
    from sim2real.study.seal import seal_set
    from sim2real.study.validate import _diagnosed, load_budget

    try:
        budget = load_budget(args.budget)
        base, _ = load_run(args.run, args.data_dir)
        library = candidate_library(base)
        effects = [parse_effect(t, library) for t in args.effect or DEFAULT_EFFECTS]
        if args.seeds < 1:
            raise ValueError(f"--seeds must be >= 1, got {args.seeds}")
    except (ValueError, FileNotFoundError) as err:
        print(f"error: {err}", file=sys.stderr)
        sys.exit(2)
    out = Path(args.out)
    common = {
        "run": args.run,
        "data_dir": args.data_dir,
        "cache_dir": out / "cache",
        "mesh_cache": args.mesh_cache,
        "budget": budget,
        "candidates": "all",
        "n_jobs": args.n_jobs,
        "progress": False,
    }
    start = time.perf_counter()
    rows = []
    total = args.seeds * (1 + len(effects))

    def done(row: dict) -> None:
        rows.append(row)
        spent = time.perf_counter() - start
        left = spent / len(rows) * (total - len(rows))
        print(json.dumps(row), flush=True)
        print(
            f"[{len(rows)}/{total}] {spent / 60:.1f} min, about {left / 60:.0f} min left",
            file=sys.stderr,
            flush=True,
        )

    def sealed(folder: Path, seed: int, planted: list[dict]) -> Path:
        if not (folder / "labels.csv").is_file():
            answer = {"seed": seed, "kind": "planted" if planted else "twin", "effects": planted}
            seal_set(
                folder,
                base=base,
                seed=seed,
                videos=args.videos,
                answer=answer,
                answer_path=out / "answers" / f"{folder.name}.json",
                overwrite=True,
            )
        return folder

    # The first twin's diagnosis builds S and S' and fixes the box for every set.
    first = sealed(out / "sets" / f"twin-{args.first_seed}", args.first_seed, [])
    reference = _diagnosed(out / "reports" / first.name, {**common, "real_dir": first})
    inputs = reference.inputs
    draws = nominal_draws(inputs, 2, n_jobs=args.n_jobs)
    settings = {
        "n_perm": inputs.budget_settings["n_perm"],
        "seed": inputs.seed,
        "alpha": inputs.alpha,
    }

    def features(folder: Path):
        return report_real_features(dataclasses.replace(inputs, real_dir=str(folder)))

    def gap(found):
        return pooled_detection(draws, found, [2], **settings)[0]

    for seed in range(args.first_seed, args.first_seed + args.seeds):
        twin_dir = sealed(out / "sets" / f"twin-{seed}", seed, [])
        twin = reference if seed == args.first_seed else None
        twin_features = features(twin_dir)
        twin_digest = frames_digest(twin_dir)
        covariates = label_design(twin_dir / "labels.csv")
        done(_row("none (twin)", seed, True, gap(twin_features), {}, twin))
        for i, effect in enumerate(effects):
            tag = f"{effect['name']}={effect['strength']}"
            folder = sealed(out / "sets" / f"e{i}-{seed}", seed, [effect])
            identical = frames_digest(folder) == twin_digest
            found = twin_features if identical else features(folder)
            size = paired_effect_size(found, twin_features, covariates)
            size["name"] = feature_name(size["rung"], size["feature"])
            result = None
            if args.diagnose:
                result = _diagnosed(out / "reports" / folder.name, {**common, "real_dir": folder})
            # No gap test against the twin itself: its videos are the planted set's, so
            # group permutations that split a pair inflate the null (p near 1 even for
            # effects the diagnosis names); the effect size is the paired measure.
            done(_row(tag, seed, identical, gap(found), size, result, effect["name"]))
    needed = needed_effect_size(args.videos, inputs.sim_groups * 2)
    summary = summarise(rows)
    out.mkdir(parents=True, exist_ok=True)
    table = _table(rows, needed)
    (out / "results.md").write_text(table)
    (out / "results.json").write_text(
        json.dumps({"needed_effect_size": needed, "summary": summary, "sets": rows}, indent=2)
    )
    print(table)
    print(
        json.dumps(
            {
                "needed_effect_size": round(needed, 3),
                "summary": summary,
                "minutes": round((time.perf_counter() - start) / 60, 1),
            }
        )
    )


if __name__ == "__main__":
    main()
