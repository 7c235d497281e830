"""Time of one sim-to-real diagnosis at ``budget=quick`` on a 90-video real set at Unif-1.

``python -m benchmarks.diagnose_bench [--videos 90] [--jobs 2] [--kind multi] [--run RUN
[--data-dir DATA]] [--work DIR]
[--budget-set KEY=VALUE ...]``

1. Builds the training data's spec exactly as ``python -m datasets.generate preset=full
   level=1`` would (only its ``spec.json`` is needed: the diagnosis never reads the shards).
2. Seals a pseudo-real set of ``--videos`` videos (``sim2real.study.seal``; its time is reported
   apart: it stands in for footage the user already has). ``--kind multi`` seals several
   simultaneous effects, so the time includes the joint calibration of a multi-effect gap
   (the case the 30-minute target is set for); by default the kind is drawn from the seed.
3. Runs the diagnosis with every candidate of the library on a fresh cache and reports its
   minutes split into reading the real set, generating the simulated sets (and, of the
   candidate sets' generation, the simulation and the rendering with its image effects),
   features and fitting, then runs it again to show what the cache saves.

Without ``--run`` the network is the thesis CNN+LSTM with random weights (its layers cost the
same; its verdicts mean less). The last line is JSON with ``diagnose_minutes``,
``candidate_sets``, ``clips_generated``, the split, ``rerun_minutes`` and the verdict.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import tempfile
import time
from pathlib import Path

from simulator.threads import use_process_threads

from .datagen_bench import _spec


def _random_run(folder: Path) -> Path:
    import torch
    from hydra.utils import instantiate

    from models.material_classifier import MaterialClassifierModule
    from simulator.cloth.material import CLASS_COUNT

    config = {
        "_target_": "models.components.video_nets.CNNLSTMNet",
        "encoder": {"_target_": "models.components.frame_encoder.FrameEncoder", "name": "alexnet5"},
        "num_classes": CLASS_COUNT,
    }
    torch.manual_seed(0)
    module = MaterialClassifierModule(instantiate(config), net_config=config)
    path = folder / "run" / "checkpoints" / "best.ckpt"
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.save(
        {"hyper_parameters": {"net_config": config}, "state_dict": module.state_dict()}, path
    )
    return folder / "run"


def main() -> None:
    """Seal, diagnose (fresh cache), diagnose again (cached); print the figures."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--videos", type=int, default=90)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument(
        "--kind",
        choices=("single", "pair", "open", "multi", "twin"),
        help="what the sealed set withholds (default: drawn from --seed)",
    )
    parser.add_argument("--run", help="a trained run (default: random CNN+LSTM weights)")
    parser.add_argument(
        "--data-dir", help="the run's training data folder (default: the full level-1 spec)"
    )
    parser.add_argument("--work", help="work folder (default: a temporary one)")
    parser.add_argument(
        "--budget-set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="a setting on top of configs/budget/quick.yaml (repeatable), e.g. refine=visual",
    )
    args = parser.parse_args()
    from sim2real.study.validate import load_budget

    try:
        budget = load_budget("quick", args.budget_set)
    except ValueError as err:
        parser.error(str(err))
    use_process_threads(1)
    from datasets.manifest import write_json
    from datasets.runs import dataset_spec
    from sim2real.pipeline import DiagnosisRequest, run_diagnosis
    from sim2real.study.seal import seal_set

    with tempfile.TemporaryDirectory() as tmp:
        work = Path(args.work or tmp)
        data = Path(args.data_dir) if args.data_dir else work / "data"
        if args.data_dir:
            spec = dataset_spec(data)
        else:
            spec = _spec(1, "full")
            write_json(data / "spec.json", {"key": spec.key(), "spec": spec.to_json()})
        run = Path(args.run) if args.run else _random_run(work)
        start = time.perf_counter()
        real = work / "real"
        if not (real / "labels.csv").is_file():
            seal_set(
                real, base=spec, seed=args.seed, videos=args.videos, kind=args.kind, overwrite=True
            )
        seal_minutes = (time.perf_counter() - start) / 60
        request = DiagnosisRequest(
            real_dir=real,
            run=run,
            data_dir=data,
            cache_dir=work / "cache",
            mesh_cache=work / "meshes",
            budget=budget,
            candidates="all",
            n_jobs=args.jobs,
        )
        start = time.perf_counter()
        result = run_diagnosis(request, work / "report")
        minutes = (time.perf_counter() - start) / 60
        start = time.perf_counter()
        run_diagnosis(dataclasses.replace(request, progress=False), work / "report-again")
        rerun = (time.perf_counter() - start) / 60
        split = {k: round(v / 60, 2) for k, v in result.timing.items()}
        clips = result.inputs.sim_clips * result.sets["total"]
        print(
            f"seal {seal_minutes:.1f} min; diagnose {minutes:.1f} min (split, worker-minutes "
            f"for generate/features of candidate sets: {split}); rerun {rerun:.2f} min"
        )
        print(
            json.dumps(
                {
                    "diagnose_minutes": round(minutes, 2),
                    "rerun_minutes": round(rerun, 2),
                    "seal_minutes": round(seal_minutes, 2),
                    "candidate_sets": result.sets["total"],
                    "clips_generated": clips,
                    "real_clips": result.inputs.real_clips,
                    "split_minutes": split,
                    "jobs": args.jobs,
                    "kind": args.kind,
                    "seed": args.seed,
                    "budget": request.budget.name,
                    "top": result.ranking.top,
                    "explained": result.ranking.explained,
                }
            )
        )


if __name__ == "__main__":
    main()
