"""Errors and warnings meant for users.

The command line prints a :class:`UserError`'s message as one line and exits with code 2,
a :class:`NoResultError`'s as one line with exit code 1, and a :class:`ThinfilmWarning` as one
``thinfilm: warning: ...`` line.

Library code names the *argument* an error is about (``argument="substrate_ior"``, the
parameter's name in Python), not a command-line flag; the command line maps arguments to its
flags (:func:`thinfilm.cli.flag_for`), so the same error reads ``substrate_ior: ...`` from
Python and ``--substrate-ior: ...`` from the shell.
"""

__all__ = ["UserError", "NoResultError", "ThinfilmWarning"]


class UserError(ValueError):
    """Bad input from a user (a file, a field, an option). The message is one sentence that
    names the file or argument, the field, and what was expected.

    Parameters
    ----------
    message : str
        What is wrong, without the argument's name when ``argument`` is given.
    argument : str, optional
        The Python name of the argument the error is about (``"out"``, ``"method"``,
        ``"substrate_ior"``, ``"thickness_range_nm"`` …).
    value : optional
        The value given for it, shown after the argument's name (``out /data/x: …``).
    """

    def __init__(self, message: str, argument: str | None = None, value=None):
        self.message = str(message)
        self.argument = argument
        self.value = value
        super().__init__(self.render(argument))

    def __reduce__(self):  # keeps the argument across processes (Dask workers)
        return (type(self), (self.message, self.argument, self.value))

    def render(self, name: str | None) -> str:
        """The message with ``name`` (an argument's or a flag's) in front, when there is one."""
        if name is None:
            return self.message
        head = name if self.value is None else f"{name} {self.value}"
        return f"{head}: {self.message}"


class NoResultError(Exception):
    """The work ran on valid input but produced nothing usable (an estimate with no valid
    pixel): reported as one line, exit code 1, and nothing is written."""


class ThinfilmWarning(UserWarning):
    """Something a user should know about their input that does not stop the work (an
    assumption made for a missing field, data a method handles only approximately)."""
