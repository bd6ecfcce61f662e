"""Output folders: checked before the work, written to a temporary folder, renamed into place.

Every command that writes a folder (``generate``, ``reconstruct``, ``evaluate``,
``benchmark``) goes through :func:`atomic_output_dir`: nothing half written is ever left at
``--out``, and an existing folder is replaced only when it is one of ours.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from pathlib import Path

from .errors import UserError

__all__ = ["OUTPUT_MARKERS", "check_output_dir", "atomic_output_dir"]

#: Files that mark a folder as one of ours (dataset, estimate, evaluation, benchmark):
#: only such folders, or empty ones, are replaced by a new output.
OUTPUT_MARKERS = ("meta.json", "estimate.json", "metrics.json", "results.json")


def check_output_dir(out, markers=OUTPUT_MARKERS) -> Path:
    """Check that ``out`` can receive a new output folder, before any work is done.

    ``out`` may not exist yet, may be an empty folder, or may be an earlier output of ours
    (it holds one of ``markers``), which will be replaced. Anything else (a file, a folder of
    someone's files) is refused with a :class:`UserError`, so no user data is ever deleted.

    Returns the absolute path.
    """
    out = Path(out).expanduser().resolve()
    if out.parent == out:
        raise UserError(f"--out {out}: cannot write an output folder at the file-system root")
    if out.exists():
        if not out.is_dir():
            raise UserError(f"--out {out}: exists and is not a folder")
        if any(out.iterdir()) and not any((out / m).is_file() for m in markers):
            raise UserError(f"--out {out}: folder exists, is not empty and is not a thinfilm "
                            f"output; refusing to replace it")
    return out


@contextlib.contextmanager
def atomic_output_dir(out, markers=OUTPUT_MARKERS):
    """Yield a temporary folder beside ``out``; on success rename it to ``out``.

    On any error the temporary folder is removed, so no half-written output is left. An
    existing ``out`` is replaced only after the new one is complete, and only if it is empty
    or an earlier output of ours (:func:`check_output_dir`). File-system errors become a
    :class:`UserError` naming ``--out``.
    """
    out = check_output_dir(out, markers)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.tmp-", dir=out.parent))
    except OSError as e:
        raise UserError(f"--out {out}: cannot create the folder ({e.strerror})") from None
    try:
        yield tmp
        check_output_dir(out, markers)  # still safe to replace after the work
        old = None
        if out.exists():
            old = out.with_name(f".{out.name}.old-{os.getpid()}")
            out.rename(old)
        try:
            tmp.rename(out)
        except OSError:
            if old is not None:
                old.rename(out)
            raise
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    except OSError as e:
        shutil.rmtree(tmp, ignore_errors=True)
        raise UserError(f"--out {out}: cannot write the output ({e.strerror or e})") from None
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


