"""Material cloning onto a skirt (``target=skirt``, thesis Fig. 7.9) with a tiny trained run."""

import json

import cv2
import numpy as np
import pytest

import apps.clone as clone
from common.errors import InputError
from simulator.sequence import MeshSequence

from .test_clone import OUTPUTS, SIZE, TINY, _compose, trained, videos  # noqa: F401


@pytest.mark.render
def test_clone_onto_a_skirt_writes_video_sheet_and_sequence(trained, videos, tmp_path):  # noqa: F811
    cfg = _compose(
        f"paths.output_dir={tmp_path}",
        f"video={videos['folder']}",
        f"run={trained}",
        *TINY,
        "target=skirt",
    )
    out = clone.run(cfg)
    assert sorted(p.name for p in tmp_path.iterdir()) == OUTPUTS
    report = json.loads(out.prediction.read_text())
    assert report["simulation"]["target"] == "skirt"
    seq = MeshSequence.load(out.sequence)
    assert seq.meta["scene"] == "garment_skirt" and seq.pos.shape[0] == 3
    assert [c["class_id"] for c in seq.meta["classes"]] == list(out.classes)
    video = cv2.VideoCapture(str(out.video))
    ok, frame = video.read()
    assert ok and int(video.get(cv2.CAP_PROP_FRAME_WIDTH)) == 4 * SIZE + 3 * 4
    for tile in range(1, 4):
        pixels = frame[-SIZE:, tile * (SIZE + 4) : tile * (SIZE + 4) + SIZE]
        assert np.ptp(pixels) > 0, f"skirt tile {tile} is blank"


def test_target_is_checked(tmp_path):
    cfg = _compose(f"paths.output_dir={tmp_path}", "video=v.mp4", "run=r", "target=dress")
    with pytest.raises(InputError, match="target must be one of cloth, skirt; got 'dress'"):
        clone._checked(cfg)
    assert list(tmp_path.iterdir()) == []
