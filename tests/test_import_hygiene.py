"""`import simulator` stays light: no rendering, training or config frameworks."""

import subprocess
import sys


def test_simulator_import_keeps_heavy_frameworks_out():
    code = (
        "import sys, simulator\n"
        "bad = [m for m in ('pyrender', 'lightning', 'hydra', 'cv2') if m in sys.modules]\n"
        "assert not bad, bad\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, timeout=120)
    assert done.returncode == 0, done.stderr.decode()
