"""Progress bars for long runs: tqdm on stderr, shown only on a terminal."""

from __future__ import annotations

import sys

__all__ = ["progress_bar", "progress_iter"]


class _NoBar:
    def update(self, n=1):
        pass

    def set_postfix_str(self, text):
        pass

    def close(self):
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


def progress_bar(total, desc: str, enabled: bool = True, unit: str = "it"):
    """A tqdm bar on stderr when ``enabled`` and stderr is a terminal, else a do-nothing bar."""
    if not enabled or not sys.stderr.isatty():
        return _NoBar()
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit=unit, file=sys.stderr, leave=False)


def progress_iter(iterable, desc: str, enabled: bool = True, total=None):
    """``iterable`` wrapped in a tqdm bar on stderr when ``enabled`` and on a terminal."""
    if not enabled or not sys.stderr.isatty():
        return iterable
    from tqdm import tqdm

    return tqdm(iterable, desc=desc, total=total, file=sys.stderr, leave=False)
