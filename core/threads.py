"""The threads this process may use for its own parallel work.

One number, the process's thread budget: by default the cores it may run on. A Dask worker
given a share of the cores sets it to that share (:func:`set_thread_budget`), which sizes
Dr.Jit's and OpenEXR's thread pools and the generator's noise threads alike, so that the
workers together use no more threads than there are cores. Dr.Jit's pool is sized here;
OpenEXR's follows the budget at its next read or write (:mod:`thinfilm.core.exr`), and this
module imports nothing of the project.

>>> from thinfilm.core.threads import cores, thread_budget
>>> thread_budget() == cores() >= 1
True
"""

from __future__ import annotations

import os

__all__ = ["cores", "thread_budget", "set_thread_budget"]

_BUDGET: int | None = None


def cores() -> int:
    """The number of cores this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def thread_budget() -> int:
    """Threads this process may use: :func:`set_thread_budget`'s value, else :func:`cores`."""
    return _BUDGET if _BUDGET is not None else cores()


def set_thread_budget(threads: int | None) -> None:
    """Give this process ``threads`` threads (at least 1; None: back to :func:`cores`):
    Dr.Jit's pool, OpenEXR's pool (at most :data:`thinfilm.core.exr.MAX_EXR_THREADS`, from
    the next EXR read or write on) and the generator's noise threads follow."""
    global _BUDGET
    _BUDGET = None if threads is None else max(1, int(threads))
    n = thread_budget()
    import drjit as dr

    if dr.thread_count() != n:
        dr.set_thread_count(n)
