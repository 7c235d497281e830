"""How much of each measured column a real set's footage carries, rung by rung.

A model trained on simulations cannot read from real footage more than the footage carries
where the model looks. On a diagnosed real set this fits, on the real clips themselves, a
ridge regression from each rung's features (the hand-made rungs and the trained network's
layers, as the diagnosis measured them) to each measured column, in log, holding out one
fabric (every video of it) at a time, and gives the Pearson r between the held-out
predictions (a video's clips averaged) and the measured values, pooled over the videos, with
a 95 % bootstrap interval over fabrics. Both are taken relative to the training fold's mean
value (a probe that learns nothing predicts that mean, which moves against the held-out
value). Held-out probes on features that carry nothing still read negative r (the fitted
direction turns against the held-out fabric), so r is compared with its null: the same probe
with the values shuffled between fabrics (each fabric's videos kept together); ``p`` is the
share of shuffles that read at least r. Fitted with R's own labels, it is an optimistic
ceiling for a sim-trained model reading that rung, and a pessimistic measure of what the
footage carries (a linear probe on fixed features). The ridge strength is chosen inside each
training fold by generalised cross-validation.

With ``--state-columns`` (``labels.csv`` columns of the cloth's measured motion, such as the
independent engine's ``vertex_speed,out_of_plane_rms,edge_strain_rms`` and the ``wind``), the
same probe also reads each column from that motion itself (rung ``state``: positive numbers
in log, words one-hot, every number also per word, so each wind gets its own slope). That is
the ceiling of any model that sees only the motion, whatever its camera.

With ``--sim-readout`` it also asks what a reader trained on simulations transfers: per rung,
a ridge fitted on the diagnosis's nominal simulated clips S (and on the calibrated S*, when the
joint calibration chose one) from the features to their own ``stiffness`` (bend multiplier)
and ``density``, applied unchanged to R, and its pooled Pearson r with R's measured column.
Between that and the ceiling lies what R's own labels add; between it and the model's score,
what the model's head loses.

Usage: ``python -m benchmarks.footage_ceiling --report outputs/sim2real/<name>
[--columns stiffness,density] [--group COLUMN] [--state-columns A,B,...] [--sim-readout]
[--out ceiling.json]``. Prints a table and, as the last line, the JSON.
"""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from common.commands import report_user_errors
from common.errors import InputError
from common.files import atomic_write_bytes
from common.paths import check_output_file

__all__ = ["ceiling", "main", "probe_r", "sim_readout", "state_features"]

ALPHAS = np.logspace(-3, 4, 15)
"""Ridge strengths tried by generalised cross-validation (features standardised)."""


def _ridge_gcv(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, float]:
    """Ridge weights (with intercept) at the GCV-best strength of :data:`ALPHAS`."""
    mean_x, mean_y = x.mean(0), y.mean()
    u, s, vt = np.linalg.svd(x - mean_x, full_matrices=False)
    uy = u.T @ (y - mean_y)
    n = len(y)
    best = None
    for alpha in ALPHAS:
        shrink = s**2 / (s**2 + alpha)
        fitted = u @ (shrink * uy)
        residual = (y - mean_y) - fitted
        gcv = (residual @ residual / n) / (1 - shrink.sum() / n) ** 2
        if best is None or gcv < best[0]:
            best = (gcv, alpha)
    alpha = best[1]
    w = vt.T @ (s / (s**2 + alpha) * uy)
    return w, mean_y - mean_x @ w


def probe_r(
    x: np.ndarray,
    clip_video: np.ndarray,
    video_value: dict[str, float],
    video_group: dict[str, str],
    *,
    n_boot: int = 1000,
    n_null: int = 50,
    seed: int = 0,
) -> dict:
    """Held-out-group Pearson r of a ridge probe from clip features ``x`` to a video value.

    ``clip_video``: each clip's video; ``video_value``: the (log) value of each video;
    ``video_group``: its fabric. Returns ``r``, its bootstrap interval over groups, its null
    (``n_null`` shuffles of the values between groups: median, 95th percentile and ``p``) and
    the per-video predictions.
    """
    found = _held_out(x, clip_video, video_value, video_group, n_boot=n_boot, seed=seed)
    rng = np.random.default_rng([seed, 1])
    groups = sorted({video_group[v] for v in video_value})
    by_group = {g: sorted(v for v in video_value if video_group[v] == g) for g in groups}
    null = []
    for _ in range(n_null):
        order = rng.permutation(len(groups))
        shuffled = {}
        for g, source in zip(groups, order, strict=True):
            donor = by_group[groups[source]]
            for i, v in enumerate(by_group[g]):
                shuffled[v] = video_value[donor[i % len(donor)]]
        null.append(_held_out(x, clip_video, shuffled, video_group, n_boot=0)["r"])
    null = np.array([r for r in null if math.isfinite(r)])
    found["null_median"] = float(np.median(null)) if len(null) else math.nan
    found["null_p95"] = float(np.quantile(null, 0.95)) if len(null) else math.nan
    found["p"] = float((1 + np.sum(null >= found["r"])) / (1 + len(null)))
    return found


def _group_interval(pearson, videos, video_group, n_boot: int, seed: int) -> list[float] | None:
    """95 % interval of ``pearson(videos)`` over ``n_boot`` resamplings of whole groups."""
    groups = sorted({video_group[v] for v in videos})
    by_group = {g: [v for v in videos if video_group[v] == g] for g in groups}
    rng = np.random.default_rng(seed)
    boot = []
    for _ in range(n_boot):
        drawn = rng.choice(len(groups), len(groups))
        boot.append(pearson([v for i in drawn for v in by_group[groups[i]]]))
    boot = np.array(boot)
    boot = boot[np.isfinite(boot)]
    return [float(np.quantile(boot, 0.025)), float(np.quantile(boot, 0.975))] if len(boot) else None


def _held_out(x, clip_video, video_value, video_group, *, n_boot: int, seed: int = 0) -> dict:
    """The probe's held-out r (and its bootstrap interval when ``n_boot``)."""
    videos = sorted(set(clip_video.tolist()) & set(video_value))
    keep = np.isin(clip_video, videos)
    x, clip_video = x[keep], clip_video[keep]
    scale = x.std(0)
    x = (x - x.mean(0)) / np.where(scale > 0, scale, 1.0)
    y_clip = np.array([video_value[v] for v in clip_video])
    clip_group = np.array([video_group[v] for v in clip_video])
    predicted = np.empty(len(clip_video))
    centre = np.empty(len(clip_video))
    for group in sorted(set(clip_group.tolist())):
        out = clip_group == group
        w, b = _ridge_gcv(x[~out], y_clip[~out])
        predicted[out] = x[out] @ w + b
        centre[out] = y_clip[~out].mean()
    pred = {v: float(predicted[clip_video == v].mean()) for v in videos}
    fold_mean = {v: float(centre[clip_video == v][0]) for v in videos}

    def pearson(vs):
        a = np.array([pred[v] - fold_mean[v] for v in vs])
        b = np.array([video_value[v] - fold_mean[v] for v in vs])
        if a.std() == 0 or b.std() == 0:
            return math.nan
        return float(np.corrcoef(a, b)[0, 1])

    interval = _group_interval(pearson, videos, video_group, n_boot, seed)
    return {"r": pearson(videos), "r_ci": interval, "videos": len(videos), "predicted": pred}


SIM_LABELS = ("stiffness", "density")
"""The measured columns a simulated set labels its clips with (LadderFeatures' labels)."""


def sim_readout(
    x_sim: np.ndarray,
    y_sim: np.ndarray,
    x_real: np.ndarray,
    clip_video: np.ndarray,
    video_value: dict[str, float],
    video_group: dict[str, str],
    *,
    n_boot: int = 1000,
    seed: int = 0,
) -> dict:
    """Pooled r on R of a ridge fitted on simulated clips (``x_sim`` to ``y_sim``).

    ``y_sim`` and ``video_value`` on the same scale (the log of the measured value).

    The features are standardised with the simulated clips' statistics and the fit applied to
    R unchanged; a video's prediction is its clips' mean. Interval: bootstrap over groups.
    Where the simulated clips all share one value there is nothing to fit: ``varied`` False.
    """
    videos = sorted(set(clip_video.tolist()) & set(video_value))
    if np.ptp(y_sim) < 1e-9:  # e.g. density: the simulated classes share the basis fabric's
        return {"r": math.nan, "r_ci": None, "videos": len(videos), "varied": False}
    mean, scale = x_sim.mean(0), x_sim.std(0)
    scale = np.where(scale > 0, scale, 1.0)
    w, b = _ridge_gcv((x_sim - mean) / scale, y_sim)
    predicted = ((x_real - mean) / scale) @ w + b
    pred = {v: float(predicted[clip_video == v].mean()) for v in videos}

    def pearson(vs):
        a = np.array([pred[v] for v in vs])
        c = np.array([video_value[v] for v in vs])
        if a.std() == 0 or c.std() == 0:
            return math.nan
        return float(np.corrcoef(a, c)[0, 1])

    return {
        "r": pearson(videos),
        "r_ci": _group_interval(pearson, videos, video_group, n_boot, seed),
        "videos": len(videos),
        "varied": True,
    }


def _sim_sets(result) -> dict:
    """The diagnosis's S and, when calibrated, S*, from its feature cache."""
    from sim2real.diagnosis.joint import assignment
    from sim2real.reopen import reopen

    try:
        reopened = reopen(result)
    except ValueError as err:
        raise InputError(f"--sim-readout: {err}") from None
    named = {"S": ()}
    if result.joint is not None and result.joint.strengths:
        named["S*"] = assignment(result.joint.strengths)
    built = reopened.features(list(named.values()))
    return dict(zip(named, built, strict=True))


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def state_features(rows: list[dict[str, str]], columns: list[str]) -> dict[str, np.ndarray]:
    """Each video's features from measured motion columns (module docstring: rung ``state``).

    ``rows``: ``labels.csv`` rows as ``{column: text}``; a column whose every value is a
    positive number enters in log, one of other numbers as is, one of words as one-hot; every
    number is also multiplied by every one-hot column.
    """
    numbers, words = [], []
    for column in columns:
        texts = [row[column] for row in rows]
        try:
            values = np.array([float(t) for t in texts])
        except ValueError:
            numeric = [t for t in texts if _is_number(t)]
            if numeric:  # a number column with a blank or a word: refuse, do not one-hot it
                bad = next(t for t in texts if not _is_number(t))
                raise InputError(
                    f"--state-columns: {column} mixes numbers ({numeric[0]!r}) and other "
                    f"values ({bad!r}); give a column of numbers or a column of words"
                ) from None
            levels = sorted(set(texts))
            words += [np.array([t == level for t in texts], float) for level in levels]
            continue
        if not np.isfinite(values).all():
            raise InputError(f"--state-columns: {column} holds a value that is not finite")
        numbers.append(np.log(values) if (values > 0).all() else values)
    parts = numbers + words + [n * w for n in numbers for w in words]
    if not parts:
        raise InputError("--state-columns: give at least one labels.csv column")
    x = np.column_stack(parts)
    return {row["video"]: x[i] for i, row in enumerate(rows)}


def ceiling(
    report_dir: Path,
    columns: list[str],
    group: str | None,
    state_columns: Sequence[str] = (),
    *,
    sim: bool = False,
) -> dict:
    """Every rung's probe r for every column on a diagnosed real set (module docstring)."""
    from datasets.real_video import fabric_groups, read_labels
    from sim2real.reopen import report_real_features
    from sim2real.report import read_report

    result = read_report(report_dir, "--report")
    real_dir = Path(result.inputs.real_dir)
    from datasets.real_video import RESERVED_KEYS

    measured = [c for c in state_columns if c not in columns and c not in RESERVED_KEYS]
    rows = read_labels(real_dir, [*columns, *measured])
    lacking = sorted({c for c in state_columns if c not in rows[0].fields})
    if lacking:  # a reserved column (the wind) that read_labels does not ask for
        raise InputError(
            f"--state-columns: {real_dir / 'labels.csv'} lacks {lacking}; it has "
            f"{sorted(rows[0].fields)}"
        )
    header = list(rows[0].fields)
    labels, _, rule = fabric_groups(rows, header, group, real_dir / "labels.csv")
    video_group = {row.fields["video"]: g for row, g in zip(rows, labels, strict=True)}
    features = report_real_features(result.inputs)
    clip_video = np.asarray(features.groups).astype(str)
    rungs = dict(features.rungs)
    if state_columns:
        state = state_features([row.fields for row in rows], list(state_columns))
        rungs["state"] = np.stack([state[v] for v in clip_video])
    out = {"report": str(report_dir), "group": rule, "columns": {}}
    sim_sets = _sim_sets(result) if sim and set(columns) & set(SIM_LABELS) else {}
    for column in columns:
        values = {}
        for row in rows:
            try:
                value = float(row.fields[column])
            except ValueError:
                value = math.nan
            if not value > 0:
                raise InputError(
                    f"--columns: {column} of video {row.fields['video']!r} must be a positive "
                    f"number for a log probe, got {row.fields[column]!r}"
                )
            values[row.fields["video"]] = math.log(value)
        out["columns"][column] = {
            rung: probe_r(x, clip_video, values, video_group) for rung, x in rungs.items()
        }
        if sim_sets and column in SIM_LABELS:
            out.setdefault("sim_readout", {})[column] = {
                name: {
                    rung: sim_readout(
                        s.rungs[rung],
                        np.log(getattr(s, column)),
                        x,
                        clip_video,
                        values,
                        video_group,
                    )
                    for rung, x in features.rungs.items()
                }
                for name, s in sim_sets.items()
            }
    return out


def _table(out: dict) -> str:
    columns = list(out["columns"])
    rungs = list(next(iter(out["columns"].values())))
    lines = [
        "| rung | " + " | ".join(f"{c}: r [95 % CI], null p95, p" for c in columns) + " |",
        "|---|" + "---|" * len(columns),
    ]
    for rung in rungs:
        cells = []
        for column in columns:
            entry = out["columns"][column][rung]
            low, high = entry["r_ci"]
            cells.append(
                f"{entry['r']:.2f} [{low:.2f}, {high:.2f}], {entry['null_p95']:.2f}, "
                f"{entry['p']:.2f}"
            )
        lines.append(f"| {rung} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _sim_table(readout: dict) -> str:
    """Rows (column, simulated set), a column per rung: the readout's r on R [95 % CI]."""
    first = next(iter(next(iter(readout.values())).values()))
    rungs = list(first)
    lines = [
        "| fitted on simulated | " + " | ".join(rungs) + " |",
        "|---|" + "---|" * len(rungs),
    ]
    for column, by_set in readout.items():
        for name, entries in by_set.items():
            cells = []
            for rung in rungs:
                entry = entries[rung]
                if not entry["varied"]:
                    cells.append("not varied in the simulations")
                    continue
                low, high = entry["r_ci"] or (math.nan, math.nan)
                cells.append(f"{entry['r']:.2f} [{low:.2f}, {high:.2f}]")
            lines.append(f"| {column} on {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


@report_user_errors
def main(argv: list[str] | None = None) -> dict:
    """Command line (see the module docstring)."""
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks.footage_ceiling", description=__doc__.split("\n")[0]
    )
    parser.add_argument("--report", required=True, help="a diagnosis's report folder")
    parser.add_argument("--columns", default="stiffness,density", help="measured columns")
    parser.add_argument(
        "--group",
        help="the column that names a fabric (default: fabric if present, else identical rows)",
    )
    parser.add_argument(
        "--state-columns",
        default="",
        help="labels.csv columns of the measured motion (and the wind): adds the rung state",
    )
    parser.add_argument(
        "--sim-readout",
        action="store_true",
        help="also fit each rung's probe on the simulated S (and S*) and read R with it",
    )
    parser.add_argument("--out", help="also write the JSON here")
    args = parser.parse_args(argv)
    if args.out:
        check_output_file(args.out, "--out")
    columns = [c.strip() for c in args.columns.split(",") if c.strip()]
    if not columns:
        raise InputError("--columns: give at least one measured column")
    state_columns = [c.strip() for c in args.state_columns.split(",") if c.strip()]
    out = ceiling(Path(args.report), columns, args.group, state_columns, sim=args.sim_readout)
    print(_table(out))
    if out.get("sim_readout"):
        print()
        print(_sim_table(out["sim_readout"]))
    for column in out["columns"].values():
        for entry in column.values():
            entry.pop("predicted")
    if args.out:
        atomic_write_bytes(Path(args.out), (json.dumps(out, indent=2) + "\n").encode())
    print(json.dumps(out, sort_keys=True))
    return out


if __name__ == "__main__":
    main()
