"""Interrupts and termination: SIGINT, SIGTERM, SIGHUP and SIGQUIT become exceptions in the commands.

The command line (:func:`thinfilm.cli.main`) calls :func:`install` before it does anything
else. SIGINT (Ctrl-C) then raises :class:`KeyboardInterrupt` as usual, and SIGTERM, SIGHUP and
SIGQUIT (Ctrl-\\) raise :class:`Terminated`; both unwind through ``with`` blocks, so
:func:`thinfilm.core.outputs.atomic_output_dir` removes its temporary folder and lock. The
signal is also recorded (:func:`received`): a library that turns the exception into one of
its own (an import that fails half-way, a Mitsuba call that wraps it) is still recognised
as interrupted, never reported as a fault of the machine or of the input.

Library code never installs handlers; only entry points do.

Examples
--------
>>> received() is None
True
>>> exit_code(signal.SIGTERM)
143
"""

from __future__ import annotations

import signal

__all__ = ["NAMES", "Terminated", "install", "received", "check_received", "reset", "exit_code", "blocked",
           "deferred"]

#: the signals an entry point turns into exceptions (each cleans up like SIGTERM, SIGINT aside)
NAMES = ("SIGINT", "SIGTERM", "SIGHUP", "SIGQUIT")

_received: int | None = None
_pending: int | None = None  # arrived inside deferred(), not raised yet
_defer_depth = 0


class Terminated(BaseException):
    """SIGTERM, SIGHUP or SIGQUIT arrived (a :class:`BaseException`, like :class:`KeyboardInterrupt`,
    so ``except Exception`` clauses do not swallow it)."""

    def __init__(self, signum: int):
        super().__init__(f"terminated by signal {signum}")
        self.signum = signum


def _raise(signum):
    if signum == signal.SIGINT:
        raise KeyboardInterrupt
    raise Terminated(signum)


#: a repeat of the signal within this many seconds is taken as the same one delivered twice
#: (libLLVM's own handler re-raises it), not as a second request: the first one's clean-up runs
REPEAT_S = 2.0
_first_time = None


def _handler(signum, frame):
    global _received, _pending, _first_time
    import time

    now = time.monotonic()
    if _received is not None and _first_time is not None and now - _first_time < REPEAT_S:
        return
    _received, _first_time = signum, now
    if _defer_depth:
        _pending = signum
        return
    _raise(signum)


class deferred:
    """Context manager: a signal that arrives inside the block is raised as its exception
    when the block ends, not inside it. For native libraries that call back into Python
    while they initialise (Dr.Jit and Mitsuba: an exception raised in such a callback
    aborts the process with a C++ ``terminate``)."""

    def __enter__(self):
        global _defer_depth
        _defer_depth += 1
        return self

    def __exit__(self, *exc):
        global _defer_depth, _pending
        _defer_depth -= 1
        if _defer_depth == 0 and _pending is not None:
            signum, _pending = _pending, None
            if exc[0] is None:
                _raise(signum)
        return False


def install() -> None:
    """Install the handlers (main thread of an entry point only)."""
    for name in NAMES:
        signum = getattr(signal, name, None)
        if signum is None:
            continue
        if signum == signal.SIGINT and signal.getsignal(signum) is signal.SIG_IGN:
            continue  # started in the background with interrupts ignored: keep it so
        signal.signal(signum, _handler)


def received() -> int | None:
    """The signal number that arrived since :func:`install` (or :func:`reset`), or None."""
    return _received


def check_received() -> None:
    """Raise the exception of the signal received since :func:`install` (``KeyboardInterrupt``
    or :class:`Terminated`), if one arrived. For ``except Exception`` clauses that record a
    failure and go on: a signal that a library turned into an error of its own stops the
    command instead of passing for a failure of one task."""
    if _received is not None:
        _raise(_received)


def reset() -> None:
    """Forget signals received so far (an entry point that runs several commands in one process)."""
    global _received, _pending, _first_time
    _received = _pending = _first_time = None


def exit_code(signum: int) -> int:
    """The shell's convention: 128 + the signal number (130 for SIGINT, 143 for SIGTERM)."""
    return 128 + int(signum)


class blocked:
    """Context manager that holds the signals of :data:`NAMES` back while a few file-system
    steps must run together (renaming a finished output into place); a signal that arrives
    meanwhile is delivered when the block ends. A no-op where signals cannot be masked."""

    _signals = tuple(s for s in (getattr(signal, n, None) for n in NAMES) if s)

    def __enter__(self):
        self._old = None
        try:
            self._old = signal.pthread_sigmask(signal.SIG_BLOCK, self._signals)
        except (AttributeError, OSError, ValueError):
            pass
        return self

    def __exit__(self, *exc):
        if self._old is not None:
            signal.pthread_sigmask(signal.SIG_SETMASK, self._old)
        return False
