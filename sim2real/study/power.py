"""How the gap test's power grows with more nominal simulations, on diagnosed sets.

``python -m sim2real.study.power REPORT.json [REPORT.json ...] --draws 2,4,6 [--answers DIR]``
re-tests stored diagnoses: for each report it pools k nominal draws (S, S' and further draws
of the same nominal scene under other simulation seeds, built through the diagnosis's own
cache) against the report's real clips, and gives the gap test's p-value
(:func:`sim2real.diagnosis.localise`) and the rungs whose own tests pass at ``alpha``, for
each k. It asks whether a set the diagnosis found no gap in holds a gap that more
simulations would find, and on which rungs: the answer separates "too few simulations"
from "too few real videos". With ``--answers`` (a validation's answer folder) each row also
names the withheld effect; the answers are read only to label the table.

Writes ``power.json`` and ``power.md`` into ``--out``; the last printed line is the JSON.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

from common.checks import check_int
from common.commands import report_user_errors
from common.errors import InputError
from common.files import atomic_write_bytes
from common.paths import check_output_dir
from datasets.spec import DatasetSpec

from ..diagnosis import localise, rung_gaps
from ..ladder import LadderFeatures
from ..pipeline import NULL_SEED_OFFSET, SetJob, run_jobs
from ..reopen import report_context, report_real_features
from ..report import read_report
from ..result import Diagnosis, DiagnosisInputs
from ..rungs import hand_rung_names

__all__ = ["draw_spec", "nominal_draws", "pooled_detection"]


def draw_spec(spec: DatasetSpec, draw: int) -> DatasetSpec:
    """Nominal draw ``draw`` of the diagnosis's S: 0 is S, 1 is S', then further seeds."""
    return dataclasses.replace(spec, seed=spec.seed + NULL_SEED_OFFSET * draw)


def pooled_detection(
    draws: list[LadderFeatures],
    real: LadderFeatures,
    counts: list[int],
    *,
    alpha: float = 0.05,
    n_perm: int = 200,
    seed: int = 0,
) -> list[dict]:
    """The gap test of the first k draws pooled against ``real``, for each k in ``counts``.

    Per k: the combined p-value ``gap_p`` and, per rung, the kernel and classifier p-values;
    ``rungs`` lists the rungs where either lies below ``alpha`` (no floors: this asks what
    the test can tell apart, not how large the gap is).
    """
    out = []
    for count in counts:
        if not 1 <= count <= len(draws):
            raise ValueError(f"counts: {count} is not in 1..{len(draws)} (the draws given)")
        pooled = LadderFeatures.pooled(*draws[:count])
        gaps = rung_gaps(pooled, real, n_perm=n_perm, n_boot=1, n_floor=0, seed=seed)
        location = localise(gaps, alpha=alpha)
        rungs = [n for n, g in gaps.items() if min(g.p_value, g.p_c2st) < alpha]
        out.append(
            {
                "draws": count,
                "sims": len(set(pooled.groups.tolist())),
                "gap_p": location["gap_p"],
                "detected": location["gap_p"] < alpha,
                "rungs": rungs,
                "pixel_or_motion": [n for n in rungs if n in hand_rung_names()],
                "p": {n: [g.p_value, g.p_c2st] for n, g in gaps.items()},
            }
        )
    return out


def nominal_draws(
    inputs: DiagnosisInputs, count: int, *, n_jobs: int = 1, progress: bool = False
) -> list[LadderFeatures]:
    """The first ``count`` nominal draws of a stored diagnosis (S, S', ...), built or cached."""
    context = report_context(inputs)
    spec = DatasetSpec.from_json(inputs.nominal_spec)
    jobs = [SetJob(f"draw{d}", draw_spec(spec, d)) for d in range(count)]
    sets, _ = run_jobs(jobs, context, n_jobs, progress, {})
    return [sets[j.label] for j in jobs]


def _study(report: Diagnosis, counts: list[int], n_jobs: int, alpha: float, progress: bool) -> list:
    inputs = report.inputs
    draws = nominal_draws(inputs, max(counts), n_jobs=n_jobs, progress=progress)
    real_features = report_real_features(inputs)
    n_perm = inputs.budget_settings["n_perm"]
    seed = inputs.seed
    return pooled_detection(draws, real_features, counts, alpha=alpha, n_perm=n_perm, seed=seed)


def _truth(answers: Path | None, name: str) -> str:
    if answers is None:
        return ""
    path = answers / f"{name}.json"
    if not path.is_file():
        return "?"
    answer = json.loads(path.read_text())
    return ", ".join(f"{e['name']}={e['strength']}" for e in answer["effects"])


def _table(rows: list[dict]) -> str:
    counts = [c["sims"] for c in rows[0]["by_count"]] if rows else []
    head = "| set | withheld | " + " | ".join(f"p, {c} sims" for c in counts)
    head += f" | rungs at {counts[-1] if counts else ''} sims |"
    lines = [head, "|" + "---|" * (3 + len(counts))]
    for row in rows:
        cells = [f"{c['gap_p']:.4f}" for c in row["by_count"]]
        rungs = ", ".join(row["by_count"][-1]["rungs"]) or "none"
        lines.append(f"| {row['set']} | {row['truth']} | " + " | ".join(cells) + f" | {rungs} |")
    return "\n".join(lines) + "\n"


@report_user_errors
def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        prog="python -m sim2real.study.power", description=__doc__.split("\n")[0]
    )
    parser.add_argument("reports", nargs="+", help="report.json files of diagnoses")
    parser.add_argument(
        "--draws",
        default="2,4,6",
        help="nominal draws pooled, comma-separated (2 = S and S', as diagnosed)",
    )
    parser.add_argument("--answers", help="a validation's answers/ folder (labels the rows)")
    parser.add_argument("--alpha", type=float, default=0.05)
    parser.add_argument("--n-jobs", type=int, default=1)
    parser.add_argument("--out", default="outputs/sim2real/power")
    args = parser.parse_args(argv)
    draws_help = f"--draws must be comma-separated integers >= 1, e.g. 2,4,6; got {args.draws!r}"
    try:
        counts = sorted({int(v) for v in args.draws.split(",")})
    except ValueError:
        raise InputError(draws_help) from None
    if counts[0] < 1:
        raise InputError(draws_help)
    if not 0 < args.alpha < 1:
        raise InputError(f"--alpha must be in (0, 1), got {args.alpha}")
    check_int(args.n_jobs, "--n-jobs", 1)
    reports = [read_report(path, "reports") for path in args.reports]
    out = check_output_dir(args.out, "--out")
    from simulator.threads import use_process_threads

    use_process_threads(1)
    answers = Path(args.answers) if args.answers else None
    rows = []
    for path, report in zip(args.reports, reports, strict=True):
        name = Path(path).parent.name
        by_count = _study(report, counts, args.n_jobs, args.alpha, progress=True)
        rows.append({"set": name, "truth": _truth(answers, name), "by_count": by_count})
        print(
            f"{name}: " + ", ".join(f"{c['sims']} sims p {c['gap_p']:.4f}" for c in by_count),
            flush=True,
        )
    summary = {"alpha": args.alpha, "draws": counts, "rows": rows}
    for name, text in (("power.json", json.dumps(summary, indent=1)), ("power.md", _table(rows))):
        atomic_write_bytes(out / name, text.encode())
    print(
        json.dumps(
            {
                "sets": len(rows),
                "draws": counts,
                "detected": {
                    str(c): int(sum(r["by_count"][i]["detected"] for r in rows))
                    for i, c in enumerate(counts)
                },
            }
        )
    )


if __name__ == "__main__":
    main()
