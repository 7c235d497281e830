"""Names stay single path components, outputs are checked before the work, Ctrl-C and
file-system errors end a command in one line (common.paths, common.files, common.commands)."""

import errno
import os
import shutil
from collections import namedtuple

import numpy as np
import pytest

import simulator.sequence as sequence_module
from common.commands import INTERRUPTED, report_user_errors
from common.configs import check_targets
from common.errors import InputError
from common.files import staged_folder
from common.paths import check_name, check_output_dir, check_output_file, resolve_inside
from simulator.export import main as export_main
from simulator.sequence import MeshSequence


@pytest.mark.parametrize("good", ["run", "wind-L1-grid-full-s0-cnn_lstm", "a.b", 7])
def test_single_names_are_accepted(good):
    assert check_name(good, "run_name") == str(good)


@pytest.mark.parametrize("bad", ["../x", "a/b", "..", ".", "", " x", "a\\b", "a\x00b", None, 1.5])
def test_names_that_are_paths_are_refused(bad):
    with pytest.raises(InputError, match=r"^run_name must be a single file or folder name"):
        check_name(bad, "run_name")


def test_resolve_inside_follows_links(tmp_path):
    (tmp_path / "root").mkdir()
    (tmp_path / "secret").write_text("x")
    os.symlink(tmp_path / "secret", tmp_path / "root" / "link")
    assert resolve_inside(tmp_path / "root", "a/b", "video") == tmp_path / "root" / "a" / "b"
    for name in ("../secret", "link", "/etc/passwd"):
        with pytest.raises(InputError, match=rf"^video '{name}' points outside"):
            resolve_inside(tmp_path / "root", name, "video")


def test_check_targets_walks_nested_nodes_and_lists():
    allowed = ["a.B", "a.C"]
    check_targets({"_target_": "a.B", "x": [{"_target_": "a.C"}], "y": {"z": 1}}, "cfg", allowed)
    for node, where in (
        ({"_target_": "os.system"}, "_target_"),
        ({"_target_": "a.B", "net": {"inner": {"_target_": "os.makedirs"}}}, "net.inner._target_"),
        ({"_target_": "a.B", "items": [1, {"_target_": "builtins.eval"}]}, r"items\[1\]._target_"),
        ({"_target_": ["a.B"]}, "_target_"),
    ):
        with pytest.raises(InputError, match=rf"^cfg: {where} is .* allowed targets: a.B, a.C$"):
            check_targets(node, "cfg", allowed)


def test_output_dir_checks_kind_before_anything_is_made(tmp_path):
    (tmp_path / "file").write_text("x")
    assert check_output_dir(tmp_path / "new" / "deeper", "out_dir") == tmp_path / "new" / "deeper"
    assert not (tmp_path / "new").exists()
    with pytest.raises(InputError, match=r"^out_dir: .*file exists and is not a folder$"):
        check_output_dir(tmp_path / "file", "out_dir")
    with pytest.raises(InputError, match=r"^out_dir: .*file is a file, so .* cannot be made"):
        check_output_dir(tmp_path / "file" / "below", "out_dir")
    with pytest.raises(InputError, match=r"^out_file: .* is a folder; give a file path$"):
        check_output_file(tmp_path, "out_file")
    for bad in ("", None, 3):
        with pytest.raises(InputError, match=r"^out_dir must be a folder path"):
            check_output_dir(bad, "out_dir")


def test_output_dir_refuses_a_full_disk_and_an_unwritable_folder(tmp_path, monkeypatch):
    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda path: usage(10**9, 10**9, 1024))
    with pytest.raises(InputError, match=r"^out_dir: .* 0.0 MiB free; at least 64 MiB"):
        check_output_dir(tmp_path / "x", "out_dir")
    monkeypatch.undo()
    monkeypatch.setattr(os, "access", lambda path, mode: False)
    with pytest.raises(InputError, match=r"^out_dir: .* cannot be written \(.*: no write perm"):
        check_output_dir(tmp_path / "x", "out_dir")


def test_a_read_only_file_system_is_named(tmp_path):
    mount = tmp_path / "ro"
    mount.mkdir()
    if os.system(f"mount -t tmpfs -o size=1m,ro tmpfs {mount} 2>/dev/null") != 0:
        pytest.skip("this machine cannot mount a read-only tmpfs")
    try:
        with pytest.raises(InputError, match=r"cannot be written \(.*: a read-only file system"):
            check_output_dir(mount / "x", "out_dir")
    finally:
        os.system(f"umount {mount}")


def _entry(exc):
    @report_user_errors
    def entry():
        raise exc

    return entry


@pytest.mark.parametrize(
    ("exc", "code", "line"),
    [
        (KeyboardInterrupt(), 130, INTERRUPTED),
        (
            OSError(errno.ENOSPC, "No space left on device", "/d/x.npz"),
            2,
            "error: cannot write /d/x.npz: No space left on device",
        ),
        (
            PermissionError(errno.EACCES, "Permission denied", "/d"),
            2,
            "error: cannot write /d: Permission denied",
        ),
        (
            FileExistsError(errno.EEXIST, "File exists", "/d"),
            2,
            "error: cannot make the folder /d: a file of that name exists",
        ),
    ],
)
def test_interrupts_and_file_system_errors_end_in_one_line(exc, code, line, capsys):
    with pytest.raises(SystemExit) as info:
        _entry(exc)()
    assert info.value.code == code
    assert capsys.readouterr().err == line + "\n"


def test_an_interrupt_inside_compiled_code_is_an_interrupt(capsys):
    """numba reports Ctrl-C as a SystemError raised while the KeyboardInterrupt is pending."""

    def entry():
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt:
            raise SystemError("<numba function> returned a result with an exception set") from None

    with pytest.raises(SystemExit) as info:
        report_user_errors(entry)()
    assert info.value.code == 130 and capsys.readouterr().err == INTERRUPTED + "\n"


def test_hydra_override_errors_are_one_line(capsys):
    from hydra.errors import ConfigCompositionException

    error = ConfigCompositionException("Could not override 'foo'.\nTo append use +foo=1")
    with pytest.raises(SystemExit) as info:
        _entry(error)()
    assert info.value.code == 2
    assert capsys.readouterr().err == "error: Could not override 'foo'. To append use +foo=1\n"


def _sequence(frames=4):
    rng = np.random.default_rng(0)
    return MeshSequence(
        pos=rng.normal(size=(2, frames, 4, 3)).astype(np.float32),
        tri_indices=np.array([[0, 1, 2], [1, 3, 2]]),
        uv=rng.random((4, 2)).astype(np.float32),
        fps=30.0,
        seeds=[0, 1],
        labels=[0, 1],
        wind_levels=[0, 0],
        meta={},
    )


def _disk_fills_after(count, monkeypatch):
    """Make the mesh writer fail with ENOSPC on its ``count``-th file."""
    calls = {"n": 0}
    write = sequence_module.atomic_write_bytes

    def fills_up(path, data):
        calls["n"] += 1
        if calls["n"] == count:
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        write(path, data)

    monkeypatch.setattr(sequence_module, "atomic_write_bytes", fills_up)


def test_staged_folder_leaves_nothing_when_the_disk_fills(tmp_path, monkeypatch):
    _disk_fills_after(3, monkeypatch)
    with pytest.raises(OSError, match="No space"), staged_folder(tmp_path / "frames") as stage:
        _sequence().export(stage)
    assert list(tmp_path.iterdir()) == []  # no frames folder, no stage


def test_staged_folder_adds_files_to_an_existing_folder_and_keeps_the_others(tmp_path):
    (tmp_path / "mine.txt").write_text("keep")
    with staged_folder(tmp_path) as stage:
        (stage / "new.txt").write_text("new")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine.txt", "new.txt"]
    (tmp_path / "own").mkdir()
    (tmp_path / "own" / "old.txt").write_text("old")
    with staged_folder(tmp_path / "own", replace=True) as stage:
        (stage / "new.txt").write_text("new")
    assert [p.name for p in (tmp_path / "own").iterdir()] == ["new.txt"]


def test_export_command_checks_its_inputs_and_writes_all_frames_or_none(
    tmp_path, monkeypatch, capsys
):
    path = _sequence().save(tmp_path / "seq.npz")
    (tmp_path / "junk.npz").write_text("hello")
    (tmp_path / "half.npz").write_bytes(path.read_bytes()[:500])
    (tmp_path / "file").write_text("x")
    cases = [
        ([str(tmp_path / "none.npz"), str(tmp_path / "o")], "none.npz does not exist"),
        ([str(tmp_path / "junk.npz"), str(tmp_path / "o")], "junk.npz is not a mesh sequence"),
        ([str(tmp_path / "half.npz"), str(tmp_path / "o")], "half.npz is not a mesh sequence"),
        ([str(path), str(tmp_path / "o"), "--instance", "2"], "--instance must be in [0, 1]"),
        ([str(path), str(tmp_path / "file")], "out_dir: "),
    ]
    for argv, words in cases:
        with pytest.raises(SystemExit) as info:
            export_main(argv)
        err = capsys.readouterr().err
        assert info.value.code == 2 and err.startswith("error: ") and words in err, err
        assert err.count("\n") == 1
    _disk_fills_after(3, monkeypatch)
    with pytest.raises(SystemExit) as info:
        export_main([str(path), str(tmp_path / "frames")])
    assert info.value.code == 2 and "No space left on device" in capsys.readouterr().err
    assert not (tmp_path / "frames").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file", "half.npz", "junk.npz", "seq.npz"]
    monkeypatch.undo()
    assert len(export_main([str(path), str(tmp_path / "frames")])) == 4
