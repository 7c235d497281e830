"""Names and destinations, checked before the work starts.

A name that becomes a folder is one path component, a file named in someone else's folder
stays inside it, and an output folder can take the outputs.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path
from typing import Any

from .errors import InputError

__all__ = [
    "MIN_FREE_BYTES",
    "check_name",
    "check_output_dir",
    "check_output_file",
    "resolve_inside",
]


def check_name(value: Any, field: str) -> str:
    """``value`` as a single path component: a file or folder name, never a path.

    Names become parts of paths (run folders, report folders); one with a separator, ``..``
    or a NUL could point outside the folder it is meant for.
    """
    text = str(value) if isinstance(value, int) and not isinstance(value, bool) else value
    if (
        not isinstance(text, str)
        or not text.strip()
        or text != text.strip()
        or text in (".", "..")
        or any(c in text for c in ("/", "\\", "\x00"))
    ):
        raise InputError(
            f"{field} must be a single file or folder name (no '/' or '\\', not '.' or "
            f"'..'), got {value!r}"
        )
    return text


def resolve_inside(root: str | Path, name: str, field: str) -> Path:
    """``root / name`` resolved, refused unless it stays inside ``root`` (links followed)."""
    base = Path(root).resolve()
    path = (base / name).resolve()
    if not path.is_relative_to(base):
        raise InputError(f"{field} {name!r} points outside {root} (to {path}); keep files in it")
    return path


MIN_FREE_BYTES = 64 * 2**20
"""Free space an output folder must have before a command starts [bytes]."""


def _existing_ancestor(path: Path) -> Path:
    while not path.exists() and path != path.parent:
        path = path.parent
    return path


def check_output_dir(value: Any, field: str, *, min_free_bytes: int = MIN_FREE_BYTES) -> Path:
    """``value`` as a folder that outputs can be written into, checked before any work.

    Refused in one line: a path that is a file (or lies below one), a folder this process
    may not write (permissions, a read-only file system) and a disk with less than
    ``min_free_bytes`` free. Nothing is created.
    """
    if not isinstance(value, str | Path) or not str(value).strip():
        raise InputError(f"{field} must be a folder path, got {value!r}")
    path = Path(value)
    if path.exists() and not path.is_dir():
        raise InputError(f"{field}: {path} exists and is not a folder")
    base = _existing_ancestor(path.absolute())
    if not base.is_dir():
        raise InputError(f"{field}: {base} is a file, so {path} cannot be made below it")
    if not os.access(base, os.W_OK | os.X_OK):
        why = "a read-only file system" if _read_only(base) else "no write permission"
        raise InputError(f"{field}: {path} cannot be written ({base}: {why})")
    free = shutil.disk_usage(base).free
    if free < min_free_bytes:
        raise InputError(
            f"{field}: {path} is on a disk with {free / 2**20:.1f} MiB free; at least "
            f"{min_free_bytes / 2**20:.0f} MiB are needed"
        )
    return path


def check_output_file(value: Any, field: str, *, min_free_bytes: int = MIN_FREE_BYTES) -> Path:
    """``value`` as a file path whose folder can take it (:func:`check_output_dir`)."""
    if not isinstance(value, str | Path) or not str(value).strip():
        raise InputError(f"{field} must be a file path, got {value!r}")
    path = Path(value)
    if path.is_dir():
        raise InputError(f"{field}: {path} is a folder; give a file path")
    check_output_dir(path.parent, field, min_free_bytes=min_free_bytes)
    return path


def _read_only(path: Path) -> bool:
    try:
        return bool(os.statvfs(path).f_flag & os.ST_RDONLY)
    except OSError:
        return False
