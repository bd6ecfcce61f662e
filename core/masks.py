"""Image thresholds shared by the importers and the reconstruction: Otsu's split of a
histogram into two classes.

Examples
--------
>>> values = np.r_[np.full(100, 1.0), np.full(50, 5.0)]
>>> 1.0 < otsu_threshold(values) < 5.0
True
"""

from __future__ import annotations

import numpy as np

__all__ = ["otsu_threshold"]


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
