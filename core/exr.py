"""EXR files: channel names, reading and writing, and OpenEXR's thread pool.

Every image of a dataset, estimate or evaluation folder is a single-part scanline EXR of
float32 channels, ZIP-compressed, all of one height and width, row 0 at the top
(``docs/design.md``, *Dataset folder*). Channel names: a polarizer angle's layer is
``pol000``, ``pol045`` … (whole degrees, three digits) with channels ``R``, ``G``, ``B``; a
spectral band is ``band000`` … in the order of ``wavelengths_nm``.

Examples
--------
>>> pol_layer(45), pol_layer(135.0), band_channel(7)
('pol045', 'pol135', 'band007')
>>> sorted(polarized_rgb_channels({0: np.zeros((1, 1, 3))}))
['pol000.B', 'pol000.G', 'pol000.R']
"""

from __future__ import annotations

import contextlib
import errno
import os
import sys
from pathlib import Path

import numpy as np

from .errors import UserError

__all__ = ["pol_layer", "band_channel", "polarized_rgb_channels", "band_channels", "read_exr", "write_exr",
           "set_exr_threads"]


def pol_layer(angle_deg: float) -> str:
    """Layer name of a polarizer angle: ``pol000``, ``pol045`` …"""
    return f"pol{int(round(angle_deg)) % 360:03d}"


def band_channel(index: int) -> str:
    """Channel name of spectral band ``index``: ``band000`` …"""
    return f"band{index:03d}"


def polarized_rgb_channels(polarized_rgb: dict) -> dict:
    """EXR channels of polarizer images ``{angle: (H, W, 3)}``: ``pol000.R``, ``pol000.G``, …"""
    return {f"{pol_layer(angle)}.{name}": img[..., c]
            for angle, img in polarized_rgb.items() for c, name in enumerate("RGB")}


def band_channels(cube, prefix: str = "") -> dict:
    """EXR channels of a spectral cube (H, W, B): ``{prefix}band000``, …"""
    return {f"{prefix}{band_channel(b)}": cube[..., b] for b in range(cube.shape[-1])}


def set_exr_threads(threads: int) -> None:
    """Size OpenEXR's thread pool, which compresses and decompresses the ZIP blocks of EXR
    files in parallel (the bytes written are the same for any number of threads); 1 or less:
    no pool (:func:`thinfilm.core.threads.set_thread_budget` calls this)."""
    import OpenEXR

    global _EXR_THREADS_SET
    _EXR_THREADS_SET = True
    OpenEXR.set_global_thread_count(int(threads) if threads > 1 else 0)


def _openexr():
    """The OpenEXR module; unless :func:`set_exr_threads` was called, its thread pool sized
    once to the process's thread budget (:mod:`.threads`; at most 8)."""
    import OpenEXR

    if not _EXR_THREADS_SET:
        from .threads import thread_budget

        set_exr_threads(min(thread_budget(), 8))
    return OpenEXR


_EXR_THREADS_SET = False


def write_exr(path, channels: dict) -> None:
    """Write 2-D float32 channels (name → H×W array) to an EXR file (ZIP, deterministic)."""
    OpenEXR = _openexr()

    shapes = {np.shape(v) for v in channels.values()}
    if len(shapes) != 1 or len(next(iter(shapes))) != 2:
        raise ValueError(f"{path}: channels must be 2-D arrays of one shape, got {shapes}")
    data = {k: np.ascontiguousarray(v, dtype=np.float32) for k, v in sorted(channels.items())}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with _c_output() as printed:
        try:
            with OpenEXR.File(header, data) as f:
                f.write(str(path))
        except OSError:
            raise
        except Exception as e:  # OpenEXR reports a full disk as a RuntimeError
            text = f"{e} {printed()}"
            code = next((c for c, words in _ERRNO_WORDS.items() if words in text), None)
            if code is None:
                raise
            raise OSError(code, os.strerror(code), str(path)) from None


_ERRNO_WORDS = {errno.ENOSPC: "No space left on device", errno.EDQUOT: "Disk quota exceeded",
                errno.EROFS: "Read-only file system", errno.EACCES: "Permission denied",
                errno.EFBIG: "File too large"}


@contextlib.contextmanager
def _c_output():
    """Catch what C libraries print on file descriptors 1 and 2 meanwhile (OpenEXR prints
    its own messages about damaged files): yields a function that returns the text.
    Python's own ``sys.stdout`` and ``sys.stderr`` are flushed first and keep working."""
    import tempfile

    captured = {"text": ""}
    try:
        sys.stdout.flush()
        sys.stderr.flush()
        saved = (os.dup(1), os.dup(2))
    except (OSError, ValueError, AttributeError):
        yield lambda: captured["text"]
        return
    import io

    sink = tempfile.TemporaryFile()
    py_sink = io.StringIO()  # what the bindings print through Python's sys.stdout
    try:
        os.dup2(sink.fileno(), 1)
        os.dup2(sink.fileno(), 2)

        def text():
            _flush_c_stdio()
            sink.seek(0)
            return " ".join((sink.read().decode("utf-8", "replace") + py_sink.getvalue()).split())

        with contextlib.redirect_stdout(py_sink), contextlib.redirect_stderr(py_sink):
            yield text
    finally:
        _flush_c_stdio()
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        os.close(saved[0])
        os.close(saved[1])
        sink.close()


def _flush_c_stdio() -> None:
    try:
        import ctypes

        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError):
        pass


def read_exr(path) -> dict:
    """Read every channel of an EXR file as float32 H×W arrays. A missing, damaged or
    truncated file is one :class:`UserError` naming it (OpenEXR's own messages on the
    terminal are caught and left out)."""
    OpenEXR = _openexr()

    path = Path(path)
    if not path.is_file():
        raise UserError(f"{path}: file not found")
    with _c_output() as printed:
        try:
            with OpenEXR.File(str(path), separate_channels=True) as f:
                channels = {k: np.asarray(v.pixels) for k, v in f.channels().items()}
        except Exception as e:  # OpenEXR raises plain exceptions for damaged files
            detail = printed() or str(e)
            if "EXR_ERR_BAD_CHUNK_LEADER" in detail or "corrupt" in detail or "scanline" in detail:
                reason = "damaged or truncated"
            else:
                reason = (str(e) or type(e).__name__).splitlines()[0]
            raise UserError(f"{path}: not a readable EXR file ({reason})") from None
    out = {}
    for k, v in channels.items():
        if v.ndim != 2 or v.dtype.kind not in "fui":
            raise UserError(f"{path}: channel '{k}' is not an image of numbers")
        out[k] = v.astype(np.float32, copy=False)
    return out
