"""Does the gap measure keep its resolution where the classifier's AUC saturates?

On a diagnosed multi-effect sealed set, the withheld effects are added to the nominal
simulation one at a time (in the answer's order) and each cumulative set is compared with R
as the diagnosis compares its candidates: per scored rung the domain classifier's AUC and its
divergence, and the share of the gap closed. A measure that keeps its resolution falls
towards its floor with every effect added while the AUC may stay at 1.

Usage: ``python -m benchmarks.gap_resolution --report outputs/sim2real/<name>
--answer <set>.answer.json [--n-jobs 2] [--out gap_resolution.json]``. Prints a table and,
as the last line, the JSON.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
from pathlib import Path

from common.commands import report_user_errors
from common.errors import InputError
from common.files import atomic_write_bytes
from common.paths import check_output_file
from simulator.threads import use_process_threads

__all__ = ["main", "resolution_steps"]


def resolution_steps(report_dir: Path, answer: dict, *, n_jobs: int = 1) -> dict:
    """The cumulative sets' AUC, divergence and closure (see the module docstring)."""
    from sim2real.diagnosis.joint import assignment
    from sim2real.reopen import reopen
    from sim2real.report import read_report

    result = read_report(report_dir, "--report")
    if not result.scored_rungs:
        raise InputError("--report: that diagnosis found no gap, so nothing is scored")
    reopened = reopen(result)
    effects = [e for e in answer["effects"] if e["library"]]
    if not effects:
        raise InputError("--answer: the set withholds no library effect")
    steps, chosen = [()], {}
    for effect in effects:
        chosen[effect["name"]] = effect["strength"]
        steps.append(assignment(chosen))
    measured = reopened.classifier(steps, n_jobs=n_jobs)
    values = reopened.values(steps, n_jobs=n_jobs)
    rows = []
    for i, (step, rungs, value) in enumerate(zip(steps, measured, values, strict=True)):
        rows.append(
            {
                "added": "nominal S" if i == 0 else effects[i - 1]["name"],
                "effects": len(step),
                "closure": value.closure,
                "rungs": {r: {k: float(v) for k, v in m.items()} for r, m in rungs.items()},
            }
        )
    divergences = {r: [row["rungs"][r]["divergence"] for row in rows] for r in result.scored_rungs}
    return {
        "report": str(report_dir),
        "seed": answer.get("seed"),
        "kind": answer.get("kind"),
        "steps": rows,
        "closure_monotone": all(b["closure"] >= a["closure"] for a, b in itertools.pairwise(rows)),
        "divergence_monotone": {
            r: all(b <= a for a, b in itertools.pairwise(d)) for r, d in divergences.items()
        },
        "auc_saturated_steps": sum(
            all(m["auc"] >= 0.99 for m in row["rungs"].values()) for row in rows
        ),
    }


def _table(out: dict) -> str:
    rungs = list(out["steps"][0]["rungs"])
    head = "| added | closure | " + " | ".join(f"{r} AUC | {r} divergence" for r in rungs) + " |"
    lines = [head, "|" + "---|" * (2 + 2 * len(rungs))]
    for row in out["steps"]:
        cells = []
        for r in rungs:
            m = row["rungs"][r]
            cells += [
                f"{m['auc']:.3f}",
                "–" if not math.isfinite(m["divergence"]) else f"{m['divergence']:.2f}",
            ]
        lines.append(
            f"| {row['added']} | {100 * row['closure']:.0f} % | " + " | ".join(cells) + " |"
        )
    return "\n".join(lines)


@report_user_errors
def main(argv: list[str] | None = None) -> dict:
    """Command line (see the module docstring)."""
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks.gap_resolution", description=__doc__.split("\n")[0]
    )
    parser.add_argument("--report", required=True, help="a diagnosis's report folder")
    parser.add_argument("--answer", required=True, help="the sealed set's answer file")
    parser.add_argument("--n-jobs", type=int, default=1)
    parser.add_argument("--out", help="also write the JSON here")
    args = parser.parse_args(argv)
    use_process_threads(1)
    if args.out:
        check_output_file(args.out, "--out")
    try:
        answer = json.loads(Path(args.answer).read_text())
    except (OSError, ValueError) as err:
        raise InputError(f"--answer: cannot read {args.answer} as JSON ({err})") from None
    if not isinstance(answer, dict) or not isinstance(answer.get("effects"), list):
        raise InputError(f"--answer: {args.answer} is not a sealed set's answer (no 'effects')")
    out = resolution_steps(Path(args.report), answer, n_jobs=args.n_jobs)
    print(_table(out))
    text = json.dumps(out, sort_keys=True)
    if args.out:
        atomic_write_bytes(Path(args.out), (json.dumps(out, indent=2) + "\n").encode())
    print(text)
    return out


if __name__ == "__main__":
    main()
