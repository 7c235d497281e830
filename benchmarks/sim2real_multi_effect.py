"""The multi-effect validation's figures against the targets of the joint diagnosis.

Reads a scored validation round of ``multi`` and ``twin`` sets (``validation.json`` written by
``python -m sim2real.study.validate --kinds multi:24,twin:20 ...``, or the round's committed
ledger, ``reports/sim2real/rounds/roundNN/rows_*.jsonl``) and, optionally, the closed loop on
independent-engine footage (a diagnosis folder after ``python -m sim2real.shrink``: its
``report.json`` holds every score's correlations before and after retraining; or an earlier
results file whose loop figures are carried over). Writes ``sim2real_multi_effect.json`` and
a Markdown table beside it.

Usage: ``python -m benchmarks.sim2real_multi_effect --validation <validate --out folder>
[--loop <diagnosis folder after shrink>] [--speed <diagnose_bench output>] [--out
docs/results]``. ``--speed``: the saved output of ``python -m benchmarks.diagnose_bench``
(its last line is JSON), a cold diagnosis on a quiet machine; it is then the figure judged
against the time target, since the round's own diagnoses share a library cache and,
often, the machine.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from common.commands import report_user_errors
from common.errors import InputError
from common.files import atomic_write_bytes
from common.paths import check_output_dir
from sim2real.study.validate import summarise

ROOT = Path(__file__).resolve().parents[1]

LOOP_PAIRS = (
    ("bend_score", "stiffness"),
    ("stretch_score", "stretch_stiffness"),
    ("density_score", "density"),
)
"""(score, measured column) pairs whose pooled Pearson r the closed loop must raise; the
independent engine's ``stiffness`` is the bending multiplier, ``stretch_stiffness`` [N/m].
A model whose classes have one density has no ``density_score``; ``material_score`` (the
thesis's choice) stands in for it then (:data:`STAND_INS`)."""

STAND_INS = {"density_score": "material_score"}
"""Score -> the score used where a report has none of the first (a one-density class grid)."""

TARGETS = {
    "multi_sets": (">=", 24),
    "twin_sets": (">=", 20),
    "factor_f1": (">=", 0.8),
    "stage_share_error_pts_max": ("<=", 15.0),
    "twin_false_attribution": ("<=", 0.05),
    "independent_engine_r_gain_min": (">=", 0.2),
    "independent_engine_r_after_min": (">=", 0.5),
    "quick_minutes": ("<=", 30.0),
}
"""The targets of the joint diagnosis (``quick_minutes``: the cold diagnosis of ``--speed``,
else the longest diagnosis of the round)."""


def _ledger_rows(folder: Path) -> list[dict] | None:
    """The rows of a round's committed ledger, or ``None`` where the folder has none.

    The ledger is ``rows_*.jsonl``, one scored set a line; a seed met twice keeps its last row.
    """
    paths = sorted(folder.glob("rows_*.jsonl"))
    if not paths:
        return None
    rows: dict[int, dict] = {}
    for path in paths:
        for number, line in enumerate(path.read_text().splitlines(), 1):
            if not line.strip():
                continue
            try:
                row = json.loads(line)
                rows[int(row["seed"])] = row
            except (ValueError, KeyError, TypeError) as err:
                raise InputError(
                    f"--validation: {path} line {number} is not a scored set ({err})"
                ) from None
    return [rows[seed] for seed in sorted(rows)]


def _rows(folder: Path) -> list[dict]:
    path = folder / "validation.json"
    if path.is_file():
        try:
            rows = json.loads(path.read_text())["sets"]
        except (ValueError, KeyError, TypeError) as err:
            raise InputError(f"--validation: {path} is not a validation.json ({err})") from None
    else:
        rows = _ledger_rows(folder)
        if rows is None:
            raise InputError(
                f"--validation: {folder} holds no validation.json and no rows_*.jsonl; give "
                "the --out folder of a finished sim2real.study.validate run or a round's "
                "ledger folder (reports/sim2real/rounds/roundNN)"
            )
        path = folder
    kept = [r for r in rows if r.get("kind") in ("multi", "twin")]
    if not kept:
        raise InputError(f"--validation: {path} has no multi or twin sets")
    return kept


def _loop(path: Path) -> dict:
    """The closed loop's figures, from a diagnosis folder or an earlier results file.

    A diagnosis folder after shrink gives them from its ``report.json``; an earlier
    ``sim2real_multi_effect.json`` carries its ``independent_engine`` block over.
    """
    if path.is_file() and path.suffix == ".json":
        try:
            loop = json.loads(path.read_text())["independent_engine"]
        except (ValueError, KeyError, TypeError) as err:
            raise InputError(
                f"--loop: {path} is not a sim2real_multi_effect.json with an "
                f"independent_engine block ({err})"
            ) from None
        if not isinstance(loop, dict) or not loop:
            raise InputError(f"--loop: {path} has no independent-engine figures")
        return loop
    report = path / "report.json"
    if not report.is_file():
        raise InputError(
            f"--loop: {path} holds no report.json (give a diagnosis folder after shrink or an "
            "earlier sim2real_multi_effect.json)"
        )
    return loop_figures(json.loads(report.read_text()))


def _gain(after, before):
    return None if None in (before, after) else after - before


def loop_figures(report: dict, pairs=LOOP_PAIRS) -> dict:
    """Pooled Pearson r of each (score, column) pair before and after, and the gains.

    Where shrink ran a control (the same fine-tuning on the nominal data), also its r and the
    gain over it: what the calibrated simulator adds beyond the extra training.
    """
    shrink = report.get("shrink") or {}
    every = shrink.get("score_correlations")
    if every is None:
        raise InputError(
            "--loop: the report has no shrink section with every score's "
            "correlations; run python -m sim2real.shrink on it first"
        )

    def scored(label: str, score: str, column: str) -> tuple[str, dict]:
        pooled = every[label]["all"]
        if score not in pooled and score in STAND_INS:
            score = STAND_INS[score]
        try:
            return score, pooled[score][column]
        except KeyError:
            raise InputError(
                f"--loop: no {score} vs {column} correlation; rerun shrink with "
                f"columns=[...,{column}]"
            ) from None

    out = {}
    for name, column in pairs:
        score, after = scored("after", name, column)
        before_score, before = scored("before", name, column)
        entry = {
            "before": before["pearson"],
            "before_ci": before["pearson_ci"],
            "after": after["pearson"],
            "after_ci": after["pearson_ci"],
            "gain": _gain(after["pearson"], before["pearson"]),
        }
        if before_score != score:  # the model before had no such score (no density axis)
            entry["before_score"] = before_score
        if "control" in every:
            control_score, control = scored("control", name, column)
            entry["control"] = control["pearson"]
            entry["control_ci"] = control["pearson_ci"]
            entry["gain_over_control"] = _gain(after["pearson"], control["pearson"])
            if control_score != score:
                entry["control_score"] = control_score
        out[f"{score} vs {column}"] = entry
    return out


def speed_figures(path: Path) -> dict:
    """The cold diagnosis of a saved ``benchmarks.diagnose_bench`` output (its last JSON line)."""
    if not path.is_file():
        raise InputError(f"--speed: {path} is not a file; save the output of diagnose_bench")
    lines = [line for line in path.read_text().splitlines() if line.startswith("{")]
    try:
        last = json.loads(lines[-1]) if lines else {}
    except json.JSONDecodeError:
        last = {}
    if not isinstance(last.get("diagnose_minutes"), int | float):
        raise InputError(
            f"--speed: {path} has no JSON line with diagnose_minutes (the last line that "
            "python -m benchmarks.diagnose_bench prints)"
        )
    return last


def figures(rows: list[dict], loop: dict | None, speed: dict | None = None) -> dict:
    """The round's figures, each target and whether it is met (``None``: not measured)."""
    summary = summarise(rows)
    minutes = [r["minutes"] for r in rows if r.get("minutes") is not None]
    out = {
        "sets": {
            "multi": sum(r["kind"] == "multi" for r in rows),
            "twin": sum(r["kind"] == "twin" for r in rows),
        },
        "seeds": sorted(int(r["seed"]) for r in rows),
        "factor_f1": summary["factor_f1"],
        "factor_f1_matter": summary["factor_f1_matter"],
        "factor_f1_ceiling": summary["factor_f1_ceiling"],
        "factor_precision": summary["factor_precision"],
        "factor_recall": summary["factor_recall"],
        "stage_share_error_pts": {
            "median": summary["stage_share_error_pts_median"],
            "max": summary["stage_share_error_pts_max"],
        },
        "factor_strength_in_interval": {
            "share": summary.get("factor_strength_in_interval"),
            "n": summary.get("factor_strength_in_interval_n", 0),
        },
        "twin_false_attribution": summary["twin_false_attribution"],
        "quick_minutes": {
            "first": minutes[0] if minutes else None,
            "median": float(np.median(minutes)) if minutes else None,
            "max": max(minutes) if minutes else None,
            "cold": None if speed is None else speed["diagnose_minutes"],
            "cold_candidate_sets": None if speed is None else speed.get("candidate_sets"),
            "cold_kind": None if speed is None else speed.get("kind"),
        },
        "independent_engine": loop,
        "independent_engine_r_gain_min": None,
        "independent_engine_r_after_min": None,
        "independent_engine_r_gain_over_control_min": None,
    }
    if loop:
        for key, field in (
            ("independent_engine_r_gain_min", "gain"),
            ("independent_engine_r_after_min", "after"),
            ("independent_engine_r_gain_over_control_min", "gain_over_control"),
        ):
            values = [v.get(field) for v in loop.values()]
            out[key] = None if None in values else min(values)
    measured = {
        **out,
        "stage_share_error_pts_max": out["stage_share_error_pts"]["max"],
        "quick_minutes": out["quick_minutes"]["max"]
        if speed is None
        else speed["diagnose_minutes"],
        "multi_sets": out["sets"]["multi"],
        "twin_sets": out["sets"]["twin"],
    }
    out["targets"] = {
        key: {
            "target": f"{op} {bound:g}",
            "measured": measured[key],
            "met": None
            if measured[key] is None
            else (measured[key] >= bound if op == ">=" else measured[key] <= bound),
        }
        for key, (op, bound) in TARGETS.items()
    }
    if speed is not None and speed.get("kind") != "multi":
        # The target is for a multi-effect gap, calibration included: a cold single-effect
        # diagnosis builds fewer joint sets, so it cannot show the target met.
        out["targets"]["quick_minutes"]["met"] = None
    return out


def _speed_note(quick: dict) -> str:
    if quick.get("cold_kind") == "multi":
        return (
            "a cold diagnosis of a multi-effect set on a quiet machine (benchmarks.diagnose_bench)."
        )
    return (
        "a cold diagnosis on a quiet machine (benchmarks.diagnose_bench) of a set that is not "
        "multi-effect, so the target is not judged: a multi-effect set's joint fit builds "
        "more sets (measure it with --kind multi)."
    )


def _shown(value) -> str:
    """A figure as the table prints it: ``–`` unmeasured, a count whole, else two decimals."""
    return "–" if value is None else str(value) if isinstance(value, int) else f"{value:.2f}"


def table(result: dict) -> str:
    """The targets as a Markdown table."""
    lines = ["| measure | target | measured | met |", "|---|---|---|---|"]
    for key, t in result["targets"].items():
        value = t["measured"]
        shown = _shown(value)
        met = "–" if t["met"] is None else ("yes" if t["met"] else "no")
        lines.append(f"| {key} | {t['target']} | {shown} | {met} |")
    sets = result["sets"]
    also = [
        ("factor F1 over the effects that matter", result.get("factor_f1_matter")),
        (
            "factor F1 of naming exactly the effects that matter (the most an answer that "
            "names only what changes at least 5 % of the gap can score)",
            result.get("factor_f1_ceiling"),
        ),
        ("factor precision", result.get("factor_precision")),
        ("factor recall", result.get("factor_recall")),
        ("stage share error, median (points)", result["stage_share_error_pts"]["median"]),
    ]
    lines.append("")
    lines.append("Also measured: " + "; ".join(f"{name} {_shown(v)}" for name, v in also) + ".")
    lines.append("")
    lines.append(
        f"{sets['multi']} multi-effect and {sets['twin']} effect-free sets (seeds "
        f"{min(result['seeds'])}-{max(result['seeds'])}); quick_minutes: "
        + (
            _speed_note(result["quick_minutes"])
            if result["quick_minutes"]["cold"] is not None
            else "the longest diagnosis of the round (library cached, machine often shared)."
        )
    )
    if result.get("command"):
        lines += ["", f"Made by `{result['command']}`."]
    return "\n".join(lines) + "\n"


@report_user_errors
def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--validation",
        type=Path,
        required=True,
        help="the --out folder of a scored multi/twin validation round, or a round's "
        "committed ledger folder (rows_*.jsonl)",
    )
    parser.add_argument(
        "--loop",
        type=Path,
        default=None,
        help="a diagnosis folder of independent-engine footage after shrink, or an earlier "
        "sim2real_multi_effect.json whose loop figures are carried over",
    )
    parser.add_argument(
        "--speed",
        type=Path,
        default=None,
        help="the saved output of python -m benchmarks.diagnose_bench (a cold diagnosis)",
    )
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "results")
    args = parser.parse_args(argv)
    rows = _rows(args.validation)
    loop = None if args.loop is None else _loop(args.loop)
    speed = None if args.speed is None else speed_figures(args.speed)
    result = figures(rows, loop, speed)
    given = sys.argv[1:] if argv is None else argv
    result["command"] = " ".join(["python -m benchmarks.sim2real_multi_effect", *given])
    check_output_dir(args.out, "--out")
    args.out.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(
        args.out / "sim2real_multi_effect.json", (json.dumps(result, indent=1) + "\n").encode()
    )
    atomic_write_bytes(args.out / "sim2real_multi_effect.md", table(result).encode())
    print(table(result))
    return result


if __name__ == "__main__":
    main()
