"""The diagnosis report: verdict, rung table, candidate ranking, probes.

Written as ``report.json``, ``report.md``, ``report.html`` and PNG figures, each atomically.
"""

from __future__ import annotations

import io
import json
import math
from pathlib import Path

import numpy as np

from common.errors import InputError
from common.files import atomic_write_bytes
from models.report import markdown_table, write_json, write_text

from .diagnosis.joint import JointFit
from .report_html import render_html
from .result import Diagnosis

__all__ = [
    "answer",
    "contact_sheet",
    "document",
    "json_safe",
    "read_report",
    "verdict",
    "write_report",
]


def read_report(path: str | Path, field: str) -> Diagnosis:
    """A diagnosis's ``report.json`` read back, refused in one line unless it is one.

    Args:
        path: The file, or the diagnosis folder that holds it.
        field: The command-line field that named it, for the message.
    """
    path = Path(path)
    if path.is_dir():
        path = path / "report.json"
    if not path.is_file():
        raise InputError(f"{field}: {path} does not exist (give a diagnosis's report.json)")
    try:
        return Diagnosis.from_json(json.loads(path.read_text(encoding="utf-8")))
    except (UnicodeDecodeError, json.JSONDecodeError) as error:
        raise InputError(f"{field}: {path} is not JSON ({error})") from None
    except (ValueError, TypeError) as error:
        raise InputError(f"{field}: {path} is not a diagnosis's report.json ({error})") from None


STAGE_COLOURS = {
    "scene": "#8c564b",
    "physics": "#1f77b4",
    "appearance": "#2ca02c",
    "camera": "#ff7f0e",
    "null": "#7f7f7f",
}


def json_safe(value):
    """JSON-safe copy: NaN/inf become None, numpy scalars plain numbers, tuples lists."""
    if isinstance(value, dict):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_safe(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _fmt(value, digits: int = 3) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    if isinstance(value, float):
        return f"{value:.{digits}g}" if abs(value) < 1e-2 and value != 0 else f"{value:.{digits}f}"
    return str(value)


def _ci(pair) -> str:
    return f"[{_fmt(pair[0])}, {_fmt(pair[1])}]"


def _change(name: str, strength) -> str:
    return f"turn on {name}" if strength is None else f"set {name} to {_fmt(strength)}"


def answer(result: Diagnosis) -> str:
    """The answer in a few sentences: what differs and by how much, what to change, the loop.

    From the joint calibration when it ran, else from the named effect; the evidence follows
    in :func:`verdict` and the tables.
    """
    if not result.location.significant:
        return (
            "The simulated and real clips cannot be told apart beyond their noise floor "
            "with this budget: there is no gap to explain."
        )
    joint, ranking = result.joint, result.ranking
    tied = joint.tied if joint is not None else []
    parts = []
    if joint is not None and joint.named:
        order = sorted(joint.shapley.items(), key=lambda kv: -kv[1])
        shares = ", ".join(f"{100 * v:.0f} % {joint.factors[n]} ({n})" for n, v in order)
        rest = f"{100 * joint.unexplained:.0f} % is unexplained"
        if joint.unexplained >= 0.2:
            rest += f" (stage {result.residual_stage})"
        parts.append(f"The gap is {shares}; {rest}.")
        changes = "; ".join(_change(n, joint.strengths[n]) for n, _ in order)
        parts.append(f"To close it, change the simulator: {changes}.")
    elif ranking.explained:
        top = result.candidates[ranking.top]
        parts.append(
            f"The gap is explained by {ranking.top} (stage {top['stage']}), which "
            f"closes {100 * top['best_score']:.0f} % of it."
        )
        parts.append(f"To close it, {_change(ranking.top, top['best_strength'])}.")
    elif joint is not None and joint.shapley and not joint.kernel_gap:
        parts.append(
            f"Every factor calibrated together closes {100 * joint.closure:.0f} % of the gap "
            "the classifier sees, but the kernel distance lies at its floor on every scored "
            f"rung: the gap is too weak to attribute, and {', '.join(joint.shapley)} "
            f"{'is' if len(joint.shapley) == 1 else 'are'} not named; unexplained residual "
            f"at stage {result.residual_stage}."
        )
    elif joint is not None and joint.shapley:
        parts.append(
            f"Every factor calibrated together closes {100 * joint.closure:.0f} % of the gap "
            f"(a fresh nominal draw {100 * joint.floor:.0f} %; a cause is named from "
            f"{100 * joint.needed:.0f} %): {', '.join(joint.shapley)} close part of it, and "
            f"none is named; unexplained residual at stage {result.residual_stage}."
        )
    elif not tied:
        parts.append(
            "No candidate, alone or with others, explains the gap: unexplained "
            f"residual at stage {result.residual_stage}."
        )
    if tied:
        parts.append(
            f"{' and '.join(tied)} each close part of the gap, and no one of them adds "
            "to another: the data cannot tell which is at work, so none of them is named "
            "(footage that varies the conditions, or a finer budget, would tell them apart)."
        )
    shrink = result.shrink
    if shrink is None:
        parts.append(
            "How far it shrinks after retraining is measured by `python -m "
            "sim2real.shrink report=<this folder>`."
        )
    else:
        before, after = shrink["correlations"]["before"], shrink["correlations"]["after"]
        parts.append(
            "Retrained with "
            + ", ".join(e["name"] for e in shrink["effects"])
            + ", the model's Spearman ρ with measured stiffness went "
            f"{_fmt(before['stiffness']['spearman'], 2)} -> "
            f"{_fmt(after['stiffness']['spearman'], 2)} and with density "
            f"{_fmt(before['density']['spearman'], 2)} -> {_fmt(after['density']['spearman'], 2)}"
            f"{_control_clause(shrink)}."
        )
    return " ".join(parts)


def verdict(result: Diagnosis) -> str:
    """One paragraph answering the three questions from the result JSON."""
    loc = result.location
    ranking = result.ranking
    gaps = result.detection_rungs or result.rungs  # what the gap test compared
    if not loc.significant:
        return " ".join(
            [
                "No gap beyond the within-domain noise floor at the chosen level (all rungs' tests "
                f"combined: p {_fmt(loc.gap_p, 2)}, alpha {loc.alpha:g}): the simulated "
                "and real clips are not distinguishable with this budget.",
                *_detectability_sentences(result),
            ]
        )
    rung_text = ", ".join(
        f"{n} (corrected AUC {_fmt(gaps[n]['corrected_auc'], 2)})" for n in loc.significant
    )
    parts = [
        f"There is a gap (all rungs' tests combined: p {_fmt(loc.gap_p, 2)}); "
        f"it shows on {rung_text}."
    ]
    if loc.first_significant_layer:
        parts.append(
            f"In the network it first appears at {loc.first_significant_layer}; the largest "
            f"rise is at {loc.jump_layer}."
        )
    parts += _swap_sentences(result)
    if ranking.explained:
        top = result.candidates[ranking.top]
        strength = top["best_strength"]
        parts.append(
            f"The candidate that closes most of it is {ranking.top} (stage {top['stage']}"
            + ("" if strength is None else f", fitted strength {_fmt(strength)}")
            + f"), closing {100 * top['best_score']:.0f} % of the floor-corrected gap on the "
            f"scored rungs (threshold {100 * ranking.threshold:.0f} %, a fresh nominal draw "
            f"closes {100 * ranking.null_score:.0f} %)."
        )
        at = ranking.kernel_strength
        if at is not None and at != strength and ranking.kernel_closure is not None:
            parts.append(
                f"At strength {_fmt(at)}, which the classifier cannot tell from the fitted one, "
                f"it also closes {100 * ranking.kernel_closure:.0f} % of the kernel distance."
            )
        if ranking.explained_by:
            parts.append(
                "Alone it closes less than the threshold; together with "
                + ", ".join(n for n in ranking.explained_by if n != ranking.top)
                + f" it closes {100 * ranking.explained_by_score:.0f} %."
            )
        if ranking.confusable_with_top:
            parts.append(
                "It cannot be told apart from " + ", ".join(ranking.confusable_with_top) + "."
            )
    elif ranking.neutral_in_interval:
        top = result.candidates[ranking.top]
        held = (
            f"its strength interval {_ci(tuple(top['strength_interval']))} holds its "
            f"neutral value {_fmt(top['neutral'])}"
        )
        if top["best_score"] >= ranking.threshold:
            parts.append(
                f"{ranking.top} closes {100 * top['best_score']:.0f} % of the classifier "
                f"gap, but {held}: the data cannot tell it from its absence, so it is not named."
            )
        else:  # the low closure is the reason; the neutral value also bars its coalitions
            parts.append(
                f"{ranking.top} leads with {100 * top['best_score']:.0f} % (threshold "
                f"{100 * ranking.threshold:.0f} %) and {held}, so neither it nor a "
                "coalition it leads is named."
            )
        parts.append(f"Unexplained residual at stage {result.residual_stage}.")
    elif ranking.look_alike and not ranking.kernel_rungs:
        top = result.candidates[ranking.top]
        parts.append(
            f"{ranking.top} closes {100 * top['best_score']:.0f} % of the classifier gap, "
            "but on no scored rung does the kernel distance lie above its floor: the gap is "
            "too weak to attribute, so no cause is named. "
            f"Unexplained residual at stage {result.residual_stage}."
        )
    elif ranking.look_alike:
        top = result.candidates[ranking.top]
        parts.append(
            f"{ranking.top} closes {100 * top['best_score']:.0f} % of the classifier gap "
            f"but only {100 * ranking.kernel_closure:.0f} % of the kernel distance on "
            f"{', '.join(ranking.kernel_rungs)} (both must reach "
            f"{100 * ranking.kernel_threshold:.0f} %): a look-alike, not the cause. "
            f"Unexplained residual at stage {result.residual_stage}."
        )
    else:
        parts.append(
            f"No candidate closes at least {100 * ranking.threshold:.0f} % of it: "
            f"unexplained residual at stage {result.residual_stage}."
        )
    parts += _residual_sentences(result.residual)
    if result.joint is not None:
        parts.append(f"Every factor calibrated together: {result.joint.sentence()}.")
    if not ranking.explained:
        parts += _detectability_sentences(result)
    shrink = result.shrink
    if shrink is None:
        parts.append("How far it shrinks after retraining was not measured in this run.")
    else:
        before = shrink["correlations"]["before"]
        after = shrink["correlations"]["after"]
        parts.append(
            "After retraining with "
            + ", ".join(e["name"] for e in shrink["effects"])
            + ": Spearman ρ with measured stiffness "
            f"{_fmt(before['stiffness']['spearman'], 2)} -> "
            f"{_fmt(after['stiffness']['spearman'], 2)}, with density "
            f"{_fmt(before['density']['spearman'], 2)} -> "
            f"{_fmt(after['density']['spearman'], 2)}{_control_clause(shrink)}."
        )
    return " ".join(parts)


def _residual_sentences(residual: dict | None) -> list[str]:
    """What is left between R and the top candidate's best set (its own gap tests)."""
    if not residual:
        return []
    added = f"With {residual['candidate']} added" + (
        "" if residual["strength"] is None else f" at {_fmt(residual['strength'])}"
    )
    if residual["significant"]:
        return [
            f"{added}, a significant gap remains (p {_fmt(residual['gap_p'], 2)}) on "
            + ", ".join(residual["significant"])
            + "."
        ]
    return [f"{added}, no significant gap remains (p {_fmt(residual['gap_p'], 2)})."]


def _detectability_sentences(result: Diagnosis) -> list[str]:
    """The verdict's words on what the test could not have seen (empty without the analysis)."""
    found = result.detectability
    if not found:
        return []
    sims = result.inputs.sim_groups
    blind = [n for n, e in found.items() if e["verdict"] == "undetected"]
    inert = [n for n, e in found.items() if e["verdict"] == "inert"]
    parts = []
    if blind:
        parts.append(
            f"Tested against a fresh nominal draw, {sims} simulations against {sims} "
            f"(the gap test itself pools {2 * sims} against the real videos and sees "
            "more), "
            "these candidates show no gap at any strength tried; they are the hardest "
            "to rule out: " + ", ".join(blind) + "."
        )
    if inert:
        parts.append(
            "Inert in this scene (they change no feature at any strength tried): "
            + ", ".join(inert)
            + "."
        )
    return parts


def _detectability_lines(found: dict | None) -> list[str]:
    """Section 2's table of which candidate strengths the gap test picks up, sim against sim."""
    if not found:
        return []

    def listed(entry, keep):
        cells = [
            f"{_fmt(v)} (p {_fmt(p, 2)})"
            for v, p, d, i in zip(
                entry["strengths"], entry["p"], entry["detected"], entry["inert"], strict=True
            )
            if keep(d, i)
        ]
        return ", ".join(cells) or "–"

    rows = [
        [
            name,
            e["stage"],
            e["verdict"],
            listed(e, lambda d, i: d),
            listed(e, lambda d, i: not d and not i),
            listed(e, lambda d, i: i),
        ]
        for name, e in found.items()
    ]
    return [
        "### What the gap test can see",
        "",
        "Each candidate set S_e tested against S' (the nominal scene, other simulation seeds, "
        "S's size) with the gap test above, as if S_e were the real set. The gap test itself "
        "compares S and S' pooled with the real videos, more rows on both sides, so it sees "
        "more than this: a strength not picked up here is hard to see, not invisible. Inert: "
        "S_e's features equal S's bit for bit, which no footage can reveal.",
        "",
        markdown_table(
            ["candidate", "stage", "verdict", "picked up", "not picked up", "inert"], rows
        ),
        "",
    ]


def _swap_sentences(result: Diagnosis) -> list[str]:
    """The verdict's words on the counterfactual stage swaps (empty when there are none)."""
    swaps = result.counterfactuals
    if not swaps:
        return []
    out = []
    shown = list(result.location.significant)
    camera = swaps["camera"]
    if camera["rungs"]:
        closed = ", ".join(
            f"{100 * camera['rungs'][r]['closure']:.0f} % on {r}"
            for r in shown
            if r in camera["rungs"]
        )
        out.append(
            f"Emulating R's measured camera statistics on S "
            f"({camera['set'].split(':', 1)[1]}) closes {closed}."
        )
    else:
        out.append(
            "R's camera statistics (noise, blur, compression, frame rate, shake, colour "
            "cast) match S's."
        )
    norm = swaps["batchnorm"]
    layer = result.location.first_significant_layer
    if norm.get("available") and layer in norm["layers"]:
        text = (
            f"Re-estimating the network's batch-norm statistics on R closes "
            f"{100 * norm['layers'][layer]['closure']:.0f} % at {layer}"
        )
        corr = norm.get("correlations", {}).get("material_score~stiffness")
        if corr:
            after = norm["correlations"]["after"]["material_score~stiffness"]
            text += (
                f"; the material score's Spearman ρ with measured stiffness goes "
                f"{_fmt(corr['spearman'], 2)} -> {_fmt(after['spearman'], 2)}"
            )
        out.append(text + ".")
    return out


def _shapley_lines(shapley: dict | None) -> list[str]:
    if not shapley:
        return []
    closure = shapley.get("closure", shapley["coalitions"])
    rows = [[n, f"{100 * shapley['values'][n]:.0f} %", ""] for n in shapley["players"]]
    rows += [
        [f"together: {k}", f"{100 * closure[k]:.0f} %", f"{100 * v:.0f} %"]
        for k, v in shapley["coalitions"].items()
    ]
    return [
        "Interactions: exact Shapley values over coalitions of the top candidates. Each "
        "coalition is measured with every member at its own fitted strength; as a joint fit "
        "could leave any member at its neutral strength, a coalition is worth at least its "
        "best sub-coalition, and the values share that worth (they add up to the largest "
        "coalition's).",
        "",
        markdown_table(
            ["candidate / coalition", "Shapley value / worth", "measured together"], rows
        ),
    ]


_JOINT_HEADER = ["factor", "stage", "calibrated strength", "share of the gap", "reset"]


def _joint_lines(joint: JointFit | None) -> list[str]:
    """The joint calibration: each factor's strength, Shapley share and reset share."""
    if joint is None:
        return []
    rows = [
        [
            name,
            stage,
            (
                "nominal"
                if name not in joint.strengths
                else "on"
                if joint.strengths[name] is None
                else _fmt(joint.strengths[name])
                + (
                    f" {_ci(joint.strength_interval[name])}"
                    if name in joint.strength_interval
                    else ""
                )
            ),
            f"{100 * joint.shapley[name]:.0f} % {_percent_ci(joint.shapley_interval[name])}"
            if name in joint.shapley
            else "–",
            f"{100 * joint.reset[name]:.0f} % {_percent_ci(joint.reset_interval[name])}"
            if name in joint.reset
            else "–",
        ]
        for name, stage in joint.factors.items()
    ]
    shares = ", ".join(f"{stage} {100 * v:.0f} %" for stage, v in joint.stage_shares().items())
    return [
        "All factors together: the factors, chosen one at a time with the others in place "
        "and calibrated jointly (coordinate ascent, each strength refitted), close "
        f"{100 * joint.closure:.0f} % {_percent_ci(joint.closure_interval)} of it; by stage: "
        f"{shares or 'none'}, unexplained {100 * joint.unexplained:.0f} %. Share: the exact "
        "Shapley value over the factors that matter (they add up to the joint closure); "
        "reset: what returns when the factor alone is set back to nominal. Intervals: 95 % "
        f"group bootstrap. {joint.sets} sets scored."
        + (
            " Share of each scored rung's divergence S* removes: "
            + ", ".join(f"{r} {100 * v:.0f} %" for r, v in joint.rung_closure.items())
            + "."
            if joint.rung_closure
            else ""
        ),
        "",
        markdown_table(_JOINT_HEADER, rows),
        "",
        *_selection_lines(joint.path),
    ]


def _selection_lines(path: list[dict]) -> list[str]:
    """How S* was chosen: each step's addition and the closures it was measured against."""
    rows = []
    for step in (s for s in path if "step" in s):
        if "reset" in step:
            rows.append([str(step["step"]), *_prune_cells(step)])
            continue
        measured = sorted(step["measured"].items(), key=lambda kv: -kv[1])
        tried = ", ".join(f"{n} {100 * v:.0f} %" for n, v in measured)
        tied = f"tied: {', '.join(step['tied'])}" if step.get("tied") else ""
        if step["added"] and step.get("refit"):
            strengths = ", ".join(f"{n} {v}" for n, v in step["refit"][step["added"]].items())
            added = f"{step['added']} (others refitted around it: {strengths})"
        elif step["added"]:
            added = step["added"] + (f" ({tied} before it)" if tied else "")
            apart = step.get("kernel_apart", {}).get(step["added"])
            if apart:
                added += f"; told from {', '.join(apart)} by the kernel distance"
        else:
            added = f"none ({tied or 'stop'})"
        if step.get("kernel_beaten"):
            added += (
                f"; passed over: {', '.join(step['kernel_beaten'])} (a tied rival removes "
                "more of the kernel distance)"
            )
        rows.append([str(step["step"]), added, tried])
    if not rows:
        return []
    return [
        "How the factors were chosen: at each step every candidate was screened on top of the "
        "factors already chosen, and these were built and measured (closure with the "
        "addition); the best was added when it closed at least 5 % more and could be told "
        "from every addition it did not clearly beat (it still adds on top of it) or removed "
        "at least 0.1 more of the kernel distance (MMD²) than it; additions that could not be "
        "told apart are listed as tied. After a step that added nothing, the additions that "
        "had gained most were tried once more with every chosen strength refitted around "
        "them (a chosen factor at a fixed strength can stand in for part of another effect)."
        + (
            " Where the selection would stop, the chosen factor that gave back least when reset "
            "alone was dropped if that was under 5 % (a stand-in for factors added after it), "
            "and the selection went on."
            if any("reset" in step for step in path)
            else ""
        ),
        "",
        markdown_table(["step", "added", "measured (closure with it)"], rows),
        "",
    ]


def _prune_cells(step: dict) -> list[str]:
    """A prune step's cells: what it dropped, and what each chosen factor gave back reset."""
    reset = sorted(step["reset"].items(), key=lambda kv: kv[1])
    dropped = step["dropped"]
    return [
        f"dropped {dropped} (it no longer matters)" if dropped else "none dropped (each matters)",
        "reset alone gives back: " + ", ".join(f"{n} {100 * v:.0f} %" for n, v in reset),
    ]


def _percent_ci(pair) -> str:
    """``[lo, hi]`` in percent, ``–`` where a bound could not be computed."""
    return "[" + ", ".join("–" if not math.isfinite(v) else f"{100 * v:.0f}" for v in pair) + "]"


def _stacked_lines(stacked: dict | None) -> list[str]:
    """The partners fitted on top of the leader (:mod:`sim2real.stacking`), best first."""
    if not stacked or not stacked["partners"]:
        return []
    order = sorted(stacked["partners"].items(), key=lambda kv: -max(kv[1]["score"]))
    rows = [
        [
            n,
            _fmt(v["strengths"][v["score"].index(max(v["score"]))]),
            f"{100 * max(v['score']):.0f} %",
        ]
        for n, v in order
    ]
    verdict = "explains the gap" if stacked["explained"] else "does not explain the gap"
    kernel = stacked["kernel_closure"]
    return [
        "",
        f"Stacked fit: with {stacked['leader']} held at {_fmt(stacked['leader_strength'])}, "
        f"each candidate that re-renders was fitted on top of it. The best pair, with "
        f"{stacked['best']}, closes {100 * stacked['score']:.0f} % (kernel "
        f"{'–' if kernel is None else f'{100 * kernel:.0f} %'}) and {verdict}.",
        "",
        markdown_table(["partner", "best strength", "pair closes"], rows),
        "",
    ]


def _predictivity_lines(srcc: dict | None) -> list[str]:
    """Sim-to-real predictivity (SRCC) before and after, with the per-checkpoint scores."""
    if not srcc:
        return []

    def cell(entry):
        if entry["srcc"] is None:
            return f"– ({entry['checkpoints']} checkpoints)"
        ci = "" if entry["ci"] is None else f" {_ci(entry['ci'])}"
        return f"{_fmt(entry['srcc'], 2)}{ci} ({entry['checkpoints']} checkpoints)"

    rows = [
        [
            Path(r["checkpoint"]).parent.parent.name + "/" + Path(r["checkpoint"]).name,
            _fmt(r["sim"], 2),
            _fmt(r["sim_effect"], 2),
            _fmt(r["real"], 2),
        ]
        for r in srcc["rows"]
    ]
    return [
        "Sim-to-real predictivity (SRCC, Kadian et al. 2020): across checkpoints, Spearman "
        "of the score on simulated clips with the score on R (each score: ρ of the material "
        f"score with stiffness). Nominal simulator: {cell(srcc['before'])}; with the effect: "
        f"{cell(srcc['after'])}.",
        "",
        markdown_table(["checkpoint", "ρ on S", "ρ on S + effect", "ρ on R"], rows),
    ]


def _control_clause(shrink: dict) -> str:
    """What the same fine-tuning on the nominal data gave, where it was measured."""
    control = shrink["correlations"].get("control")
    if control is None:
        return ""
    stiffness, density = control["stiffness"]["spearman"], control["density"]["spearman"]
    return (
        f" (fine-tuned as long on the nominal data instead: {_fmt(stiffness, 2)} and "
        f"{_fmt(density, 2)})"
    )


def _shrink_section(shrink: dict | None) -> list[str]:
    if shrink is None:
        return [
            "Not measured in this run: `python -m sim2real.shrink report=<this folder>` "
            "regenerates the training set with the fitted effect, fine-tunes and fills this in.",
            "",
        ]
    effects = ", ".join(f"{e['name']} ({_fmt(e['strength'])})" for e in shrink["effects"])
    runs = [k for k in ("before", "after", "control") if k in shrink["correlations"]]
    rows = []
    for target in ("stiffness", "density"):
        for kind in ("pearson", "spearman"):
            row = [target, kind]
            for label in runs:
                entry = shrink["correlations"][label][target]
                ci = entry[f"{kind}_ci"]
                row += [_fmt(entry[kind], 2), "–" if ci is None else _ci(ci)]
            rows.append(row)
    header = ["measured", "r"]
    for label in runs:
        header += [_RUN_NAMES[label], "95 % CI"]
    gap_rows = [
        [
            name,
            _fmt(r["corrected_auc_before"], 2),
            _fmt(r["corrected_auc_after"], 2),
            _fmt(r.get("closure_predicted"), 2),
            _fmt(r["closure_realised"], 2),
        ]
        for name, r in shrink["rungs"].items()
    ]
    return [
        f"Training set regenerated with {effects} (preset `{shrink['preset']}`), "
        + _retrain_words(shrink)
        + (
            ""
            if shrink.get("closure_predicted_total") is None
            else f" The calibrated simulator was predicted to close "
            f"{100 * shrink['closure_predicted_total']:.0f} % of the gap."
        ),
        "",
        *_predictivity_lines(shrink.get("predictivity")),
        markdown_table(header, rows),
        markdown_table(
            [
                "rung",
                "corrected AUC before",
                "after",
                "closure predicted (section 2)",
                "closure realised",
            ],
            gap_rows,
        ),
        *_score_correlation_lines(shrink.get("score_correlations")),
    ]


_RUN_NAMES = {"before": "before", "after": "after", "control": "nominal control"}
"""Column names of the shrink section's runs: the model, retrained, and the control."""


def _retrain_words(shrink: dict) -> str:
    """How the model after was trained, and its control, as a clause of the section's lead."""
    control = shrink.get("control")
    if shrink.get("init") == "scratch":
        words = f"a fresh model trained for {shrink['epochs']} epochs with the run's recipe"
        if control and control.get("is_the_run"):
            return words + "; its control is the run itself (trained as long on the nominal data)."
        if control:
            return words + "; as a control, one trained as long afresh on the nominal data."
        return words + "."
    words = f"model fine-tuned for {shrink['epochs']} epochs from the run's weights"
    if shrink.get("lr_scale") is not None:
        words += f" at {shrink['lr_scale']:g} of its training rate"
    if control:
        return (
            words + "; as a control, fine-tuned as long from the same weights on the nominal data."
        )
    return words + "."


def _score_correlation_lines(correlations: dict | None) -> list[str]:
    """Every score against every measured column, pooled and per wind, before and after.

    Pearson r with the evaluation's grouped bootstrap intervals.
    """
    if not correlations:
        return []
    before, after = correlations["before"], correlations["after"]
    control = correlations.get("control")

    def change(a, b):
        if b is None or b["pearson"] is None or a["pearson"] is None:
            return None
        return a["pearson"] - b["pearson"]

    def cells(entry):
        if entry is None:  # a score the model before did not have (a density axis added)
            return ["–", "–"]
        ci = entry["pearson_ci"]
        return [_fmt(entry["pearson"], 2), "–" if ci is None else _ci(ci)]

    def of(section, scope, score, column):
        return section.get(scope, {}).get(score, {}).get(column)

    rows = []
    for scope, by_score in after.items():
        for score, by_column in by_score.items():
            for column, a in by_column.items():
                b = of(before, scope, score, column)
                row = ["pooled" if scope == "all" else scope, score, column, *cells(b), *cells(a)]
                row.append(_fmt(change(a, b), 2))
                if control is not None:
                    c = of(control, scope, score, column)
                    row += [*cells(c), _fmt(change(a, c), 2)]
                rows.append(row)
    header = ["videos", "score", "measured", "before", "95 % CI", "after", "95 % CI", "change"]
    if control is not None:
        header += ["nominal control", "95 % CI", "after − nominal"]
    return [
        "",
        "Every score against every measured column (Pearson r; 95 % intervals from a bootstrap "
        "over fabrics), pooled over the winds and per wind:",
        "",
        markdown_table(header, rows),
    ]


def _rung_rows(result: Diagnosis) -> list[list]:
    rows = []
    pooled = result.detection_rungs or {}
    for name, gap in result.rungs.items():
        probe = result.probes.get(name, {})
        rows.append(
            [
                name,
                _fmt(gap["mmd2"]),
                _ci(gap["mmd2_ci"]),
                _fmt(gap["floor_mmd2"]),
                _fmt(gap["auc"], 2),
                _ci(gap["auc_ci"]),
                _fmt(gap["floor_auc"], 2),
                _fmt(gap["p_value"], 2),
                _fmt(gap.get("p_c2st"), 2),
                _fmt(pooled.get(name, {}).get("p_gap"), 2),
                "yes" if name in result.location.significant else "",
                "yes" if name in result.location.bonferroni else "",
                _fmt(probe.get("stiffness_spearman"), 2),
                _fmt(probe.get("density_spearman"), 2),
            ]
        )
    return rows


_RUNG_HEADER = [
    "rung",
    "MMD²",
    "95 % CI",
    "floor",
    "AUC",
    "95 % CI",
    "floor AUC",
    "p (MMD²)",
    "p (C2ST)",
    "p, S + S' vs R",
    "shows the gap",
    "on its own",
    "probe ρ stiffness",
    "probe ρ density",
]


def _percent(value: float | None) -> str:
    return "–" if value is None else f"{100 * value:.0f} %"


def _candidate_rows(result: Diagnosis) -> list[list]:
    rows = []
    rungs = result.scored_rungs
    for rank, name in enumerate(result.ranking.ranking, 1):
        entry = result.candidates[name]
        best = entry["best"] if "best" in entry else int(np.argmax(entry["score"]))
        closure = entry.get("closure_auc") or entry["closure"]
        closes = [f"{100 * closure[r][best]:.0f} %" for r in rungs]
        lo, hi = entry["strength_interval"]
        rows.append(
            [
                rank,
                name,
                entry["stage"],
                _fmt(entry["best_strength"]),
                "" if lo is None else f"[{_fmt(lo)}, {_fmt(hi)}]",
                f"{100 * entry['best_score']:.0f} %",
                _percent(entry.get("kernel_closure")),
                *closes,
            ]
        )
    null = result.null
    if null is not None:
        closure = null.get("closure_auc") or null["closure"]
        closes = [f"{100 * closure[r][0]:.0f} %" for r in rungs]
        rows.append(
            [
                "–",
                "S' (fresh nominal draw)",
                "null",
                "",
                "",
                f"{100 * null['best_score']:.0f} %",
                _percent(null.get("kernel_closure")),
                *closes,
            ]
        )
    return rows


def _closure_table(first: str, rungs: dict) -> str:
    """A swap's gap per rung before and after (:func:`sim2real.counterfactuals.swap_closure`)."""
    return markdown_table(
        [first, "MMD² before", "after", "closed", "corrected AUC before", "after"],
        [
            [
                r,
                _fmt(v["mmd2_before"]),
                _fmt(v["mmd2_after"]),
                f"{100 * v['closure']:.0f} %",
                _fmt(v["corrected_auc_before"], 2),
                _fmt(v["corrected_auc_after"], 2),
            ]
            for r, v in rungs.items()
        ],
    )


def _swap_lines(swaps: dict | None) -> list[str]:
    """Section 1's counterfactual stage swaps: camera of R on S, AdaBN on R."""
    if not swaps:
        return []
    lines = ["### Counterfactual stage swaps", ""]
    camera = swaps["camera"]
    rows = [
        [
            name,
            m["statistic"] or "none found",
            _fmt(m.get("nominal")),
            _fmt(m.get("real")),
            _fmt(m.get("z"), 2),
            "yes" if m["present"] else "no",
            _fmt(m["strength"]),
        ]
        for name, m in camera["matched"].items()
    ]
    lines += [
        "**Camera of R emulated on S.** Each camera effect's signature statistic (the clip "
        "statistic it moves most and the other camera effects least) measured on S and R; an "
        "effect counts as present when R differs from S by >= 3 standard errors in the "
        "effect's direction, and its strength is read off its sets.",
        "",
        markdown_table(["effect", "signature", "S", "R", "z", "present", "strength"], rows),
    ]
    if camera["rungs"]:
        lines += [
            f"S with {camera['set'].split(':', 1)[1]} vs R:",
            "",
            _closure_table("rung", camera["rungs"]),
        ]
    else:
        lines += ["R's camera statistics match S's: nothing to emulate.", ""]
    norm = swaps["batchnorm"]
    if not norm["available"]:
        return [*lines, f"**Batch-norm statistics re-estimated on R:** {norm['reason']}.", ""]
    lines += [
        "**Batch-norm statistics re-estimated on R (AdaBN).** The share of each layer's gap "
        "that a per-channel shift and scale explain:",
        "",
        _closure_table("layer", norm["layers"]),
    ]
    if "correlations" in norm:
        rows = []
        for key, before in norm["correlations"]["before"].items():
            after = norm["correlations"]["after"][key]
            score, target = key.split("~")
            rows.append(
                [
                    score,
                    target,
                    _fmt(before["spearman"], 2),
                    "–" if before["spearman_ci"] is None else _ci(before["spearman_ci"]),
                    _fmt(after["spearman"], 2),
                    "–" if after["spearman_ci"] is None else _ci(after["spearman_ci"]),
                ]
            )
        lines += [
            "The model's scores on R (per video) against the measured values, Spearman ρ "
            "before and after AdaBN:",
            "",
            markdown_table(
                ["score", "measured", "ρ before", "95 % CI", "ρ after", "95 % CI"], rows
            ),
        ]
    return lines


def document(result: Diagnosis, figures: list[str]) -> list:
    """The report as lines of Markdown and tables (:class:`models.report.MarkdownTable`)."""
    lead = [f for f in figures if f == "shares.png"]
    lines = [
        f"# Sim-to-real diagnosis: {result.name}",
        "",
        answer(result),
        "",
        *[f"![{f}]({f})" for f in lead],
        "",
        "## Evidence",
        "",
        verdict(result),
        "",
    ]
    info = result.inputs
    lines += [
        f"Real set: `{info.real_dir}` ({info.real_videos} videos, {info.real_clips} "
        f"clips; skipped as too short: {info.real_skipped or 'none'}). Run: `{info.run}`. "
        f"Simulated nominal set S: {info.sim_clips} clips of {info.sim_groups} "
        f"simulations (training data settings, fresh seeds). Budget `{info.budget}`.",
        "",
        "## 1. Where the gap lies",
        "",
        markdown_table(_RUNG_HEADER, _rung_rows(result)),
        "S against R, the size every candidate set S_e is compared at: MMD² on features "
        "standardised with S and R pooled; floors are the values expected from group sampling "
        "alone (S vs S' split by simulation, R vs R' by video); p (MMD²) from group "
        "permutations, p (C2ST) a one-sided Mann-Whitney test of the classifier's out-of-fold "
        "scores per group. The gap test compares R with S and S' pooled (twice the "
        "simulations, so more power) and combines both p-values of every rung (harmonic mean "
        "p-value); given a gap, a rung shows it when its p, S + S' vs R (twice its smaller p) "
        "is below alpha, and stands on its own when that passes the Bonferroni level over the "
        "rungs; probes: ridge "
        "of the class position trained on S, Spearman ρ of the per-video prediction with the "
        "measured values on R.",
        "",
        *_swap_lines(result.counterfactuals),
        "## 2. Which unmodelled effect",
        "",
        f"Scored rungs: {', '.join(result.scored_rungs) or 'none'}. Score = mean fraction "
        "of the floor-corrected domain-classifier AUC that S_e closes at the fitted strength "
        "(AUC(S, R) - AUC(S_e, R)) / (AUC(S, R) - floor); kernel = mean fraction of the "
        "floor-corrected MMD² closed on the scored rungs where it lies above its floor ("
        + (", ".join(result.ranking.kernel_rungs) or "none")
        + "), at the fitted strength or, where larger, at another strength inside the interval "
        "whose score also reaches the threshold. A cause must reach the threshold on both.",
        "",
        markdown_table(
            [
                "rank",
                "candidate",
                "stage",
                "fitted strength",
                "interval",
                "score",
                "kernel",
                *[f"closes {r}" for r in result.scored_rungs],
            ],
            _candidate_rows(result),
        ),
        *_shapley_lines(result.shapley),
        *_stacked_lines(result.stacked),
        *_joint_lines(result.joint),
        *_detectability_lines(result.detectability),
        "Best score per stage: "
        + ", ".join(
            f"{s} {('–' if v is None else f'{100 * v:.0f} %')}"
            for s, v in result.ranking.stage_scores.items()
        ),
        "",
        "## 3. How far it shrinks",
        "",
        *_shrink_section(result.shrink),
        "## Time",
        "",
        markdown_table(
            ["stage", "seconds"],
            [[k, f"{v:.1f}"] for k, v in result.timing.items()],
        ),
        "",
    ]
    lines += [f"![{f}]({f})" for f in figures if f not in lead]
    return lines


def _markdown(result: Diagnosis, figures: list[str]) -> str:
    return "\n".join(str(line) for line in document(result, figures)) + "\n"


def _png(fig) -> bytes:
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png")
    return buffer.getvalue()


def _figures(result: Diagnosis, out_dir: Path) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(result.rungs)
    gaps = [result.rungs[n] for n in names]
    fig, ax = plt.subplots(figsize=(9, 3.8), dpi=100)
    auc = np.array([g["auc"] for g in gaps])
    lo = np.array([g["auc_ci"][0] for g in gaps])
    hi = np.array([g["auc_ci"][1] for g in gaps])
    floor = np.array([np.nan if g["floor_auc"] is None else g["floor_auc"] for g in gaps])
    colours = ["#d62728" if n in result.location.significant else "#7f7f7f" for n in names]
    ax.bar(names, auc, color=colours, yerr=[auc - lo, hi - auc], capsize=3)
    ax.plot(names, floor, "k_", markersize=18, label="noise floor (S vs S', R vs R')")
    ax.set_ylim(0.3, 1.02)
    ax.set_ylabel("domain AUC (S vs R)")
    ax.set_title("Where the gap lies: red = significant after the floor")
    ax.tick_params(axis="x", rotation=45)
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    atomic_write_bytes(out_dir / "rungs.png", _png(fig))
    plt.close(fig)

    ranking = result.ranking.ranking
    scores = [result.candidates[n]["best_score"] for n in ranking]
    stages = [result.candidates[n]["stage"] for n in ranking]
    fig, ax = plt.subplots(figsize=(9, 0.28 * len(ranking) + 1.4), dpi=100)
    ax.barh(ranking[::-1], scores[::-1], color=[STAGE_COLOURS[s] for s in stages[::-1]])
    ax.axvline(result.ranking.threshold, color="k", linestyle="--", label="open-set threshold")
    ax.axvline(
        result.ranking.null_score, color="#7f7f7f", linestyle=":", label="fresh nominal draw S'"
    )
    ax.set_xlim(-1, 1)
    ax.set_xlabel("fraction of the floor-corrected gap closed (scored rungs, fitted strength)")
    ax.legend(loc="lower left", fontsize=8)
    fig.tight_layout()
    atomic_write_bytes(out_dir / "candidates.png", _png(fig))
    plt.close(fig)
    if result.joint is None or not result.joint.shapley:
        return ["rungs.png", "candidates.png"]
    atomic_write_bytes(out_dir / "shares.png", _share_chart(result.joint))
    return ["shares.png", "rungs.png", "candidates.png"]


def _share_chart(joint: JointFit) -> bytes:
    """Each factor's share of the gap (Shapley value, 95 % interval), then the unexplained."""
    import matplotlib.pyplot as plt

    order = sorted(joint.shapley.items(), key=lambda kv: -kv[1])
    names = [f"{n} ({joint.factors[n]})" for n, _ in order] + ["unexplained"]
    values = np.array([v for _, v in order] + [joint.unexplained]) * 100
    low = np.array([joint.shapley_interval[n][0] for n, _ in order] + [np.nan]) * 100
    high = np.array([joint.shapley_interval[n][1] for n, _ in order] + [np.nan]) * 100
    errors = np.nan_to_num(np.abs(np.stack([values - low, high - values])), nan=0.0)
    colours = [STAGE_COLOURS[joint.factors[n]] for n, _ in order] + ["#bbbbbb"]
    fig, ax = plt.subplots(figsize=(9, 0.45 * len(names) + 1.3), dpi=100)
    ax.barh(names[::-1], values[::-1], color=colours[::-1], xerr=errors[:, ::-1], capsize=3)
    ax.set_xlim(0, 100)
    ax.set_xlabel("share of the gap [%] (Shapley value at the calibrated simulator)")
    ax.set_title(f"The calibrated simulator closes {100 * joint.closure:.0f} % of the gap")
    fig.tight_layout()
    data = _png(fig)
    plt.close(fig)
    return data


def contact_sheet(path: Path, rows: dict[str, np.ndarray], box, frames: int = 5) -> None:
    """PNG grid: one row of ``frames`` frames per named clip (uint8 (T, H, W, 3)), ROI drawn."""
    import cv2

    tiles = []
    for label, clip in rows.items():
        step = max(1, len(clip) // frames)
        picked = [clip[i].copy() for i in range(0, step * frames, step)[:frames] if i < len(clip)]
        y0, y1, x0, x1 = box
        for frame in picked:
            cv2.rectangle(frame, (x0, y0), (x1 - 1, y1 - 1), (255, 0, 0), 1)
        strip = np.concatenate(picked, axis=1)
        band = np.full((14, strip.shape[1], 3), 255, np.uint8)
        cv2.putText(band, label, (2, 11), cv2.FONT_HERSHEY_SIMPLEX, 0.35, (0, 0, 0), 1)
        tiles.append(np.concatenate([band, strip], axis=0))
    width = max(t.shape[1] for t in tiles)
    tiles = [
        np.pad(t, ((0, 0), (0, width - t.shape[1]), (0, 0)), constant_values=255) for t in tiles
    ]
    ok, data = cv2.imencode(".png", np.concatenate(tiles, axis=0)[..., ::-1])
    if not ok:
        raise RuntimeError("cv2.imencode failed on the contact sheet")
    atomic_write_bytes(path, data.tobytes())


def write_report(result: Diagnosis, out_dir: Path, extra_figures: tuple[str, ...] = ()) -> None:
    """Write ``report.json``, ``report.md``, ``report.html`` and the figures into ``out_dir``."""
    out_dir.mkdir(parents=True, exist_ok=True)
    figures = [*extra_figures, *_figures(result, out_dir)]
    markdown = _markdown(result, figures)
    write_json(out_dir / "report.json", result.to_json())
    write_text(out_dir / "report.md", markdown)
    write_text(
        out_dir / "report.html",
        render_html(document(result, figures), f"Sim-to-real diagnosis: {result.name}"),
    )
