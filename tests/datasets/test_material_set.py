"""Material sets: the class grid travels from the config through the spec into the manifest.

Data made before the sets were recorded (no ``material_set`` in its spec or manifest) reads as
``wang54`` and keeps its keys and bytes.
"""

import dataclasses
import json
import shutil
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from datasets.datamodule import ClothVideoDataModule
from datasets.generate import spec_from_config
from datasets.generation import generate_dataset
from datasets.manifest import Manifest, legacy_class_grid, write_json
from datasets.preview import class_lines
from datasets.shards import ShardError
from datasets.spec import PRESETS, DatasetSpec
from simulator.cloth.material import (
    BASIS_MATERIAL,
    BEND_MULTIPLIERS,
    STRETCH_MULTIPLIERS,
    WANG54,
    MaterialError,
    MaterialSet,
    class_summary,
    load_wang_material,
    wang_material_names,
)
from simulator.cloth.scenes import ScenarioWind

from .conftest import tiny_spec

ROOT = Path(__file__).resolve().parents[2]
CONFIGS = str(ROOT / "configs")
TWO = MaterialSet("two", BASIS_MATERIAL, (1.0, 10.0), (0.5,))
"""A 2 x 1 grid: class 0 = (p 1, k 0.5), class 1 = (p 10, k 0.5)."""


def _compose(*overrides):
    with initialize_config_dir(config_dir=CONFIGS, version_base="1.3"):
        return compose(config_name="generate", overrides=list(overrides))


def test_wang54_is_the_config_and_the_module_constants():
    node = OmegaConf.to_container(OmegaConf.load(ROOT / "configs/material_set/wang54.yaml"))
    assert MaterialSet.from_json(node) == WANG54
    assert WANG54.stretch_multipliers == STRETCH_MULTIPLIERS
    assert WANG54.bend_multipliers == BEND_MULTIPLIERS
    assert (WANG54.num_classes, WANG54.stretch_count, WANG54.bend_count) == (54, 6, 9)
    assert spec_from_config(_compose()).material_set == WANG54
    assert MaterialSet.from_json(WANG54.to_json()) == WANG54
    assert legacy_class_grid() == WANG54.to_json()
    for c in (0, 13, 53):
        assert WANG54.summary(c) == class_summary(c)


def test_default_set_leaves_the_spec_keys_of_existing_datasets_unchanged():
    # keys of specs made before material sets existed (computed with that code)
    tiny = tiny_spec()
    assert (tiny.key(), tiny.physics_key()) == ("13bdf124ceaad342", "539abc1223c4d354")
    full = DatasetSpec(motion="wind", scenario=ScenarioWind(), preset=PRESETS["full"])
    assert (full.key(), full.physics_key()) == ("609c7a6e8be8a5b3", "1ff3db761e28a2ff")
    assert "material_set" not in tiny_spec().to_json()
    assert full.classes == tuple(range(54))
    assert DatasetSpec.from_json(tiny_spec().to_json()).material_set == WANG54
    # the Newton loop's whole_step (same arithmetic) enters the JSON only when off
    newton = dataclasses.replace(tiny.sim.newton, whole_step=False)
    off = dataclasses.replace(tiny, sim=dataclasses.replace(tiny.sim, newton=newton))
    assert off.to_json()["sim"]["newton"]["whole_step"] is False
    assert off.key() != tiny.key() and DatasetSpec.from_json(off.to_json()) == off


def test_another_set_enters_the_spec_and_its_keys():
    spec = tiny_spec(classes=None, material_set=TWO)
    assert spec.classes == (0, 1)
    data = json.loads(json.dumps(spec.to_json()))
    assert data["material_set"]["name"] == "two"
    back = DatasetSpec.from_json(data)
    assert back == spec and back.key() == spec.key()
    assert spec.physics_key() != tiny_spec(classes=(0, 1)).physics_key()
    with pytest.raises(ValueError, match=r"classes must be in \[0, 1\], got \[53\]"):
        tiny_spec(classes=(0, 53), material_set=TWO)
    cfg = _compose(
        "material_set.name=two",
        "material_set.stretch_multipliers=[1,10]",
        "material_set.bend_multipliers=[0.5]",
        "classes=[1]",
    )
    assert spec_from_config(cfg).material_set == TWO and spec_from_config(cfg).classes == (1,)


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (
            ["material_set.bend_multipliers=[2,1]"],
            "material_set.bend_multipliers must be a "
            "non-empty, strictly increasing list of numbers > 0, got [2, 1]",
        ),
        (["material_set.stretch_multipliers=[]"], "material_set.stretch_multipliers must be"),
        (["material_set.basis=silk"], "material_set.basis must be one of"),
        (["+material_set.colour=red"], "material_set needs ['name', 'basis', "),
        (["classes=[54]"], r"classes[0] must be an integer class id in [0, 53], got 54"),
    ],
)
def test_bad_material_sets_are_named(overrides, message):
    with pytest.raises(ValueError) as info:
        spec_from_config(_compose(*overrides))
    assert message in str(info.value) and "\n" not in str(info.value)


def test_material_set_refuses_bad_fields_and_classes():
    with pytest.raises(MaterialError, match="class_id must be an integer in \\[0, 1\\]"):
        TWO.multipliers(2)
    assert TWO.multipliers(1) == (10.0, 0.5) and TWO.class_of(10, 0.5) == 1
    assert TWO.nearest(7.0, 0.1) == (1, 10.0, 0.5)
    with pytest.raises(MaterialError, match="counts"):
        MaterialSet.from_json({**TWO.to_json(), "num_classes": 54})
    with pytest.raises(MaterialError, match=r"manifest: material_set needs .* missing \['basis'\]"):
        no_basis = {"name": "x", "stretch_multipliers": [1], "bend_multipliers": [1]}
        MaterialSet.from_json(no_basis, "manifest: material_set")


def _copy(dataset: Path, to: Path, edit) -> Path:
    """A copy of ``dataset`` whose manifest JSON is changed by ``edit`` (in place)."""
    shutil.copytree(dataset, to)
    data = json.loads(Manifest.path(to).read_text())
    edit(data)
    write_json(Manifest.path(to), data)
    return to


@pytest.mark.render
def test_the_manifest_carries_the_set_and_old_manifests_read_as_wang54(tiny_dataset, tmp_path):
    data = json.loads(Manifest.path(tiny_dataset).read_text())
    assert data["material_set"] == WANG54.to_json()
    assert Manifest.load(tiny_dataset).material_set == WANG54
    old = _copy(tiny_dataset, tmp_path / "old", lambda d: d.pop("material_set"))
    assert Manifest.load(old).material_set == WANG54
    module = ClothVideoDataModule(old)
    assert (module.num_classes, module.stretch_count, module.bend_count) == (54, 6, 9)
    assert module.stretch_multipliers == list(STRETCH_MULTIPLIERS)
    assert module.bend_multipliers == list(BEND_MULTIPLIERS)
    assert module.class_grid == WANG54.to_json()

    # Running the generator again over a finished old dataset keeps its manifest's bytes: they
    # are the identity training runs recorded.
    before = Manifest.path(old).read_bytes()
    assert generate_dataset(tiny_spec(), old, progress=False) is not None
    assert Manifest.path(old).read_bytes() == before

    two = _copy(tiny_dataset, tmp_path / "two", lambda d: d.update(material_set=TWO.to_json()))
    assert ClothVideoDataModule(two).num_classes == 2
    with pytest.raises(ValueError, match="data_dirs must share one material set"):
        _ = ClothVideoDataModule([tiny_dataset, two]).num_classes
    bad = _copy(tiny_dataset, tmp_path / "bad", lambda d: d["material_set"].update(bend_count=3))
    with pytest.raises(ShardError, match=r"manifest.json: material_set: counts"):
        Manifest.load(bad)


@pytest.mark.render
def test_a_dataset_of_another_set_is_labelled_by_it(tmp_path):
    spec = dataclasses.replace(tiny_spec(), classes=None, material_set=TWO)
    manifest = generate_dataset(spec, tmp_path / "two", progress=False)
    assert manifest is not None and manifest.material_set == TWO
    assert Manifest.load(tmp_path / "two").material_set == TWO
    for clip in manifest.clips:
        summary = TWO.summary(clip["class_id"])
        assert (clip["stretch_mult"], clip["bend_mult"]) == TWO.multipliers(clip["class_id"])
        assert (clip["stretch_index"], clip["bend_index"]) == (clip["class_id"], 0)
        assert clip["stretch_stiffness"] == summary["stretch_stiffness"]
    assert ClothVideoDataModule(tmp_path / "two").class_grid["num_classes"] == 2


DENSE = MaterialSet("dense", BASIS_MATERIAL, (1.0, 10.0), (0.5, 2.0), (0.5, 1.0, 2.0))
"""A 2 x 2 x 3 grid: class id = (stretch_index * 2 + bend_index) * 3 + density_index."""


def test_a_density_axis_orders_ids_density_last_and_scales_the_density():
    assert DENSE.num_classes == 12 and DENSE.grid.describe().startswith("12 (the 2 x 2 x 3")
    assert DENSE.position(7) == (1, 0, 1) and DENSE.grid.class_id(1, 0, 1) == 7
    assert [DENSE.position(c) for c in range(12)] == [
        (s, b, d) for s in range(2) for b in range(2) for d in range(3)
    ]
    assert DENSE.multipliers(7) == (10.0, 0.5) and DENSE.density_mult(7) == 1.0
    assert DENSE.class_of(10.0, 2.0, 2.0) == 11 and DENSE.nearest(9.0, 0.6, 0.4)[0] == 6
    basis = class_summary(0)["density"]
    summaries = [DENSE.summary(c) for c in (6, 7, 8)]
    assert [s["density"] for s in summaries] == pytest.approx([0.5 * basis, basis, 2 * basis])
    assert {s["stretch_stiffness"] for s in summaries} == {DENSE.summary(6)["stretch_stiffness"]}
    materials = DENSE.materials([6, 7, 8])
    assert materials.density.tolist() == pytest.approx([0.5 * basis, basis, 2 * basis])
    assert torch.equal(materials.stretching[0], materials.stretching[2])
    assert class_lines(7, DENSE) == ("class 7", "stretch x10", "bend x0.5", "density x1")
    assert class_lines(7) == ("class 7", "stretch x0.5", "bend x15")
    with pytest.raises(MaterialError, match=r"class_id must be an integer in \[0, 11\]"):
        DENSE.density_mult(12)
    with pytest.raises(MaterialError, match=r"density \(0.5, 1.0, 2.0\)"):
        DENSE.class_of(1.0, 0.5, 3.0)


def test_a_density_axis_round_trips_and_one_density_keeps_the_old_keys():
    data = json.loads(json.dumps(DENSE.to_json()))
    assert data["density_multipliers"] == [0.5, 1.0, 2.0] and data["density_count"] == 3
    assert MaterialSet.from_json(data) == DENSE
    assert "density_multipliers" not in TWO.to_json() and "density_count" not in WANG54.to_json()
    with pytest.raises(MaterialError, match="counts"):
        MaterialSet.from_json({**data, "density_count": 2})
    with pytest.raises(MaterialError, match=r"material_set\.density_multipliers must be"):
        MaterialSet("x", BASIS_MATERIAL, (1.0,), (1.0,), (2.0, 1.0))
    spec = tiny_spec(classes=None, material_set=DENSE)
    assert spec.classes == tuple(range(12))
    back = DatasetSpec.from_json(json.loads(json.dumps(spec.to_json())))
    assert back == spec and back.physics_key() == spec.physics_key()
    # a one-density set writes the spec keys it wrote before density was an axis
    assert (
        "density_multipliers"
        not in tiny_spec(classes=None, material_set=TWO).to_json()["material_set"]
    )
    # one density other than the basis's is kept too: it is another material, another cache
    light = dataclasses.replace(TWO, density_multipliers=(0.5,))
    assert MaterialSet.from_json(json.loads(json.dumps(light.to_json()))) == light
    light_spec = tiny_spec(classes=None, material_set=light)
    assert DatasetSpec.from_json(json.loads(json.dumps(light_spec.to_json()))) == light_spec
    assert light_spec.physics_key() != tiny_spec(classes=None, material_set=TWO).physics_key()
    node = OmegaConf.to_container(OmegaConf.load(ROOT / "configs/material_set/wang162.yaml"))
    wang162 = MaterialSet.from_json(node)
    assert wang162.num_classes == 162 and wang162.multipliers(3 * 53 + 2) == (20.0, 20.0)
    fabrics = [load_wang_material(n).density for n in wang_material_names()]
    lightest, heaviest = (wang162.summary(c)["density"] for c in (0, 2))
    assert lightest <= 1.05 * min(fabrics) and heaviest >= max(fabrics)
    cfg = _compose("material_set=wang162", "classes=[161]")
    assert spec_from_config(cfg).material_set == wang162


@pytest.mark.render
def test_a_dataset_with_a_density_axis_labels_each_clip_with_its_density(tmp_path):
    spec = dataclasses.replace(tiny_spec(), classes=(0, 2), material_set=DENSE)
    manifest = generate_dataset(spec, tmp_path / "dense", progress=False)
    assert manifest is not None and manifest.material_set == DENSE
    basis = class_summary(0)["density"]
    for clip in manifest.clips:
        assert clip["density_index"] == clip["class_id"]  # classes 0 and 2: densities 0, 2
        assert clip["density"] == pytest.approx(DENSE.density_mult(clip["class_id"]) * basis)
        assert (clip["stretch_index"], clip["bend_index"]) == (0, 0)
    module = ClothVideoDataModule(tmp_path / "dense")
    assert module.num_classes == 12 and module.class_grid["density_count"] == 3
