"""A footage folder from someone else: reads stay inside it, every read file is in the
evaluation's identity, and every malformed ``labels.csv`` is one line (issue 61)."""

import os

import numpy as np
import pytest

from common.errors import InputError
from datasets.real_video import RealVideoDataset, footage_files, read_labels

from .conftest import write_mp4


def _frames(count: int, seed: int) -> np.ndarray:
    base = np.random.default_rng(seed).integers(0, 255, size=(32, 40, 3), dtype=np.uint8)
    return np.stack([np.roll(base, 2 * t, axis=1) for t in range(count)])


@pytest.fixture
def footage(tmp_path):
    root = tmp_path / "real"
    root.mkdir()
    for i in range(3):
        write_mp4(root / f"f{i}.mp4", _frames(12, i), 15.0)
    write_mp4(tmp_path / "outside.mp4", _frames(12, 9), 15.0)
    (root / "labels.csv").write_text(
        "video,stiffness,density\nf0.mp4,1,0.2\nf1.mp4,2,0.3\nf2.mp4,3,0.4\n"
    )
    return root


@pytest.mark.parametrize("name", ["../outside.mp4", "../outside", "/etc/hostname", "a/../../x"])
def test_a_video_outside_the_folder_is_refused(footage, name):
    (footage / "labels.csv").write_text(f"video,stiffness,density\n{name},1,0.2\n")
    with pytest.raises(InputError, match=r"line 2: video .* inside .*no absolute path, no '\.\.'"):
        RealVideoDataset(footage, clip_len=4)


def test_a_link_to_a_video_outside_the_folder_is_refused(footage):
    os.symlink(footage.parent / "outside.mp4", footage / "linked.mp4")
    (footage / "labels.csv").write_text("video,stiffness,density\nlinked.mp4,1,0.2\n")
    with pytest.raises(InputError, match=r"line 2: video 'linked.mp4' is a link to .*outside"):
        RealVideoDataset(footage, clip_len=4)


def test_footage_files_are_labels_and_the_listed_videos(footage):
    (footage / "notes.txt").write_text("not read")
    assert [p.name for p in footage_files(footage)] == ["labels.csv", "f0.mp4", "f1.mp4", "f2.mp4"]


def test_a_spreadsheet_byte_order_mark_is_not_part_of_the_header(footage):
    text = (footage / "labels.csv").read_text()
    (footage / "labels.csv").write_bytes(b"\xef\xbb\xbf" + text.encode())
    assert [r.fields["video"] for r in read_labels(footage)] == ["f0.mp4", "f1.mp4", "f2.mp4"]


def test_a_latin1_file_is_refused_in_one_line(footage):
    text = "video,stiffness,density\nf0.mp4,1,0.2 \xb5\n"
    (footage / "labels.csv").write_bytes(text.encode("latin-1"))
    with pytest.raises(InputError, match=r"labels.csv is not UTF-8 text .* save it as UTF-8 CSV"):
        read_labels(footage)


@pytest.mark.parametrize(
    ("row", "message"),
    [
        ("f0.mp4,-1,0.2", r"line 2: column 'stiffness' must be > 0, got '-1'"),
        ("f0.mp4,1,0", r"line 2: column 'density' must be > 0, got '0'"),
        ("f0.mp4,1,nan", r"line 2: column 'density' must be finite"),
        ("f0.mp4,1,0.2,7", r"line 2: 4 fields but the header names 3"),
    ],
)
def test_measured_values_follow_one_rule(footage, row, message):
    (footage / "labels.csv").write_text(f"video,stiffness,density\n{row}\n")
    with pytest.raises(InputError, match=message):
        RealVideoDataset(footage, clip_len=4)


_ALPHABET = [*"abc,\n\"'.-/\\ 0123456789", "\x00", "é", "..", "f0.mp4", "\r\n", ";"]


def test_fuzzed_labels_give_one_line_errors(footage):
    """Random CSV rows (seeded, bounded) either read or are refused with one line."""
    rng = np.random.default_rng(61)
    outcomes = {"read": 0, "refused": 0}
    for _ in range(300):
        header = (
            "video,stiffness,density"
            if rng.random() < 0.8
            else "".join(rng.choice(_ALPHABET, size=int(rng.integers(0, 20))))
        )
        rows = [
            "".join(rng.choice(_ALPHABET, size=int(rng.integers(0, 30))))
            for _ in range(int(rng.integers(0, 5)))
        ]
        if rng.random() < 0.5:
            rows.append(f"f{int(rng.integers(0, 3))}.mp4,{rng.normal():.3g},{rng.normal():.3g}")
        data = "\n".join([header, *rows]).encode("utf-8", errors="surrogatepass")
        if rng.random() < 0.2:
            data = data + rng.bytes(int(rng.integers(1, 8)))
        (footage / "labels.csv").write_bytes(data)
        try:
            RealVideoDataset(footage, clip_len=4)
            outcomes["read"] += 1
        except (InputError, FileNotFoundError) as error:
            assert "\n" not in str(error).strip(), str(error)
            outcomes["refused"] += 1
    assert outcomes["refused"] > 200, outcomes
