"""The core's errors that a user can fix: bad input and a bad material.

:class:`InputError` (a field with a bad value) comes from :mod:`common.errors`, where every
package's user errors are registered; a command reports them in one line
(:func:`common.commands.report_user_errors`).
"""

from __future__ import annotations

from common.errors import InputError, user_error

__all__ = ["InputError", "MaterialError"]


@user_error
class MaterialError(ValueError):
    """An unknown material or class, a malformed material file, or a modulus out of range."""
