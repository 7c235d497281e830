"""Virtual try-on: another body keeps G and C, wind animation, the command and its refusals."""

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from hydra import compose, initialize_config_dir

import apps.garment.tryon as tryon
from apps.garment.scenes import POSES
from common.errors import InputError
from simulator.garment.body import BodyShape, Mannequin, capsule_distance
from simulator.garment.patterns import build_pattern, default_params
from simulator.sequence import MeshSequence

CONFIGS = str(Path(__file__).resolve().parents[3] / "configs")


def _pattern_json(tmp_path, garment="skirt", params=None, material=None):
    pattern = build_pattern(garment, params or default_params(garment))
    data = pattern.to_json(material or {"bend": 20.0, "stretch": 1.5})
    path = tmp_path / "pattern.json"
    path.write_text(json.dumps(data))
    return path


def test_try_on_another_body_keeps_the_garment_and_material(tmp_path):
    garment, params, material = tryon.load_pattern_json(_pattern_json(tmp_path))
    body = Mannequin.build(BodyShape(height=1.6, waist=0.72, hip=1.02))
    dressed = tryon.try_on(garment, params, material, body, POSES["b"], edge_length=0.1)
    assert dressed.pattern.params == params and dressed.material == material
    caps = body.capsules(POSES["b"].angles[None])[0]
    assert capsule_distance(dressed.pos, caps)[0].min() > -2e-3
    # Worn: the waist edge sits around the body's waist, not on the floor.
    waist = dressed.pattern.topology.segment_vertices[("yoke_front", "waist")]
    assert dressed.pos[waist, 2].mean() > body.levels["hip"]


def test_resize_grades_girths_only():
    params = default_params("pants")
    bigger = tryon.resize_params("pants", params, BodyShape(), BodyShape(waist=0.84, hip=1.06))
    assert bigger["w1"] == pytest.approx(params["w1"] * 0.84 / 0.76)
    assert bigger["h1"] == params["h1"]


def test_wind_moves_the_garment(tmp_path):
    garment, params, material = tryon.load_pattern_json(_pattern_json(tmp_path))
    body = Mannequin.build()
    dressed = tryon.try_on(garment, params, material, body, POSES["a"], edge_length=0.1)
    seq = tryon.wind(dressed, speed=6.0, seconds=0.4, fps=10.0, gust=0.0, ramp=0.1)
    assert isinstance(seq, MeshSequence) and seq.pos.shape[:2] == (1, 5)
    assert np.isfinite(seq.pos).all()
    moved = np.linalg.norm(seq.pos[0, -1] - seq.pos[0, 0], axis=-1).max()
    assert moved > 0.01  # the wind lifts the hem
    # A steady wind along +x pushes the skirt's centre of mass that way.
    assert seq.pos[0, -1, :, 0].mean() > seq.pos[0, 0, :, 0].mean()


def test_bad_pattern_files_are_refused(tmp_path):
    with pytest.raises(InputError, match="pattern: cannot read"):
        tryon.load_pattern_json(tmp_path / "none.json")
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"garment": "dress", "params": {}}))
    with pytest.raises(InputError, match="garment must be one of skirt, pants, tshirt"):
        tryon.load_pattern_json(bad)
    big = _pattern_json(tmp_path, material={"bend": 500.0, "stretch": 1.0})
    with pytest.raises(InputError, match=r"pattern.material.bend .* must lie in \[1.0, 100.0\]"):
        tryon.load_pattern_json(big)


@pytest.mark.render
def test_the_tryon_command_writes_its_files(tmp_path):
    path = _pattern_json(tmp_path)
    out = tmp_path / "out"
    with initialize_config_dir(config_dir=CONFIGS, version_base="1.3"):
        cfg = compose(
            config_name="garment_tryon",
            overrides=[
                f"pattern={path}",
                f"out_dir={out}",
                "edge_length=0.1",
                "wind.seconds=0.2",
                "wind.fps=10",
                "size=64",
                "pose=c",
            ],
        )
    tryon.run(cfg)
    assert sorted(p.name for p in out.iterdir()) == sorted(
        [*tryon.TRYON_OUTPUTS, "garment.obj", "body.obj"]
    )
    video = cv2.VideoCapture(str(out / "wind.mp4"))
    assert int(video.get(cv2.CAP_PROP_FRAME_COUNT)) == 3
    assert cv2.imread(str(out / "tryon.png")).shape == (64, 128, 3)
