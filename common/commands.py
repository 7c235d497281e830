"""The end of a command: one line for a user error or Ctrl-C, a traceback for a bug.

A user error prints ``error: ...`` and exits with status 2, Ctrl-C prints
:data:`INTERRUPTED` and exits with 130.
"""

from __future__ import annotations

import contextlib
import errno
import functools
import os
import sys
from collections.abc import Callable, Iterator
from typing import Any

from .configs import register_config_resolvers
from .errors import user_errors

__all__ = ["INTERRUPTED", "hydra_command", "report_user_errors"]


INTERRUPTED = "interrupted; rerun the same command to resume"
"""The line Ctrl-C ends a command with (exit status 130, as a shell reports SIGINT)."""

_ENVIRONMENT_ERRNOS = frozenset(
    {
        errno.ENOSPC,
        errno.EROFS,
        errno.EACCES,
        errno.EPERM,
        errno.ENOTDIR,
        errno.EISDIR,
        errno.EDQUOT,
        errno.ENAMETOOLONG,
        errno.EFBIG,
        errno.EEXIST,
    }
)
"""File-system errors a user fixes (a full disk, a read-only or wrong destination)."""


def _chain(exc: BaseException) -> Iterator[BaseException]:
    """``exc`` and the errors it was raised from or during (``__cause__``, ``__context__``)."""
    seen: set[int] = set()
    current: BaseException | None = exc
    while current is not None and id(current) not in seen and len(seen) < 16:
        seen.add(id(current))
        yield current
        current = current.__cause__ or current.__context__


def _wrapper_module(exc: BaseException) -> bool:
    """Errors of the config machinery that wrap the error raised inside it."""
    return type(exc).__module__.split(".")[0] in ("hydra", "omegaconf")


def _user_error_in(exc: BaseException) -> BaseException | None:
    """The error a user can fix that ``exc`` is or wraps, else ``None``.

    Hydra's ``instantiate`` and OmegaConf's interpolation resolvers wrap the error raised
    inside them; a file-system error (a full disk, a read-only destination) is the user's too.
    """
    user = user_errors()
    for current in _chain(exc):
        if isinstance(current, user):
            return current
        if isinstance(current, OSError) and current.errno in _ENVIRONMENT_ERRNOS:
            return current
        if not _wrapper_module(current):
            return None
    return None


_CONFIG_ERRORS = frozenset(
    {
        "hydra.errors.ConfigCompositionException",
        "hydra.errors.MissingConfigException",
        "hydra.errors.OverrideParseException",
        "omegaconf.errors.MissingMandatoryValue",
    }
)
"""Hydra's own refusals of a command line: an override that does not parse or fit."""


def _config_error(exc: BaseException) -> bool:
    return any(f"{c.__module__}.{c.__name__}" in _CONFIG_ERRORS for c in type(exc).__mro__)


def _message(exc: BaseException) -> str:
    key = getattr(exc, "full_key", None)
    if type(exc).__name__ == "MissingMandatoryValue" and key:
        return f"{key} is required: give {key}=<value> on the command line"
    if isinstance(exc, OSError) and exc.strerror and exc.filename is not None:
        if exc.errno == errno.EEXIST:
            return f"cannot make the folder {exc.filename}: a file of that name exists"
        return f"cannot write {exc.filename}: {exc.strerror}"
    return " ".join(str(exc).split())  # one line, whatever the message held


def report_user_errors(main: Callable[..., Any]) -> Callable[..., Any]:
    """Wrap a command so that a user error prints one line and exits with status 2.

    Ctrl-C prints :data:`INTERRUPTED` and exits with 130, whether it arrived in Python or in
    compiled code (numba reports it as a ``SystemError`` raised during the interrupt).
    Programming errors keep their traceback. Put it outside ``@hydra.main`` as well as on
    the task: outside, it also reports what Hydra raises while composing the config and
    making the run folder (it sets ``HYDRA_FULL_ERROR`` so that Hydra passes errors on).
    """

    @functools.wraps(main)
    def wrapped(*args, **kwargs):
        os.environ["HYDRA_FULL_ERROR"] = "1"
        register_config_resolvers()
        stderr = sys.stderr
        if not isinstance(stderr, _LineEnds):
            sys.stderr = _LineEnds(stderr)
        try:
            return main(*args, **kwargs)
        except (Exception, KeyboardInterrupt) as exc:
            _close_progress_bars()
            if any(isinstance(e, KeyboardInterrupt) for e in _chain(exc)):
                _last_line(INTERRUPTED)
                raise SystemExit(130) from None
            user = _user_error_in(exc)
            if user is None and _config_error(exc):
                user = exc
            if user is None:
                raise
            _last_line(f"error: {_message(user)}")
            raise SystemExit(2) from None
        finally:
            sys.stderr = stderr

    return wrapped


class _LineEnds:
    """``sys.stderr`` that remembers whether its last write ended a line (a bar's does not)."""

    def __init__(self, stream):
        self._stream = stream
        self.at_line_start = True

    def write(self, text: str) -> int:
        """Write ``text`` to the stream."""
        if text:
            self.at_line_start = text.endswith("\n")
        return self._stream.write(text)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._stream, name)


def _last_line(text: str) -> None:
    """Print a command's last line on stderr, on a line of its own."""
    if not getattr(sys.stderr, "at_line_start", True):
        print(file=sys.stderr)
    print(text, file=sys.stderr)


def _close_progress_bars() -> None:
    """Close the tqdm bars still open, so that they do not redraw over the last line."""
    tqdm = sys.modules.get("tqdm")
    if tqdm is None:
        return
    for bar in list(getattr(tqdm.tqdm, "_instances", ())):
        with contextlib.suppress(Exception):  # a bar interrupted while it was being set up
            bar.close()


def hydra_command(
    task: Callable[[Any], Any], *, config_name: str, config_path: str = "../configs"
) -> Callable[[], Any]:
    """``task(cfg)`` as a command line, every error ending as :func:`report_user_errors` says.

    Hydra composes ``config_name`` from ``config_path`` (relative to ``task``'s file); its own
    errors (an override that does not parse, a bad run-folder name) end in one line too.
    """
    import hydra

    @functools.wraps(task)  # Hydra finds the config folder and names the job from ``task``
    def body(cfg):
        return task(cfg)

    compose = hydra.main(version_base="1.3", config_path=config_path, config_name=config_name)
    return report_user_errors(compose(report_user_errors(body)))
