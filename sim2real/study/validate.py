"""Blind check of the diagnosis on sealed sets: seal, diagnose, then open the answer and score.

``python -m sim2real.study.validate --sets N --run RUN [--data-dir D] [--out DIR]`` seals sets
``first_seed .. first_seed + N - 1`` (:mod:`sim2real.study.seal`), diagnoses each one without its
answer, and only then reads the answers and scores: stage correct, effect top-1 / top-3,
fitted strength inside its interval, share of the floor-corrected gap closed by the true
effect, open-set false attribution. Candidate sets do not depend on the real set, so they
are built once and reused from the cache by every sealed set. Writes ``validation.md``
(the table), ``validation.json`` and ``confusion.png`` into ``--out``. A plan can be
sharded over processes (``--skip``, ``--sets``), each with its own ``--out``; once their
``sets/``, ``answers/`` and ``reports/`` are merged into one folder, ``--finished-only``
writes the table of every finished set there without sealing or diagnosing anything.
``--rescore`` does the same but first decides every stored diagnosis again from its
measured closures and residual stage (:mod:`sim2real.study.rescore`), with today's rules or another
``--open-set-threshold``, and writes ``rescored.md``, ``rescored.json`` and
``confusion_rescored.png`` beside the blind table, which it leaves alone.
``--scored FILE`` carries a plan over machines: the rows of an earlier ``validation.json``
stand for the sets it scored that are not finished under ``--out``, so those are neither
sealed nor diagnosed again and the table covers the whole plan. ``--budget NAME`` diagnoses
at ``configs/budget/NAME.yaml`` (default ``quick``); the table names it. ``--stability N``
reruns N sets spread evenly over the plan at simulation seeds 1 and 2 and reports the
rankings' Kendall tau, overall and per kind of set.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from common.checks import check_int
from common.commands import report_user_errors
from common.errors import InputError
from common.files import atomic_write_bytes
from common.paths import check_output_dir

from ..candidates import candidate_library
from ..detectability import detectable_at
from ..diagnosis import OPEN_SET_MIN_CLOSURE
from ..pipeline import Budget, DiagnosisRequest, load_run, run_diagnosis
from ..report import read_report
from ..result import Diagnosis
from .multi import answer_effects, f1_ceiling, score_multi, truth_attribution
from .rescore import decided_again
from .seal import SEAL_KINDS, draw_answer, seal_set

__all__ = [
    "budget_names",
    "load_budget",
    "ranking_stability",
    "ranks",
    "score_set",
    "set_plan",
    "stability_positions",
    "stability_scores",
    "summarise",
]

TARGETS = {
    "stage": 0.90,
    "top1": 0.80,
    "top3": 0.95,
    "gap_closed": 0.50,
    "open_false_attribution": 0.10,
}
"""The issue's targets (false attribution: at most)."""


def _predicted_stages(result: Diagnosis) -> set[str]:
    ranking = result.ranking
    if ranking.explained:
        return {result.candidates[ranking.top]["stage"]}
    text = result.residual_stage
    return {s for s in ("scene", "physics", "appearance", "camera") if s in text}


def ranks(result: Diagnosis) -> bool:
    """Whether a diagnosis ranks its candidates at all.

    Not without a significant gap (no scored rungs), nor when every candidate scores 0 (S's
    own classifier gap at or below its floor on every scored rung, possible since the gap
    test pools S and S'): the order is then the library's, and a withheld effect early in
    the library would count as a top-3 hit by chance.
    """
    return bool(result.scored_rungs) and any(
        c["best_score"] != 0 for c in result.candidates.values()
    )


def score_set(result: Diagnosis, answer: dict, attribution: dict | None = None) -> dict:
    """One sealed set's scores (answer opened only here).

    ``attribution``: a ``multi`` set's :func:`~sim2real.study.multi.truth_attribution`.
    """
    truth = [e["name"] for e in answer["effects"] if e["library"]]
    stages = {e["stage"] for e in answer["effects"]}
    ranking = result.ranking
    order = ranking.ranking
    row = {
        "seed": answer["seed"],
        "kind": answer["kind"],
        "truth": [f"{e['name']}={e['strength']}" for e in answer["effects"]],
        "predicted": ranking.top if ranking.explained else "unexplained",
        "stage_correct": bool(_predicted_stages(result) & stages) if stages else None,
    }
    row["detected"] = bool(result.scored_rungs)
    row["budget"] = result.inputs.budget
    row["model"] = result.inputs.checkpoint_digest
    if answer["kind"] == "open":
        fabric = {e["name"] for e in answer_effects(answer) if e["library"]}  # density spread
        row["false_attribution"] = bool(ranking.explained) and not (
            set(ranking.explained_by or [ranking.top]) <= fabric
        )
        return row
    if answer["kind"] in ("multi", "twin"):
        return {**row, **score_multi(result, answer, attribution)}
    found = result.detectability
    if found is not None:  # reports written before the analysis existed have none
        row["truth_detectable"] = any(
            detectable_at(found[e["name"]], e["strength"])
            for e in answer["effects"]
            if e["library"] and e["name"] in found
        )
    ranked = ranks(result)
    row["top1"] = bool(ranking.explained and ranking.top in truth)
    row["top3"] = ranked and bool(set(order[:3]) & set(truth))
    closed = [result.candidates[n]["best_score"] for n in truth if n in result.candidates]
    row["gap_closed"] = max(closed) if closed else None
    if row["top1"]:
        effect = next(e for e in answer["effects"] if e["name"] == ranking.top)
        lo, hi = result.candidates[ranking.top]["strength_interval"]
        strength = effect["strength"]
        row["strength_in_interval"] = (
            None if lo is None or not isinstance(strength, int | float) else lo <= strength <= hi
        )
    return row


def ranking_stability(rankings: list[list[str]], *, weighted: bool = False) -> float:
    """Mean pairwise Kendall tau between candidate rankings (same candidates, other draws).

    ``weighted``: Vigna's (2015) top-weighted tau (``scipy.stats.weightedtau``, hyperbolic
    weights on the rank), where swaps near the top count more than swaps among candidates
    that close nothing and are ordered by noise.
    """
    from scipy.stats import kendalltau, weightedtau

    names = sorted(rankings[0])
    places = [np.array([r.index(n) for n in names]) for r in rankings]
    if weighted:  # weightedtau ranks by decreasing value: give the top the largest one
        taus = [weightedtau(-a, -b)[0] for i, a in enumerate(places) for b in places[i + 1 :]]
    else:
        taus = [kendalltau(a, b)[0] for i, a in enumerate(places) for b in places[i + 1 :]]
    return float(np.mean(taus))


def stability_positions(plan_size: int, count: int) -> set[int]:
    """Plan positions of the ``count`` sets rerun at simulation seeds 1 and 2.

    Spread evenly over the plan (``round(i * plan_size / count)``), so that the ranking's
    stability is measured on every kind of set in proportion to the plan. The first three
    positions, used before, are open sets in an ``open:4,...`` plan: there every candidate
    closes about nothing and the order of that tied cluster is the simulation draw's.
    """
    count = min(max(count, 0), plan_size)
    return {round(i * plan_size / count) for i in range(count)} if count else set()


def stability_scores(results: list[Diagnosis]) -> dict:
    """Taus of one sealed set's diagnoses under several simulation seeds.

    ``kendall_tau`` and ``weighted_tau`` compare the rankings of the diagnoses that rank
    (:func:`ranks`). One that found no gap ranks nothing: every candidate scores 0 and its
    order is the library's, so there is no ranking to compare, and it is counted in
    ``no_gap_diagnoses`` instead. ``kendall_tau_all`` keeps it, in that order.
    """
    every = [r.ranking.ranking for r in results]
    ranked = [r.ranking.ranking for r in results if ranks(r)]
    out = {
        "kendall_tau_all": ranking_stability(every),
        "no_gap_diagnoses": len(every) - len(ranked),
    }
    if len(ranked) > 1:
        out["kendall_tau"] = ranking_stability(ranked)
        out["weighted_tau"] = ranking_stability(ranked, weighted=True)
    return out


def summarise(rows: list[dict]) -> dict:
    """Rates over the scored sets (``None`` where no set applies)."""

    def rate(key, kinds=None):
        return _mean(r.get(key) for r in rows if kinds is None or r["kind"] in kinds)

    out = {}
    for key in ("stage_correct", "top1", "top3", "strength_in_interval"):
        out[key], out[f"{key}_n"] = rate(key)
    closed = [r["gap_closed"] for r in rows if r.get("gap_closed") is not None]
    out["gap_closed_median"] = float(np.median(closed)) if closed else None
    out["budgets"] = sorted({r["budget"] for r in rows if r.get("budget")})
    out["open_false_attribution"], out["open_n"] = rate("false_attribution", ("open",))
    out["twin_false_attribution"], out["twin_n"] = rate("false_attribution", ("twin",))
    out["twin_named_fabric_spread"], _ = rate("named_fabric_spread", ("twin",))
    for key in ("factor_f1", "factor_f1_matter", "factor_precision", "factor_recall"):
        out[key], out[f"{key}_n"] = rate(key, ("multi",))
    out["factor_f1_ceiling"], _ = _mean(f1_ceiling(r) for r in rows if r["kind"] == "multi")
    checked = sum(r.get("strengths_checked", 0) for r in rows if r["kind"] == "multi")
    inside = sum(r.get("strengths_in_interval", 0) for r in rows if r["kind"] == "multi")
    out["factor_strength_in_interval"] = inside / checked if checked else None
    out["factor_strength_in_interval_n"] = checked
    errors = [
        r["stage_share_error_pts"] for r in rows if r.get("stage_share_error_pts") is not None
    ]
    out["stage_share_error_pts_median"] = float(np.median(errors)) if errors else None
    out["stage_share_error_pts_max"] = float(np.max(errors)) if errors else None
    for key in ("kendall_tau", "weighted_tau", "kendall_tau_all"):
        taus = [r[key] for r in rows if key in r]
        out[key] = float(np.mean(taus)) if taus else None
        out[f"{key}_n"] = len(taus)
    kinds = sorted({r["kind"] for r in rows if "kendall_tau" in r}, key=str)
    out["kendall_tau_by_kind"] = {
        str(kind): _mean(r["kendall_tau"] for r in rows if "kendall_tau" in r and r["kind"] == kind)
        for kind in kinds
    }
    out["detected"], out["detected_n"] = rate("detected", ("single", "pair"))
    found = [r for r in rows if r.get("detected") and "top1" in r]  # library effects only
    out["top1_detected"], out["top1_detected_n"] = (
        (float(np.mean([r["top1"] for r in found])), len(found)) if found else (None, 0)
    )
    out.update(_by_detectability(rows))
    return out


def _by_detectability(rows: list[dict]) -> dict:
    """Rates split by whether the diagnosis's own sim-vs-sim test picks up the withheld effect.

    ``truth_detectable`` (:func:`score_set`) separates a miss of the test's power (the effect
    at its sealed strength shows no gap even against a clean nominal draw) from a miss of the
    identification. ``gap_found_when_undetectable`` and ``gap_missed_when_detectable`` check
    that analysis against what the diagnosis then found on the sealed set.
    """
    known = [r for r in rows if "truth_detectable" in r]
    seen = [r for r in known if r["truth_detectable"]]
    blind = [r for r in known if not r["truth_detectable"]]
    out = {}
    out["truth_detectable"], out["truth_detectable_n"] = _mean(r["truth_detectable"] for r in known)
    for key in ("stage_correct", "top1", "top3"):
        out[f"{key}_detectable"], out[f"{key}_detectable_n"] = _mean(r.get(key) for r in seen)
    out["gap_found_when_undetectable"], out["gap_found_when_undetectable_n"] = _mean(
        r["detected"] for r in blind
    )
    out["gap_missed_when_detectable"], out["gap_missed_when_detectable_n"] = _mean(
        not r["detected"] for r in seen
    )
    return out


def _mean(values) -> tuple[float | None, int]:
    """(mean, count) of the values that are not None; (None, 0) when there are none."""
    values = [v for v in values if v is not None]
    return (float(np.mean(values)) if values else None), len(values)


def _confusion_png(path: Path, rows: list[dict]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [r for r in rows if r["truth"]]  # effect-free twins have no withheld effect
    if not rows:
        return
    truths = sorted({r["truth"][0].split("=")[0] for r in rows})
    preds = sorted({r["predicted"] for r in rows} | set(truths))
    matrix = np.zeros((len(truths), len(preds)))
    for r in rows:
        matrix[truths.index(r["truth"][0].split("=")[0]), preds.index(r["predicted"])] += 1
    fig, ax = plt.subplots(figsize=(0.4 * len(preds) + 3, 0.35 * len(truths) + 2.5), dpi=100)
    ax.imshow(matrix, cmap="Blues")
    ax.set_xticks(range(len(preds)), preds, rotation=90, fontsize=7)
    ax.set_yticks(range(len(truths)), truths, fontsize=7)
    ax.set_xlabel("diagnosed (top-1 or unexplained)")
    ax.set_ylabel("withheld effect (first of the set)")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def _table(summary: dict, rows: list[dict]) -> str:
    def pct(v):
        return "–" if v is None else f"{100 * v:.0f} %"

    budgets = summary.get("budgets")
    lines = [
        *([f"Diagnosed at budget {', '.join(budgets)} (configs/budget/).", ""] if budgets else []),
        "| measure | target | measured | sets |",
        "|---|---|---|---|",
        f"| stage correct | >= 90 % | {pct(summary['stage_correct'])} | "
        f"{summary['stage_correct_n']} |",
        f"| effect top-1 | >= 80 % | {pct(summary['top1'])} | {summary['top1_n']} |",
        f"| effect top-3 | >= 95 % | {pct(summary['top3'])} | {summary['top3_n']} |",
        f"| strength in interval | – | {pct(summary['strength_in_interval'])} | "
        f"{summary['strength_in_interval_n']} |",
        f"| gap closed by the true effect (median) | >= 50 % | {pct(summary['gap_closed_median'])} "
        f"| {summary['top1_n']} |",
        f"| open-set false attribution | <= 10 % | {pct(summary['open_false_attribution'])} | "
        f"{summary['open_n']} |",
        "| ranking stability (Kendall tau, 3 simulation seeds) | >= 0.8 | "
        + ("–" if summary["kendall_tau"] is None else f"{summary['kendall_tau']:.2f}")
        + f" | {summary['kendall_tau_n']} |",
        *(
            f"| ranking stability on {kind} sets (Kendall tau) | – | {tau:.2f} | {n} |"
            for kind, (tau, n) in summary.get("kendall_tau_by_kind", {}).items()
        ),
        "| ranking stability (top-weighted tau, same draws) | – | "
        + ("–" if summary["weighted_tau"] is None else f"{summary['weighted_tau']:.2f}")
        + f" | {summary['weighted_tau_n']} |",
        "| ranking stability, no-gap diagnoses kept in library order (Kendall tau) | – | "
        + ("–" if summary["kendall_tau_all"] is None else f"{summary['kendall_tau_all']:.2f}")
        + f" | {summary['kendall_tau_all_n']} |",
        f"| library effect left a significant gap | – | {pct(summary['detected'])} | "
        f"{summary['detected_n']} |",
        f"| effect top-1 where a gap was found | – | {pct(summary['top1_detected'])} | "
        f"{summary['top1_detected_n']} |",
        *_detectability_rows(summary, pct),
        *_multi_rows(summary, pct),
        "",
        "| seed | kind | withheld | diagnosed | stage | top-3 | gap closed |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        closed = r.get("gap_closed")
        diagnosed = r["predicted"]
        if "named" in r:  # a multi-effect set or a twin: the joint fit's factors
            diagnosed = ", ".join(r["named"]) or "nothing named"
        stage = r["stage_correct"]
        lines.append(
            f"| {r['seed']} | {r['kind']} | {', '.join(r['truth'])} | {diagnosed} | "
            f"{'–' if stage is None else 'yes' if stage else 'no'} | "
            f"{'–' if 'top3' not in r else ('yes' if r['top3'] else 'no')} | "
            f"{'–' if closed is None else f'{100 * closed:.0f} %'} |"
        )
    return "\n".join(lines) + "\n"


def _multi_rows(summary: dict, pct) -> list[str]:
    """The multi-effect and twin measures, where such sets were scored."""
    if not summary.get("factor_f1_n") and not summary.get("twin_n"):
        return []

    def number(v, unit=""):
        return "–" if v is None else f"{v:.2f}{unit}"

    return [
        f"| factor F1 (multi-effect sets) | >= 0.8 | {number(summary['factor_f1'])} | "
        f"{summary['factor_f1_n']} |",
        f"| factor F1 over the effects that matter | – | "
        f"{number(summary['factor_f1_matter'])} | {summary['factor_f1_matter_n']} |",
        f"| stage share error, median (points) | – | "
        f"{number(summary['stage_share_error_pts_median'])} | {summary['factor_f1_matter_n']} |",
        f"| stage share error, worst (points) | <= 15 | "
        f"{number(summary['stage_share_error_pts_max'])} | {summary['factor_f1_matter_n']} |",
        f"| named true factors: strength inside its interval | – | "
        f"{pct(summary.get('factor_strength_in_interval'))} | "
        f"{summary.get('factor_strength_in_interval_n', 0)} |",
        f"| effect-free twins: false attribution | <= 5 % | "
        f"{pct(summary['twin_false_attribution'])} | {summary['twin_n']} |",
        f"| effect-free twins naming their fabrics' density spread | – | "
        f"{pct(summary.get('twin_named_fabric_spread'))} | {summary['twin_n']} |",
    ]


def _rescored_note(threshold: float, rows: list[dict]) -> str:
    """The header of a rescored table: what was decided again, and what could not be."""
    lines = [
        f"Decided again (ranking, cause and residual stage) from the stored closures at "
        f"open-set threshold {threshold:g} (`--rescore`); the diagnoses were not rerun.",
        "",
    ]
    missing = [str(r["seed"]) for r in rows if r.get("replayed") is False]
    if missing:
        lines += [
            f"Sets {', '.join(missing)} now call for a stacked fit that their stored run did "
            "not make; they count as unexplained here. Rerun them to know.",
            "",
        ]
    return "\n".join(lines) + "\n"


def _detectability_rows(summary: dict, pct) -> list[str]:
    if not summary.get("truth_detectable_n"):
        return []
    rows = [
        ("withheld effect picked up by the sim-vs-sim test", "truth_detectable"),
        ("stage correct, where picked up", "stage_correct_detectable"),
        ("effect top-1, where picked up", "top1_detectable"),
        ("effect top-3, where picked up", "top3_detectable"),
        ("gap found although not picked up", "gap_found_when_undetectable"),
        ("no gap found although picked up", "gap_missed_when_detectable"),
    ]
    return [f"| {text} | – | {pct(summary[key])} | {summary[f'{key}_n']} |" for text, key in rows]


def set_plan(kinds: str | None, names: list[str], first_seed: int) -> list[tuple] | None:
    """(seed, kind, fixed effect) per set of a plan like ``single:22,pair:6,open:4``.

    Singles take the library's effects in turn (``names`` order), so a plan with at least as
    many singles as effects covers every switch; pairs and open-set sets draw theirs from the
    seed. Seeds run from ``first_seed`` in plan order. ``None`` without a plan.
    """
    if not kinds:
        return None
    plan, seed = [], first_seed
    for part in kinds.split(","):
        kind, _, count = part.partition(":")
        if kind not in SEAL_KINDS or not count.isdigit():
            raise ValueError(f"kinds: {part!r} must be <kind>:<count> with kind in {SEAL_KINDS}")
        for i in range(int(count)):
            effect = names[i % len(names)] if kind == "single" else None
            plan.append((seed, kind, effect))
            seed += 1
    return plan


def scored_rows(paths: list[str], plan: list[tuple]) -> dict[int, dict]:
    """Rows of earlier ``validation.json`` files by seed, checked against the plan's kinds.

    A row whose seed the plan holds with another kind belongs to another plan; mixing them
    would score sets that were never drawn, so it is refused.
    """
    kinds = {seed: kind for seed, kind, _ in plan}
    rows = {}
    for path in paths:
        try:
            sets = json.loads(Path(path).read_text())["sets"]
        except (OSError, ValueError, KeyError, TypeError) as err:
            raise ValueError(f"--scored: {path} is not a validation.json ({err})") from None
        for row in sets:
            seed = row.get("seed")
            if seed not in kinds:
                continue
            if kinds[seed] is not None and row.get("kind") != kinds[seed]:
                raise ValueError(
                    f"--scored: {path} scored set {seed} as kind {row.get('kind')!r}, the "
                    f"plan has {kinds[seed]!r}; pass the same --kinds and --first-seed"
                )
            rows[seed] = row
    return rows


BUDGETS = Path(__file__).resolve().parents[2] / "configs" / "budget"
"""The budget configs that ``python -m sim2real.diagnose budget=NAME`` also reads."""


def budget_names() -> list[str]:
    """Names of the budget configs (``configs/budget/*.yaml``)."""
    return sorted(p.stem for p in BUDGETS.glob("*.yaml"))


def load_budget(name: str, overrides: Sequence[str] = ()) -> Budget:
    """The :class:`~sim2real.pipeline.Budget` of ``configs/budget/NAME.yaml``.

    ``overrides`` are ``key=value`` settings on top (``refine=visual``, YAML values), for
    checking a rule change on development sets without editing the config; the budget's
    name then lists them, so every table says what it ran at.
    """
    from hydra.utils import instantiate
    from omegaconf import OmegaConf

    if name not in budget_names():
        raise ValueError(f"--budget must be one of {', '.join(budget_names())}, got {name!r}")
    budget = instantiate(OmegaConf.load(BUDGETS / f"{name}.yaml"))
    if not overrides:
        return budget
    settings = sorted(f.name for f in dataclasses.fields(Budget) if f.name != "name")
    changes = {"name": f"{name}+{','.join(overrides)}"}
    for item in overrides:
        key, sep, value = item.partition("=")
        if not sep or key not in settings or not value:
            raise ValueError(
                f"--budget-set must be KEY=VALUE with KEY one of {', '.join(settings)}, "
                f"got {item!r}"
            )
        changes[key] = OmegaConf.to_container(OmegaConf.from_dotlist([item]))[key]
    return dataclasses.replace(budget, **changes)


def _minutes(result: Diagnosis) -> float | None:
    """The diagnosis's own wall time, as its report recorded it (not the time to reload it)."""
    total = result.timing.get("total")
    return None if total is None else total / 60


def _diagnosed(out_dir: Path, request: DiagnosisRequest) -> Diagnosis:
    """The diagnosis of one sealed set: its finished report, else a fresh run.

    Reports are written last and whole, so a killed validation resumes set by set.
    """
    if (out_dir / "report.json").is_file():
        return read_report(out_dir, "reports")
    return run_diagnosis(request, out_dir)


@report_user_errors
def main(argv: list[str] | None = None) -> None:
    """Command line (see the module docstring)."""
    parser = argparse.ArgumentParser(
        prog="python -m sim2real.study.validate", description=__doc__.split("\n")[0]
    )
    parser.add_argument("--sets", type=int, required=True)
    parser.add_argument("--run", required=True, help="training run folder or checkpoint")
    parser.add_argument("--data-dir", help="the run's training dataset folder")
    parser.add_argument("--out", default="outputs/sim2real/validation")
    parser.add_argument("--first-seed", type=int, default=1000)
    parser.add_argument(
        "--kinds",
        help="a fixed plan, e.g. single:22,pair:6,open:4 (singles cycle through the library "
        "in name order, so 26 cover every effect of the default wind scene); default: each "
        "set's kind drawn from its seed. With a plan, --sets counts its sets: 0 means all of them",
    )
    parser.add_argument(
        "--skip",
        type=int,
        default=0,
        help="leave out the plan's first SKIP sets (shard a plan over processes)",
    )
    parser.add_argument("--videos", type=int, default=90)
    parser.add_argument("--candidates", default="all", help="comma-separated names or stages")
    parser.add_argument("--mesh-cache", default="data/mesh_cache")
    parser.add_argument(
        "--cache-dir",
        help="feature cache (default: <out>/cache); share it with "
        "diagnoses of the same run to reuse their candidate sets",
    )
    parser.add_argument("--n-jobs", type=int, default=2)
    parser.add_argument(
        "--budget",
        default="quick",
        help=f"budget of every diagnosis: one of {', '.join(budget_names())} (configs/budget/)",
    )
    parser.add_argument(
        "--budget-set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="a budget setting on top of --budget (repeatable), e.g. refine=visual: a rule "
        "change checked on development sets; the table's budget name lists it",
    )
    parser.add_argument(
        "--finished-only",
        action="store_true",
        help="score only the sets whose diagnosis is finished under --out, sealing and "
        "diagnosing nothing: the table of a plan sharded over processes (--skip), once "
        "their folders are merged into one",
    )
    parser.add_argument(
        "--rescore",
        action="store_true",
        help="like --finished-only, but decide each stored diagnosis again from its stored "
        "closures first (today's rules, or --open-set-threshold); writes rescored.*",
    )
    parser.add_argument(
        "--scored",
        action="append",
        default=[],
        help="validation.json of an earlier run of the same plan (repeatable): its rows stand "
        "for the sets that are not finished under --out (a plan carried over machines)",
    )
    parser.add_argument(
        "--open-set-threshold",
        type=float,
        default=OPEN_SET_MIN_CLOSURE,
        help=f"with --rescore: the least closure that names a cause "
        f"(default {OPEN_SET_MIN_CLOSURE}, today's)",
    )
    parser.add_argument(
        "--stability",
        type=int,
        default=0,
        help="on N sets spread evenly over the whole plan (positions round(i * plan / N), "
        "whatever --skip and --sets run) also diagnose with sim_seed 1 and 2 (Kendall tau)",
    )
    args = parser.parse_args(argv)
    if not 0 < args.open_set_threshold <= 1:
        raise InputError(f"--open-set-threshold must be in (0, 1], got {args.open_set_threshold}")
    if args.open_set_threshold != OPEN_SET_MIN_CLOSURE and not args.rescore:
        raise InputError(
            "--open-set-threshold applies only with --rescore (a blind run uses today's rules)"
        )
    if args.sets < (0 if args.kinds else 1):  # with a plan, 0 = all its sets
        raise InputError(
            f"--sets must be an integer >= 1 (0 means every set of a --kinds plan), got {args.sets}"
        )
    for name, low in (
        ("first_seed", 0),
        ("skip", 0),
        ("videos", 4),
        ("n_jobs", 1),
        ("stability", 0),
    ):
        check_int(getattr(args, name), "--" + name.replace("_", "-"), low)
    args.finished_only = args.finished_only or args.rescore
    out = check_output_dir(args.out, "--out")
    try:
        budget = load_budget(args.budget, args.budget_set)
        base, _ = load_run(args.run, args.data_dir)
    except ValueError as err:
        raise InputError(str(err)) from None
    if args.scored and args.rescore:
        raise InputError(
            "--scored rows cannot be decided again (their reports are elsewhere); use it "
            "without --rescore"
        )
    library = candidate_library(base)
    try:
        plan = set_plan(args.kinds, sorted(library), args.first_seed)
        seeds = range(args.first_seed, args.first_seed + args.sets)
        whole = plan if plan is not None else [(seed, None, None) for seed in seeds]
        rerun = {whole[i][0] for i in stability_positions(len(whole), args.stability)}
        plan = whole if plan is None else whole[args.skip :][: args.sets or None]
        earlier = scored_rows(args.scored, plan)
    except ValueError as err:
        raise InputError(str(err)) from None
    rows = []
    for seed, kind, effect in plan:
        real = out / "sets" / f"set{seed}"
        answer_path = out / "answers" / f"set{seed}.json"
        finished = (out / "reports" / real.name / "report.json").is_file()
        if seed in earlier and not finished:
            rows.append(earlier[seed])
            print(json.dumps(earlier[seed]), flush=True)
            continue
        if args.finished_only and not (finished and answer_path.is_file()):
            continue
        answer_path.parent.mkdir(parents=True, exist_ok=True)
        sealed = (real / "labels.csv").is_file() and answer_path.is_file()
        if not sealed and not args.finished_only:
            answer = None if kind is None else draw_answer(seed, library, kind, effect)
            seal_set(
                real,
                base=base,
                seed=seed,
                videos=args.videos,
                answer_path=answer_path,
                overwrite=True,
                answer=answer,
            )
        request = DiagnosisRequest(
            real_dir=real,
            run=args.run,
            data_dir=args.data_dir,
            cache_dir=Path(args.cache_dir) if args.cache_dir else out / "cache",
            mesh_cache=args.mesh_cache,
            budget=budget,
            candidates=args.candidates.split(","),
            n_jobs=args.n_jobs,
            progress=False,
        )
        result = _diagnosed(out / "reports" / real.name, request)
        reruns = [result]
        if seed in rerun:
            for sim_seed in (1, 2):
                folder = out / "reports" / f"{real.name}-sim{sim_seed}"
                if args.finished_only and not (folder / "report.json").is_file():
                    continue
                reruns.append(_diagnosed(folder, dataclasses.replace(request, sim_seed=sim_seed)))
        if args.rescore:
            result = decided_again(result, min_closure=args.open_set_threshold)
        answer = json.loads(answer_path.read_text())  # opened only after the diagnosis
        truth = (
            truth_attribution(result, answer, n_jobs=args.n_jobs)
            if answer["kind"] == "multi"
            else None
        )
        row = score_set(result, answer, truth)
        if args.rescore:
            row["replayed"] = result.ranking.replayed
        if len(reruns) > 1:
            row.update(stability_scores(reruns))
        row["minutes"] = _minutes(result)
        rows.append(row)
        print(json.dumps(row), flush=True)
    if not rows:
        raise InputError(f"no finished sealed set of the plan under {out}/reports")
    summary = summarise(rows)
    out.mkdir(parents=True, exist_ok=True)
    stem, table = "validation", _table(summary, rows)
    if args.rescore:
        stem, table = "rescored", _rescored_note(args.open_set_threshold, rows) + table
        summary["open_set_threshold"] = args.open_set_threshold
    atomic_write_bytes(
        out / f"{stem}.json", json.dumps({"summary": summary, "sets": rows}, indent=2).encode()
    )
    atomic_write_bytes(out / f"{stem}.md", table.encode())
    _confusion_png(out / ("confusion_rescored.png" if args.rescore else "confusion.png"), rows)
    print(table)
    print(
        json.dumps(
            {k: v for k, v in summary.items() if not isinstance(v, float) or math.isfinite(v)}
        )
    )


if __name__ == "__main__":
    main()
