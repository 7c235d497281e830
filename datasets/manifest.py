"""The manifest: every clip with its labels and physical values, every shard with its checksum.

Layout of a dataset directory::

    spec.json            the DatasetSpec (JSON) and its key; written first
    units/unit-0003.json one per finished work unit: its shards (sha256, bytes) and clips
    shards/{split}-unit-0003.tar
    manifest.json        all units merged: spec, material set (the class grid), shards, clips
                         (written when all units exist)
    manifest.csv         one row per clip, for people and pandas

A unit counts as finished only when its index file exists and its shards match their
recorded checksums, so a killed run is resumed by running the same command again.

The manifest's ``material_set`` says what the labels mean (basis fabric, stretch and bend
multipliers, class count): training, evaluation and the models read the classes from it, never
from the simulator. Manifests written before it was recorded lack it; they read as
:data:`~simulator.cloth.material.WANG54`, the 54 classes every such dataset was made of.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import json
from pathlib import Path

import numpy as np

from common.files import atomic_write_bytes
from simulator.cloth.material import WANG54, MaterialError, MaterialSet

from .plan import SimulationPlan
from .shards import ShardError, verify_shard
from .spec import DatasetSpec

__all__ = [
    "MANIFEST_SCHEMA",
    "SPLIT_PROTOCOLS",
    "Manifest",
    "clip_record",
    "legacy_class_grid",
    "read_json",
    "write_json",
]

SPLIT_PROTOCOLS = ("simulation", "sequence")
"""How clips are assigned to train/val/test:

* ``simulation`` (default): as generated - whole simulations are held out, so a test clip's
  cloth, texture, background and wind were never seen in training;
* ``sequence``: the thesis's protocol (7.6.1, 7.7.1: each simulated sequence "is divided into
  sub-sequences" that are split 2,106 / 432): per class, the clips of all simulations are
  pooled and dealt to the splits at random, keeping each class's split sizes. Test clips then
  share simulations (and so texture, background and wind) with training clips; it measures
  recognition within a seen simulation, not generalisation to new ones.
"""

MANIFEST_SCHEMA = 1
CSV_COLUMNS = (
    "key",
    "split",
    "shard",
    "class_id",
    "stretch_index",
    "bend_index",
    "stretch_mult",
    "bend_mult",
    "stretch_stiffness",
    "bend_stiffness",
    "density",
    "motion",
    "wind_level",
    "wind_speed",
    "texture_mode",
    "resolution_level",
    "effects",
    "seed",
    "sim_id",
    "clip_index",
    "start_frame",
    "frame_count",
    "fps",
    "height",
    "width",
    "sha256",
)


def legacy_class_grid() -> dict:
    """The class grid of data and checkpoints that do not record theirs: ``WANG54``'s, as JSON.

    For :mod:`models`, which take the grid as plain numbers (``stretch_multipliers``,
    ``bend_multipliers`` and the counts) and never import the simulator.
    """
    return WANG54.to_json()


def write_json(path: str | Path, payload) -> None:
    """Atomic, deterministic JSON."""
    text = json.dumps(payload, sort_keys=True, indent=1, allow_nan=False)
    atomic_write_bytes(path, (text + "\n").encode())


def read_json(path: str | Path):
    """Read JSON, naming the file when it is unreadable."""
    try:
        return json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError) as err:
        raise ShardError(f"cannot read {path}: {err}") from None


def clip_record(
    spec: DatasetSpec,
    sim: SimulationPlan,
    clip_index: int,
    shard: str,
    frames_shape: tuple[int, ...],
    sha256: str,
    coverage: bool = False,
    passes: bool = False,
) -> dict:
    """Manifest row of one clip (also stored as the clip's ``.json`` inside its shard).

    ``passes`` (render passes and background stored) is written only when true, so rows of
    datasets made before it existed are unchanged.
    """
    summary = spec.material_set.summary(sim.class_id)
    stretch_index, bend_index, density_index = spec.material_set.position(sim.class_id)
    speeds = getattr(spec.scenario, "wind_speeds", None)
    preset = spec.preset
    row = {
        "key": f"{spec.motion}-{sim.sim_id}-k{clip_index:02d}",
        "split": sim.split,
        "shard": shard,
        "class_id": sim.class_id,
        "stretch_index": stretch_index,
        "bend_index": bend_index,
        "stretch_mult": summary["stretch_mult"],
        "bend_mult": summary["bend_mult"],
        "stretch_stiffness": summary["stretch_stiffness"],
        "bend_stiffness": summary["bend_stiffness"],
        "density": summary["density"],
        "motion": spec.motion,
        "wind_level": sim.wind_level if speeds else -1,
        "wind_speed": float(speeds[sim.wind_level]) if speeds else 0.0,
        "texture_mode": spec.texture_mode,
        "resolution_level": spec.scenario.resolution_level,
        "effects": ";".join(spec.enabled_effects()),
        "seed": sim.seed,
        "sim_id": sim.sim_id,
        "clip_index": clip_index,
        "start_frame": spec.clip_start_frame(clip_index),
        "frame_count": int(frames_shape[0]),
        "fps": preset.fps,
        "height": int(frames_shape[1]),
        "width": int(frames_shape[2]),
        "sha256": sha256,
        "coverage": bool(coverage),
    }
    if passes:
        row["passes"] = True
    return row | _density_fields(spec, density_index, summary)


def _density_fields(spec: DatasetSpec, density_index: int, summary: dict) -> dict:
    """A row's density index and multiplier, in sets of several densities only.

    Rows of one-density sets keep the keys they had before density became a class axis.
    """
    if spec.material_set.density_count == 1:
        return {}
    return {"density_index": density_index, "density_mult": summary["density_mult"]}


@dataclasses.dataclass(frozen=True)
class Manifest:
    """A finished dataset: spec, shards (with checksums), clips and its material set."""

    root: Path
    spec: dict
    spec_key: str
    shards: tuple[dict, ...]
    clips: tuple[dict, ...]
    material_set: MaterialSet = WANG54
    """What the class ids mean; ``WANG54`` for manifests that do not record it (see the
    module doc)."""

    @staticmethod
    def path(root: str | Path) -> Path:
        """Where the manifest of the dataset at ``root`` lives."""
        return Path(root) / "manifest.json"

    @classmethod
    def load(cls, root: str | Path) -> Manifest:
        """Read ``root/manifest.json``; a clear error if the directory is not a dataset.

        A manifest without ``material_set`` (written before it was recorded) reads as
        :data:`~simulator.cloth.material.WANG54`.
        """
        root = Path(root)
        if not root.is_dir():
            raise FileNotFoundError(f"dataset directory {root} does not exist")
        path = cls.path(root)
        if not path.is_file():
            raise FileNotFoundError(
                f"{path} not found: {root} is not a finished dataset (run datasets.generate, "
                "which resumes an unfinished one)"
            )
        data = read_json(path)
        if data.get("schema_version") != MANIFEST_SCHEMA:
            raise ShardError(f"{path}: schema_version {data.get('schema_version')} unsupported")
        material_set = WANG54
        if "material_set" in data:
            try:
                material_set = MaterialSet.from_json(data["material_set"], f"{path}: material_set")
            except MaterialError as err:
                raise ShardError(str(err)) from None
        return cls(
            root=root,
            spec=data["spec"],
            spec_key=data["spec_key"],
            shards=tuple(data["shards"]),
            clips=tuple(data["clips"]),
            material_set=material_set,
        )

    def save(self) -> None:
        """Write ``manifest.json`` and ``manifest.csv`` atomically."""
        write_json(
            self.path(self.root),
            {
                "schema_version": MANIFEST_SCHEMA,
                "spec": self.spec,
                "spec_key": self.spec_key,
                "material_set": self.material_set.to_json(),
                "shards": list(self.shards),
                "clips": list(self.clips),
            },
        )
        buffer = io.StringIO()
        writer = csv.DictWriter(buffer, fieldnames=CSV_COLUMNS, lineterminator="\n")
        writer.writeheader()
        for clip in self.clips:
            writer.writerow({k: clip[k] for k in CSV_COLUMNS})
        atomic_write_bytes(self.root / "manifest.csv", buffer.getvalue().encode())

    def shard_path(self, name: str) -> Path:
        """File of shard ``name``."""
        return self.root / "shards" / name

    def verify(self, split: str | None = None, *, names: set[str] | None = None) -> None:
        """Check the size and checksum of the shards of ``split`` (all for ``None``).

        ``names`` restricts the check further to those shard files. Raises
        :class:`ShardError` naming the first bad shard.
        """
        for shard in self.shards:
            if split is not None and shard["split"] != split:
                continue
            if names is not None and shard["name"] not in names:
                continue
            verify_shard(self.shard_path(shard["name"]), shard["sha256"], shard["bytes"])

    def clips_of(self, split: str | None, protocol: str = "simulation") -> list[dict]:
        """Clips of one split (``train``, ``val``, ``test``), or all for ``None``.

        ``protocol`` is one of :data:`SPLIT_PROTOCOLS`; under ``sequence`` the returned
        records carry their reassigned ``split`` (their ``shard`` is where they are stored).
        """
        if split is not None and split not in ("train", "val", "test"):
            raise ValueError(f"split must be 'train', 'val', 'test' or None, got {split!r}")
        if protocol not in SPLIT_PROTOCOLS:
            raise ValueError(f"split_protocol must be one of {SPLIT_PROTOCOLS}, got {protocol!r}")
        clips = self.clips if protocol == "simulation" else _deal_by_sequence(self.clips)
        return [c for c in clips if split is None or c["split"] == split]


_SEQUENCE_DEAL_STREAM = 0x5E9
"""Random stream of the ``sequence`` protocol's deal (with the class id)."""


def _deal_by_sequence(clips) -> list[dict]:
    """The ``sequence`` protocol: per class, pooled clips dealt to splits of unchanged sizes.

    The deal is a seeded permutation of the class's clips in key order, so it does not
    depend on the manifest's order or on the process.
    """
    by_class: dict[int, list[dict]] = {}
    for clip in clips:
        by_class.setdefault(int(clip["class_id"]), []).append(clip)
    dealt = []
    for class_id, members in sorted(by_class.items()):
        members = sorted(members, key=lambda c: c["key"])
        splits = sorted(c["split"] for c in members)
        order = np.random.default_rng([class_id, _SEQUENCE_DEAL_STREAM]).permutation(len(members))
        dealt += [{**members[i], "split": split} for i, split in zip(order, splits, strict=True)]
    return sorted(dealt, key=lambda c: c["key"])
