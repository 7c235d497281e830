"""Errors a user can fix: :class:`InputError` and the domain errors packages register.

A command reports each of them in one line (:func:`common.commands.report_user_errors`);
every other exception is a programming error and keeps its traceback.
"""

from __future__ import annotations

__all__ = ["InputError", "user_error", "user_errors"]


class InputError(ValueError):
    """Bad user input; the message names the field and the allowed values."""


_DOMAIN_ERRORS: list[type[BaseException]] = []
"""Domain errors of the packages that a user can fix (see :func:`user_error`)."""


def user_error(cls: type[BaseException]) -> type[BaseException]:
    """Class decorator: ``cls`` is an error a user can fix, reported in one line by commands.

    Packages register their domain errors this way (this package imports none of them).
    """
    if cls not in _DOMAIN_ERRORS:
        _DOMAIN_ERRORS.append(cls)
    return cls


def user_errors() -> tuple[type[BaseException], ...]:
    """Errors a user can fix: :class:`InputError`, a missing file, the registered ones."""
    return (InputError, FileNotFoundError, *_DOMAIN_ERRORS)
