"""Training runs as inputs: a run folder's checkpoint and the spec of its training data.

Commands that take a trained model (material cloning, the sim-to-real diagnosis) accept a
run folder (``logs/train/<run>``) or a checkpoint file, and find the dataset the run was
trained on through the run's saved Hydra config; the dataset's ``spec.json`` says how its
clips were made (clip length, frame rate, frame size, scene), which the command must repeat.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from omegaconf import OmegaConf

from common.errors import InputError

from .manifest import read_json
from .spec import DatasetSpec

__all__ = ["RUN_HELP", "TrainedRun", "dataset_spec", "find_run"]

RUN_HELP = "a training run folder (logs/train/<run>) or a checkpoint file"


@dataclasses.dataclass(frozen=True)
class TrainedRun:
    """A training run's checkpoint and the spec of the dataset it was trained on."""

    checkpoint: Path
    data_dir: Path
    spec: DatasetSpec
    """The training data's spec: clip length, fps and frame size the classifier expects."""


def find_run(run: str | Path, data_dir: str | Path | None = None) -> TrainedRun:
    """The checkpoint of a training run and the spec of its training data.

    Args:
        run: A run folder (``checkpoints/best.ckpt``, else ``checkpoints/last.ckpt``, and
            ``.hydra/config.yaml``) or a checkpoint file (its run folder is two levels up).
        data_dir: The training dataset folder (holds ``spec.json``); default: the run
            config's ``data.data_dirs[0]``.

    Raises:
        InputError: naming ``run`` or ``data_dir`` and what is missing.
    """
    if not isinstance(run, str | Path) or not str(run).strip():
        raise InputError(f"run must be {RUN_HELP}, got {run!r}")
    path = Path(run)
    if path.is_file():
        checkpoint, folder = path, path.parent.parent
    elif path.is_dir():
        folder = path
        found = [path / "checkpoints" / name for name in ("best.ckpt", "last.ckpt")]
        checkpoint = next((p for p in found if p.is_file()), None)
        if checkpoint is None:
            raise InputError(
                f"run: {path} has no checkpoints/best.ckpt or checkpoints/last.ckpt; give "
                f"{RUN_HELP}"
            )
    else:
        raise InputError(f"run: {path} does not exist; give {RUN_HELP}")
    if data_dir is None:
        config = folder / ".hydra" / "config.yaml"
        if not config.is_file():
            raise InputError(
                f"run: {folder} has no .hydra/config.yaml (the training config that names its "
                "dataset); pass data_dir=<the training dataset folder>"
            )
        try:
            dirs = OmegaConf.to_container(OmegaConf.load(config).data.data_dirs, resolve=True)
            data_dir = dirs[0]
        except Exception as err:  # any config problem gets the same advice
            raise InputError(
                f"run: cannot read data.data_dirs from {config} ({' '.join(str(err).split())}); "
                "pass data_dir=<the training dataset folder>"
            ) from None
    elif not isinstance(data_dir, str | Path) or not str(data_dir).strip():
        raise InputError(f"data_dir must be a dataset folder or null, got {data_dir!r}")
    return TrainedRun(checkpoint=checkpoint, data_dir=Path(data_dir), spec=dataset_spec(data_dir))


def dataset_spec(data_dir: str | Path) -> DatasetSpec:
    """The spec a dataset folder was generated from (its ``spec.json``).

    An InputError names the file when there is none or it does not hold a spec.
    """
    spec_path = Path(data_dir) / "spec.json"
    if not spec_path.is_file():
        raise InputError(
            f"data_dir: {spec_path} not found (the spec of the run's training dataset, written "
            "by datasets.generate); pass data_dir=<the training dataset folder>"
        )
    try:
        return DatasetSpec.from_json(read_json(spec_path)["spec"])
    except Exception as err:  # unreadable JSON, a missing key, a bad field: not a spec
        raise InputError(f"data_dir: {spec_path} is not a dataset spec ({err})") from None
