"""Checks of command-line values: the value, or an :class:`InputError` naming the field.

The message names the field and the allowed values.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any

from .errors import InputError

__all__ = [
    "check_bool",
    "check_choice",
    "check_device",
    "check_float",
    "check_int",
    "check_threads",
    "require_cuda",
]


def check_int(value: Any, field: str, low: int | None = None, high: int | None = None) -> int:
    """``value`` as an int in ``[low, high]``; refuses bools, non-integral floats and text."""
    ok = isinstance(value, int) and not isinstance(value, bool)
    if isinstance(value, float) and value.is_integer():
        value, ok = int(value), True
    if isinstance(value, str):
        try:
            value, ok = int(value.strip()), True
        except ValueError:
            ok = False
    if not ok:
        raise InputError(f"{field} must be an integer{_range_text(low, high)}, got {value!r}")
    if (low is not None and value < low) or (high is not None and value > high):
        raise InputError(f"{field} must be an integer{_range_text(low, high)}, got {value}")
    return int(value)


def check_float(
    value: Any,
    field: str,
    low: float | None = None,
    high: float | None = None,
    *,
    low_open: bool = False,
) -> float:
    """``value`` as a finite float in ``[low, high]`` (``(low, high]`` with ``low_open``)."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        number = math.nan
    if isinstance(value, bool) or not math.isfinite(number):
        raise InputError(
            f"{field} must be a finite number{_range_text(low, high, low_open)}, got {value!r}"
        )
    below = low is not None and (number <= low if low_open else number < low)
    if below or (high is not None and number > high):
        raise InputError(
            f"{field} must be a number{_range_text(low, high, low_open)}, got {number:g}"
        )
    return number


def check_choice(value: Any, field: str, choices: Iterable[Any]) -> Any:
    """``value`` if it is one of ``choices``."""
    allowed = list(choices)
    if value not in allowed:
        raise InputError(f"{field} must be one of {', '.join(map(str, allowed))}; got {value!r}")
    return value


def check_bool(value: Any, field: str) -> bool:
    """``value`` if it is a bool (``true`` / ``false`` on the command line)."""
    if not isinstance(value, bool):
        raise InputError(f"{field} must be true or false, got {value!r}")
    return value


def check_device(value: Any, field: str) -> str:
    """A torch device name (``auto``, ``cpu``, ``cuda``, ``cuda:N``) this machine has."""
    import torch

    text = str(value).strip().lower()
    if text not in ("auto", "cpu", "cuda") and not (
        text.startswith("cuda:") and text[5:].isdigit()
    ):
        raise InputError(f"{field} must be one of auto, cpu, cuda, cuda:N; got {value!r}")
    if text.startswith("cuda"):
        require_cuda(f"{field}={value}", f"use {field}=cpu or {field}=auto")
        index = int(text[5:]) if ":" in text else 0
        if index >= torch.cuda.device_count():
            raise InputError(
                f"{field}={value}: this machine has {torch.cuda.device_count()} CUDA device(s)"
            )
    return text


def require_cuda(request: str, alternative: str) -> None:
    """Refuse ``request`` (e.g. ``trainer.accelerator=gpu``) in one line when there is no CUDA."""
    import torch

    if not torch.cuda.is_available():
        raise InputError(
            f"{request} asks for CUDA, but this machine has no CUDA device "
            f"(torch.cuda.is_available() is false); {alternative}"
        )


def check_threads(value: Any, name: str = "threads") -> int | None:
    """``value`` as an int >= 1, or ``None`` (leave torch's count alone)."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise InputError(f"{name} must be an integer >= 1 or null (torch's default), got {value!r}")
    return value


def _range_text(low, high, low_open: bool = False) -> str:
    if low is not None and high is not None:
        return f" in {'(' if low_open else '['}{low}, {high}]"
    if low is not None:
        return f" {'>' if low_open else '>='} {low}"
    if high is not None:
        return f" <= {high}"
    return ""
