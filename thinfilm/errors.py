"""Errors meant for users: the CLI prints their message as one line and exits with code 2."""

__all__ = ["UserError"]


class UserError(ValueError):
    """Bad input from a user (a file, a field, an option). The message is one sentence that
    names the file or option, the field, and what was expected."""
