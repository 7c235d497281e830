"""Outputs never half-written: a file, or a series of files, arrives whole or not at all."""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

__all__ = ["atomic_write_bytes", "staged_folder"]

_UMASK = os.umask(0)
os.umask(_UMASK)


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` via a temporary file and ``os.replace``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as handle:
            handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
        os.chmod(tmp, 0o666 & ~_UMASK)  # mkstemp creates 0600; give the usual file mode
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


@contextlib.contextmanager
def staged_folder(dest: str | Path, *, replace: bool = False) -> Iterator[Path]:
    """A fresh folder beside ``dest`` whose files reach ``dest`` once the block ends without error.

    On success a new ``dest`` is the stage renamed; an existing one receives the staged files
    (same names replaced, other files kept) or, with ``replace`` (a folder the command owns),
    is replaced whole. On any error or interrupt the stage is removed, so no half-written
    series is left at ``dest``.
    """
    dest = Path(dest)
    dest.parent.mkdir(parents=True, exist_ok=True)
    stage = Path(tempfile.mkdtemp(dir=dest.parent, prefix=f".{dest.name}.", suffix=".tmp"))
    try:
        stage.chmod(0o777 & ~_UMASK)  # mkdtemp makes it private; outputs are ordinary folders
        yield stage
        if dest.exists() and replace:
            shutil.rmtree(dest)
        if not dest.exists():
            stage.rename(dest)
            return
        for item in sorted(stage.iterdir()):
            os.replace(item, dest / item.name)
        stage.rmdir()
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        raise
