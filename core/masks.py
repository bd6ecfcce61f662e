"""Object masks shared by the importers and the reconstruction: Otsu's split of a histogram
into two classes, and a user's mask image read from disk.

Examples
--------
>>> values = np.r_[np.full(100, 1.0), np.full(50, 5.0)]
>>> 1.0 < otsu_threshold(values) < 5.0
True
"""

from __future__ import annotations

import io
import os
import stat
from pathlib import Path

import numpy as np

from .errors import UserError
from .files import path_error, read_bytes_file, show_path, special_file_kind

__all__ = ["otsu_threshold", "read_mask_file"]


def otsu_threshold(values, bins: int = 256) -> float:
    """Otsu's threshold of ``values``: the histogram split of largest between-class variance.

    Parameters
    ----------
    values : array of finite numbers (any shape; flattened).
    bins : histogram bins over the range of ``values``.

    Returns
    -------
    float
        The centre of the last bin of the lower class: values ``<=`` it are one class, values
        above it the other.

    References
    ----------
    N. Otsu, "A threshold selection method from gray-level histograms", IEEE Trans. Systems,
    Man, and Cybernetics 9 (1979) 62–66.
    """
    hist, edges = np.histogram(values, bins=bins)
    centers = 0.5 * (edges[:-1] + edges[1:])
    w0 = np.cumsum(hist)
    w1 = w0[-1] - w0
    m0 = np.cumsum(hist * centers)
    mu0 = m0 / np.maximum(w0, 1)
    mu1 = (m0[-1] - m0) / np.maximum(w1, 1)
    between = w0 * w1 * (mu0 - mu1) ** 2
    return float(centers[int(np.argmax(between))])


def read_mask_file(path, shape):
    """Read a mask image (EXR, PNG, or ``.npy``; non-zero on the object) of the given shape."""
    from .exr import read_exr  # OpenEXR, only for an EXR mask

    p = Path(path)
    try:
        if not stat.S_ISREG(os.stat(p).st_mode) and not special_file_kind(os.stat(p).st_mode):
            raise UserError(f"{show_path(p)}: mask file not found")
    except (FileNotFoundError, NotADirectoryError):
        raise UserError(f"{show_path(p)}: mask file not found") from None
    except OSError as e:
        raise path_error(p, "mask file", e) from None
    suffix = p.suffix.lower()
    data = None if suffix == ".exr" else read_bytes_file(p, "mask file")
    try:
        if suffix == ".exr":
            ch = read_exr(p)
            name = "mask" if "mask" in ch else sorted(ch)[0]
            m = ch[name]
        elif suffix == ".npy":
            m = np.load(io.BytesIO(data))
        else:
            import matplotlib.image as mpimg

            m = mpimg.imread(io.BytesIO(data), format=suffix.lstrip(".") or None)
        m = np.asarray(m, dtype=np.float64)
    except UserError:
        raise
    except Exception as e:
        reason = (str(e) or type(e).__name__).splitlines()[0]
        raise UserError(f"{p}: cannot read the mask image ({reason})") from None
    if not np.all(np.isfinite(m)):
        raise UserError(f"{p}: mask image holds NaN or infinite values")
    if m.ndim == 3:
        m = m[..., :3].max(axis=-1) if m.shape[-1] >= 3 else m[..., 0]
    if m.shape != tuple(shape):
        raise UserError(f"{p}: mask has shape {m.shape}, expected the captures' {tuple(shape)}")
    return m > 0
