"""A choice among each pixel's candidate solutions that keeps the film thickness smooth.

Colours and spectra repeat along the thickness (the orders of interference), so a pixel's
data may fit several thicknesses almost equally well, the more so where the fringes are weak
(a film whose index is close to its substrate's). Alone, each pixel picks its best fit and
noise decides between near-equal ones: patches of a wrong order. Film thickness varies
smoothly over an object, so the choice is made for all pixels together: each pixel's
candidates cost their data misfit (in units of the noise), and neighbouring pixels pay a
truncated quadratic penalty for differing thicknesses. The minimum of this energy is
approximated by min-sum loopy belief propagation on the 4-neighbour grid, which carries the
evidence of whole regions to every pixel.

Examples
--------
Two candidates per pixel (300 nm and 450 nm) on a strip; the data prefer 450 nm slightly at
most pixels but 300 nm at a few, which the neighbours outvote:

>>> import numpy as np
>>> mask = np.ones((1, 12), dtype=bool)
>>> values = np.tile([300.0, 450.0], (12, 1))
>>> costs = np.tile([1.0, 0.0], (12, 1))
>>> costs[[3, 7]] = [0.0, 1.0]
>>> choose_smooth(values, costs, mask, sigma=10.0).tolist()
[1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1]
"""

from __future__ import annotations

import numpy as np

__all__ = ["choose_smooth", "neighbour_penalty"]

_MISSING = 1e9


def neighbour_penalty(delta, sigma, truncation=8.0):
    """The penalty of two neighbours whose thicknesses differ by ``delta``:
    ``min((delta / sigma)² / 2, truncation)`` (a real jump costs no more than ``truncation``)."""
    d = np.asarray(delta, dtype=np.float64) / sigma
    return np.minimum(0.5 * d * d, truncation)


def choose_smooth(values, costs, mask, sigma, truncation=8.0, iterations=25, damping=0.5):
    """Index of the chosen candidate per mask pixel (in the order of ``mask``'s pixels).

    Parameters
    ----------
    values : (N, K) candidate values (thickness in nm) of the N mask pixels; NaN: none.
    costs : (N, K) misfit of each candidate in units of the noise (a χ²); inf: none.
    mask : (H, W) bool with N pixels.
    sigma : scale of the neighbour penalty ``min((Δ/sigma)² / 2, truncation)``.
    truncation : the penalty's cap (a real jump costs no more than this).
    iterations : message passes.
    damping : fraction of the old message kept at each pass.

    Returns
    -------
    (N,) int
    """
    values = np.asarray(values, dtype=np.float64)
    costs = np.asarray(costs, dtype=np.float64)
    mask = np.asarray(mask, dtype=bool)
    n, k = values.shape
    missing = ~np.isfinite(values) | ~np.isfinite(costs)
    U = np.where(missing, _MISSING, costs)
    U = U - U.min(axis=1, keepdims=True)
    vals = np.where(missing, 0.0, values)
    if k == 1 or n == 0:
        return np.zeros(n, dtype=np.int64)
    # a pixel whose best candidate beats its others by more than its four neighbours could
    # ever pay is decided by its own data; the others are chosen by belief propagation among
    # themselves, their decided neighbours entering as fixed terms
    best = np.argmin(U, axis=1)
    second = np.partition(U, 1, axis=1)[:, 1]
    open_ = second <= 4.0 * truncation
    if not open_.any():
        return best
    H, W = mask.shape
    index = np.full((H, W), -1, dtype=np.int64)
    index[mask] = np.arange(n)
    r, c = np.nonzero(mask)
    steps = ((-1, 0), (1, 0), (0, -1), (0, 1))
    opposite = (1, 0, 3, 2)
    sub = np.nonzero(open_)[0]
    m = sub.size
    local = np.full(n, -1, dtype=np.int64)
    local[sub] = np.arange(m)
    Us = U[sub].copy()
    nbr = []
    pair = []
    for dr, dc in steps:
        rr, cc = r[sub] + dr, c[sub] + dc
        ok = (rr >= 0) & (rr < H) & (cc >= 0) & (cc < W)
        j = np.full(m, -1, dtype=np.int64)
        j[ok] = index[rr[ok], cc[ok]]
        jj = np.maximum(j, 0)
        V = neighbour_penalty(vals[sub][:, :, None] - vals[jj][:, None, :], sigma, truncation)
        V = np.where(missing[sub][:, :, None] | missing[jj][:, None, :], truncation, V)
        fixed = (j >= 0) & ~open_[jj]
        # a decided neighbour: the penalty against its chosen candidate
        Us += np.where(fixed[:, None], V[np.arange(m), :, best[jj]], 0.0)
        nbr.append(np.where((j >= 0) & open_[jj], local[jj], -1))
        pair.append(V)
    msgs = [np.zeros((m, k)) for _ in steps]          # msgs[d][i]: into i from its d-neighbour
    for _ in range(iterations):
        total = Us + sum(msgs)
        new = []
        for d, j in enumerate(nbr):
            has = j >= 0
            jj = np.maximum(j, 0)
            # what the neighbour j knows, less what i told it (i is j's opposite neighbour)
            h = total[jj] - msgs[opposite[d]][jj]
            mm = np.min(pair[d] + h[:, None, :], axis=2)
            mm = mm - mm.min(axis=1, keepdims=True)
            mm = np.where(has[:, None], mm, 0.0)
            new.append(damping * msgs[d] + (1.0 - damping) * mm)
        msgs = new
    out = best.copy()
    out[sub] = np.argmin(Us + sum(msgs), axis=1)
    return out
