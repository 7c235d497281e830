"""The shrink command's own fields: one line naming the field, before any work."""

import subprocess
import sys

import pytest


@pytest.mark.parametrize(
    ("override", "field"),
    [
        ("columns=[]", "columns"),
        ("columns=stiffness", "columns"),
        ("group=[a]", "group"),
        ("data_preset=huge", "data_preset"),
        ("control=maybe", "control"),
        ("lr_scale=0", "lr_scale"),
        ("lr_scale=2", "lr_scale"),
    ],
)
def test_shrink_names_a_bad_field(tmp_path, override, field):
    done = subprocess.run(
        [sys.executable, "-m", "sim2real.shrink", f"report={tmp_path}", override],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode != 0
    assert done.stderr.strip().splitlines()[-1].startswith(f"error: {field} must be")
    assert "Traceback" not in done.stderr
