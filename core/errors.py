"""Errors and warnings meant for users.

The command line prints a :class:`UserError`'s message as one line and exits with code 2,
and a :class:`ThinfilmWarning` as one ``thinfilm: warning: ...`` line.
"""

__all__ = ["UserError", "ThinfilmWarning"]


class UserError(ValueError):
    """Bad input from a user (a file, a field, an option). The message is one sentence that
    names the file or option, the field, and what was expected."""


class ThinfilmWarning(UserWarning):
    """Something a user should know about their input that does not stop the work (an
    assumption made for a missing field, data a method handles only approximately)."""
