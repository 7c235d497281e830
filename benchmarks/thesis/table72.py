"""Regenerate the Table 7.2-style comparison (baselines, CNN+LSTM variants) from run folders.

``python -m benchmarks.thesis.table72`` reads
``logs/train/<dataset>[-seq]-<method>/eval/sim_test.json`` of the wind and arm datasets (the
runs of ``python train.py -m experiment=train/<method> dataset=wind,arm``; ``-seq``: the
thesis's sub-sequence split, ``protocol=sequence``), copies each into the results ledger
``reports/runs/<run name>.json`` (committed: run folders are not, so a fresh checkout rebuilds
the same table from the ledger) and writes ``docs/results/table72.md`` (``--out``); with
``--readme FILE`` it also replaces the block between ``<!-- table72:start -->`` and
``<!-- table72:end -->`` in that file (never by default). Missing runs show as "-"; the
thesis's numbers for the same mesh level (Unif-k / Randk) stand beside ours.
``--level 1,3`` gives a row per mesh level, ``--arm-preset small,full`` a row per preset,
``--texture random,grid`` a row per texture; a setting without any run is listed under the
table instead of as an empty row.
``--scenes wind,arm,armstrokes`` adds datasets generated with another scene of the same motion
(the folder-name prefix of their ``out_dir``; the thesis's numbers of the motion it starts
with stand beside them). Runs of a training variant
(``logs/train/<dataset>[-seq]-<variant tag>-<method>``, :data:`VARIANTS`) get rows of their own.
"""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

from models.report import markdown_table, write_json, write_text

__all__ = ["METHODS", "THESIS_TABLE_72", "collect", "ledger_record", "main", "render_table"]

METHODS = {
    "base1": "Base-1 (RGB-I)",
    "base2": "Base-2 (RGB-V)",
    "cnn_lstm": "CNN+LSTM (RGB-V)",
    "cnn_lstm_ft": "CNN+LSTM from Base-1's CNN",
    "cnn_lstm_diff": "CNN+LSTM on frame differences (Diff-V)",
    "cnn_lstm_2s": "two-stream CNN+LSTM, frames + differences",
}
"""Our methods (run-name suffix -> column). ``cnn_lstm_ft`` is the thesis's recipe (a CNN
trained beforehand, fine-tuned with the LSTM) with baseline 1 in place of ImageNet weights;
``cnn_lstm_diff`` is our fourth method, the same network reading frame differences;
``cnn_lstm_2s`` our fifth, both streams (frames and differences) into one LSTM."""
THESIS_METHODS = ("base1", "base2", "cnn_lstm")
THESIS_TABLE_72 = {
    ("arm", 1): (54.0, 56.8, 62.9),
    ("arm", 2): (51.9, 57.0, 62.7),
    ("arm", 3): (53.6, 56.9, 71.8),
    ("wind", 1): (53.6, 53.3, 64.7),
    ("wind", 2): (58.9, 57.0, 64.5),
    ("wind", 3): (56.9, 53.0, 66.7),
}
"""Thesis Table 7.2 top-1 % (Base-1, Base-2, CNN+LSTM), uniform remeshing level 1-3, Rand."""
START, END = "<!-- table72:start -->", "<!-- table72:end -->"
PROTOCOLS = {"simulation": ("", "held-out sims"), "sequence": ("-seq", "thesis sub-seq.")}
"""Split protocol -> (run-name tag, table label); see ``datasets.manifest.SPLIT_PROTOCOLS``."""
VARIANTS = {
    "": "as rendered",
    "-bgswap": "background swap",
    "-bgswap-stage2": "background swap, 2nd stage",
    "-texswap": "texture + background swap",
}
"""Training variant run-name tag (``configs/variant/``) -> table label."""


def thesis_motion(scene: str) -> str:
    """The thesis motion (``wind`` or ``arm``) a scene's dataset prefix starts with."""
    for motion in ("wind", "arm"):
        if scene.startswith(motion):
            return motion
    raise ValueError(f"--scenes entries must start with wind or arm, got {scene!r}")


def dataset_name(motion: str, level: int, texture: str, preset: str, seed: int) -> str:
    """The folder name ``datasets.generate`` (and ``configs/dataset``) give a dataset."""
    return f"{motion}-L{level}-{texture}-{preset}-s{seed}"


LEDGER_DROP = ("confusion",)
"""Keys of ``sim_test.json`` the ledger leaves out (the confusion matrix stays in the run's
PNG and JSON; the ledger keeps what tables and notes quote)."""


def ledger_record(result: dict, run_name: str) -> dict:
    """The ledger's copy of one run's ``sim_test.json``: every figure but the confusion matrix."""
    record = {k: v for k, v in result.items() if k not in LEDGER_DROP}
    record["run"] = run_name
    return record


def collect(log_dir: Path, name: str, ledger: Path | None = None) -> dict[str, dict]:
    """``method -> result`` of the runs of dataset ``name``.

    A run folder's ``eval/sim_test.json`` wins and refreshes its ledger entry
    (``<ledger>/<run name>.json``); a run whose folder is gone is read from the ledger.
    """
    found = {}
    for method in METHODS:
        run = f"{name}-{method}"
        path = log_dir / "train" / run / "eval" / "sim_test.json"
        entry = None if ledger is None else ledger / f"{run}.json"
        if path.is_file():
            found[method] = ledger_record(json.loads(path.read_text()), run)
            if entry is not None:
                write_json(entry, found[method])
        elif entry is not None and entry.is_file():
            found[method] = json.loads(entry.read_text())
    return found


def _cell(result: dict | None) -> str:
    if result is None:
        return "-"
    return f"{100 * result['acc']:.1f} ({100 * result['top5']:.0f})"


def render_table(
    log_dir: Path,
    *,
    ledger: Path | None = None,
    levels: list[int],
    textures: list[str],
    presets: dict[str, list[str]],
    seed: int,
) -> str:
    """Markdown: a row per motion, texture, preset and split that has runs.

    Ours as top-1 (top-5), then the thesis's for the same motion and mesh level, on every
    texture: its uniform-remeshing rows are random texture only, and they are the targets our
    rows of any texture are held to. Settings without runs are listed for the first level and
    the thesis's two scenes only (extra scenes are experiments, not gaps).
    """
    rows = []
    notes = set()
    budgets: list[str] = []
    missing: list[str] = []
    settings = [
        (lv, m, t, p)
        for lv in levels
        for m, names in presets.items()
        for t in textures
        for p in names
    ]
    for level, motion, texture, preset in settings:
        mesh = f"L{level} " if len(levels) > 1 else ""
        thesis = THESIS_TABLE_72.get((thesis_motion(motion), level), (None, None, None))
        theirs = ["-" if t is None else f"{t:.1f}" for t in thesis]
        for (split_tag, label), (variant_tag, variant) in (
            (p, v) for p in PROTOCOLS.values() for v in VARIANTS.items()
        ):
            tag = split_tag + variant_tag
            name = dataset_name(motion, level, texture, preset, seed)
            results = collect(log_dir, name + tag, ledger)
            if not results:
                if not variant_tag and level == levels[0] and motion == thesis_motion(motion):
                    missing.append(f"{mesh}{motion} {texture} {preset} {label}")
                continue
            ours = [_cell(results.get(m)) for m in METHODS]
            clips = next(r["clips"] for r in results.values())
            rows.append(
                [motion, f"Unif-{level}", texture, preset, label, variant, clips, *ours, *theirs]
            )
            for method, result in results.items():
                if result.get("device"):
                    notes.add(f"{result['device']}")
                if "epochs" in result:
                    minutes = result.get("train_minutes", 0.0)
                    setting = f"{mesh}{motion} {texture} {preset}{tag}"
                    budgets.append(
                        f"{setting} {method} {result['epochs']} epochs / {minutes:.0f} min"
                    )
    header = [
        "motion",
        "mesh",
        "texture",
        "preset",
        "split",
        "training",
        "test clips",
        *[f"ours {v}" for v in METHODS.values()],
        *[f"thesis {METHODS[m]}" for m in THESIS_METHODS],
    ]
    text = markdown_table(header, rows)
    text += (
        "\nOurs: top-1 % over 54 classes on the test clips (top-5 % in brackets; chance is "
        "1.9 % and 9.3 %). Split *held-out sims*: no test clip's simulation (cloth, texture, "
        "background, wind) was seen in training; *thesis sub-seq.*: the thesis's protocol "
        "(7.7.1), each class's clips dealt to the splits regardless of simulation, so test "
        "clips are other moments of training simulations. Training *background swap*: every "
        "training clip re-composited over a new background (`variant=bgswap`); *2nd stage*: "
        "a further run started from that run's best weights (`init_from`, lower learning "
        "rate); *texture + background swap*: also re-textured with a new print "
        "(`variant=texswap`, a dataset with `render.store_passes=true`). Thesis: "
        "Table 7.2, same motion, "
        "uniform remeshing at the row's level, beside every texture of ours although the "
        "thesis rendered these rows with random textures only (it has no grid-texture row; "
        "its 66.7 / 71.8 % targets are the Unif-3 rows)."
    )
    if missing:
        text += " No runs yet: " + "; ".join(missing).rstrip(".") + "."
    if notes:
        text += " Trained on: " + "; ".join(sorted(notes)) + "."
    if budgets:
        text += " Training: " + ", ".join(budgets) + "."
    return text + "\n"


def update_readme(readme: Path, table: str) -> None:
    """Replace the text between the table72 markers of ``readme``."""
    text = readme.read_text()
    if START not in text or END not in text:
        raise ValueError(f"{readme} has no {START} ... {END} block to replace")
    pattern = re.compile(re.escape(START) + ".*?" + re.escape(END), re.S)
    write_text(readme, pattern.sub(lambda _: f"{START}\n{table}{END}", text))


def main(argv: list[str] | None = None) -> str:
    """Write the table to ``--out`` (and the ``--readme`` block when asked); returns it."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--log-dir", type=Path, default=Path("logs"))
    parser.add_argument(
        "--ledger",
        type=Path,
        default=Path("reports/runs"),
        help="committed copies of the runs' results (read when a run folder is gone)",
    )
    parser.add_argument("--level", default="1", help="mesh level(s) 1-3, a,b")
    parser.add_argument("--texture", default="random", help="texture(s), a,b")
    parser.add_argument("--preset", default="full", help="preset(s) of both motions, a,b")
    parser.add_argument("--wind-preset", default=None, help="overrides --preset for wind")
    parser.add_argument("--arm-preset", default=None, help="overrides --preset for arm")
    parser.add_argument(
        "--scenes",
        default="wind,arm",
        help="dataset prefixes, a,b (e.g. armstrokes: arm data generated with scenario.strokes)",
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("docs/results/table72.md"))
    parser.add_argument(
        "--readme",
        type=Path,
        default=None,
        help="also replace the table72 block of this Markdown file (e.g. README.md)",
    )
    args = parser.parse_args(argv)
    motion_presets = {
        "wind": (args.wind_preset or args.preset).split(","),
        "arm": (args.arm_preset or args.preset).split(","),
    }
    try:
        presets = {s: motion_presets[thesis_motion(s)] for s in args.scenes.split(",")}
    except ValueError as err:
        parser.error(str(err))
    levels = args.level.split(",")
    if any(v not in ("1", "2", "3") for v in levels):
        parser.error(f"--level entries must be mesh levels 1, 2 or 3, got {args.level!r}")
    table = render_table(
        args.log_dir,
        ledger=args.ledger,
        levels=[int(v) for v in levels],
        textures=args.texture.split(","),
        presets=presets,
        seed=args.seed,
    )
    write_text(
        args.out, "# Table 7.2 (style): material classification on simulated clips\n\n" + table
    )
    if args.readme is not None:
        update_readme(args.readme, table)
    print(table)
    return table


if __name__ == "__main__":
    main()
