"""Height maps from normal fields on a mask, and normals from height maps.

Camera frame of ``docs/design.md``, *Conventions*: image x to the right, y up (row 0 is the top
row), z towards the orthographic camera. A height map ``z(x, y)`` in pixel units has the normal
``(-z_x, -z_y, 1) / |…|``, so a unit normal gives the gradient ``z_x = -n_x / n_z``,
``z_y = -n_y / n_z``.

:func:`integrate_normals` solves the weighted least-squares (Poisson) problem on the mask,

    min_z  Σ_edges w_e (z_j - z_i - ḡ_e)²  +  λ Σ (second differences of z)²,

one equation per pair of 4-neighbouring mask pixels (``ḡ_e`` the mean of the two pixels'
gradients along the edge, ``w_e`` the smaller of their weights). It works on any mask shape,
holes included; each connected part of the mask gets zero mean height. The optional
second-difference term (``smoothness`` = λ) regularizes regions where the normals carry
little information (small weights), e.g. near normal incidence in polarization data.

Examples
--------
>>> import numpy as np
>>> y, x = np.mgrid[16:-17:-1, -16:17].astype(float)     # pixel coordinates, y up
>>> mask = x ** 2 + y ** 2 < 15 ** 2
>>> h = 0.02 * (x ** 2 + y ** 2)                        # a paraboloid, in pixel units
>>> n = np.stack([-0.04 * x, -0.04 * y, np.ones_like(x)], axis=-1)
>>> n /= np.linalg.norm(n, axis=-1, keepdims=True)
>>> z = integrate_normals(n, mask)
>>> float(np.abs(z - (h - h[mask].mean()))[mask].max()) < 1e-6
True
"""

from __future__ import annotations

import numpy as np

__all__ = ["integrate_normals", "height_to_normals", "normals_to_gradients", "second_differences"]


def normals_to_gradients(normals, max_slope_deg: float = 85.0):
    """Surface gradients ``(z_x, z_y)`` (y up) of unit normals, slopes clipped to ``max_slope_deg``."""
    n = np.asarray(normals, dtype=np.float64)
    nz = np.maximum(n[..., 2], np.cos(np.radians(max_slope_deg)))
    return -n[..., 0] / nz, -n[..., 1] / nz


def integrate_normals(normals, mask, weights=None, smoothness: float = 0.0,
                      max_slope_deg: float = 85.0, max_direct: int | None = 20000):
    """Integrate a normal field to a height map on a mask (weighted least squares).

    Parameters
    ----------
    normals : (H, W, 3) unit normals in the camera frame (x right, y up, z to the camera).
    mask : (H, W) bool, pixels to integrate over.
    weights : optional (H, W) non-negative confidence of each pixel's normal.
    smoothness : weight λ of the second-difference regularizer (0: pure Poisson).
    max_slope_deg : normals steeper than this are clipped (silhouette pixels).
    max_direct : masks of more pixels are integrated at half the resolution (2 x 2 blocks,
        recursively) and the height is upsampled bilinearly: a smooth surface's normals
        then stay within about 0.1° of the full solution at a tenth of the time; None:
        always at full resolution.

    Returns
    -------
    height : (H, W) in pixel units (the unit of one pixel's width), each connected part of the
        mask with zero mean; 0 outside the mask.
    """
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    mask = np.asarray(mask, dtype=bool)
    H, W = mask.shape
    p, q = normals_to_gradients(normals, max_slope_deg)
    w = np.ones((H, W)) if weights is None else np.asarray(weights, dtype=np.float64)
    w = np.where(mask & np.isfinite(p) & np.isfinite(q), np.clip(w, 0.0, None), 0.0)
    p, q = np.nan_to_num(p), np.nan_to_num(q)
    idx = -np.ones((H, W), dtype=np.int64)
    n = int(mask.sum())
    if n == 0:
        return np.zeros((H, W))
    if max_direct is not None and n > max_direct:
        nc, mc, wc = _half_resolution(np.nan_to_num(normals), mask, w)
        zc = integrate_normals(nc, mc, wc, smoothness, max_slope_deg, max_direct)
        z = 2.0 * _upsample(zc, mc, mask.shape)
        return np.where(mask, z - _part_means(z, mask), 0.0)
    idx[mask] = np.arange(n)

    rows, cols, vals, rhs, roww = [], [], [], [], []
    nrow = 0

    def add(i, j, g, wt):
        nonlocal nrow
        m = i.size
        r = np.arange(nrow, nrow + m)
        rows.extend([r, r])
        cols.extend([i, j])
        vals.extend([-np.ones(m), np.ones(m)])
        rhs.append(g)
        roww.append(wt)
        nrow += m

    # x edges: z[r, c+1] - z[r, c] = mean p
    e = mask[:, :-1] & mask[:, 1:]
    add(idx[:, :-1][e], idx[:, 1:][e], 0.5 * (p[:, :-1] + p[:, 1:])[e], np.minimum(w[:, :-1], w[:, 1:])[e])
    # y edges (y up = row - 1): z[r-1, c] - z[r, c] = mean q
    e = mask[1:, :] & mask[:-1, :]
    add(idx[1:, :][e], idx[:-1, :][e], 0.5 * (q[1:, :] + q[:-1, :])[e], np.minimum(w[1:, :], w[:-1, :])[e])

    A = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(nrow, n))
    b = np.concatenate(rhs)
    wt = np.concatenate(roww)
    scale = np.mean(wt[wt > 0]) if np.any(wt > 0) else 1.0
    wt = wt / scale
    Wd = sp.diags(wt)
    N = (A.T @ Wd @ A).tocsr()
    rhs_vec = A.T @ (wt * b)

    if smoothness > 0:
        S = second_differences(mask, idx, n)
        N = N + smoothness * (S.T @ S)
    # Tiny Tikhonov term: fixes the free constant of every connected part (zero-mean height).
    N = N + 1e-9 * sp.identity(n)
    # N is symmetric positive definite: a symmetric fill-reducing ordering and no pivoting
    # (half the fill of the general-purpose default).
    lu = spla.splu(N.tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                   options={"SymmetricMode": True})
    z = lu.solve(np.asarray(rhs_vec, dtype=np.float64))
    z = _zero_mean_parts(z, mask, idx)
    out = np.zeros((H, W))
    out[mask] = z
    return out


def _half_resolution(normals, mask, weights):
    """Normals, mask and weights on a grid of 2 x 2 blocks: the weighted mean normal, blocks
    with at least two mask pixels, the summed weights."""
    H, W = mask.shape
    Hp, Wp = H + H % 2, W + W % 2
    pad = ((0, Hp - H), (0, Wp - W))
    m = np.pad(mask, pad).astype(float)
    w = np.pad(np.where(mask, weights, 0.0), pad) + 1e-12 * m
    n = np.stack([np.pad(normals[..., k], pad) for k in range(3)], axis=-1)

    def blocks(a):
        return a.reshape(Hp // 2, 2, Wp // 2, 2, *a.shape[2:]).sum(axis=(1, 3))

    wb = blocks(w)
    nb = blocks(n * w[..., None]) / np.maximum(wb, 1e-300)[..., None]
    nb /= np.maximum(np.linalg.norm(nb, axis=-1, keepdims=True), 1e-12)
    return nb, blocks(m) >= 2, wb


def _upsample(zc, mask_c, shape):
    """Bilinear upsampling by 2 of a half-resolution height (values outside ``mask_c`` taken
    from the nearest mask pixel)."""
    from scipy import ndimage

    _, (ir, ic) = ndimage.distance_transform_edt(~mask_c, return_indices=True)
    filled = zc[ir, ic]
    r = (np.arange(shape[0]) - 0.5) / 2.0
    c = (np.arange(shape[1]) - 0.5) / 2.0
    R, C = np.meshgrid(r, c, indexing="ij")
    return ndimage.map_coordinates(filled, [R, C], order=1, mode="nearest")


def _part_means(z, mask):
    """Per pixel, the mean of ``z`` over its connected part of ``mask``."""
    from scipy import ndimage

    labels, count = ndimage.label(mask)
    means = np.asarray(ndimage.mean(z, labels, index=np.arange(1, count + 1)))
    return np.where(labels > 0, means[np.maximum(labels, 1) - 1], 0.0)


def second_differences(mask, idx, n):
    """The second differences along x and y of the pixels of ``mask`` numbered ``idx`` (-1
    outside), as a sparse (rows × n) matrix: one row per three consecutive mask pixels."""
    import scipy.sparse as sp

    rows, cols, vals = [], [], []
    nrow = 0
    H, W = mask.shape
    for (a, b, c) in (((slice(None), slice(None, -2)), (slice(None), slice(1, -1)), (slice(None), slice(2, None))),
                      ((slice(None, -2), slice(None)), (slice(1, -1), slice(None)), (slice(2, None), slice(None)))):
        e = mask[a] & mask[b] & mask[c]
        m = int(e.sum())
        r = np.arange(nrow, nrow + m)
        for sl, v in ((a, 1.0), (b, -2.0), (c, 1.0)):
            rows.append(r)
            cols.append(idx[sl][e])
            vals.append(np.full(m, v))
        nrow += m
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(nrow, n))


def _zero_mean_parts(z, mask, idx):
    from scipy import ndimage

    labels, count = ndimage.label(mask)
    lab = labels[mask]
    means = ndimage.mean(z, lab, index=np.arange(1, count + 1))
    return z - np.asarray(means)[lab - 1]


def height_to_normals(height, mask):
    """Unit normals of a height map (pixel units, y up) on a mask.

    Central differences where both neighbours lie in the mask, one-sided ones at the mask's
    edge, zero slope along an axis where a pixel has no neighbour in the mask.

    Returns
    -------
    (H, W, 3) unit normals; ``(0, 0, 1)`` outside the mask.
    """
    z = np.asarray(height, dtype=np.float64)
    mask = np.asarray(mask, dtype=bool)
    zx = _derivative(z, mask, axis=1, sign=1.0)
    zy = _derivative(z, mask, axis=0, sign=-1.0)  # rows grow downwards, y grows upwards
    n = np.stack([-zx, -zy, np.ones_like(z)], axis=-1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    n[~mask] = (0.0, 0.0, 1.0)
    return n


def _derivative(z, mask, axis, sign):
    zp = np.zeros_like(z)
    zm = np.zeros_like(z)
    mp = np.zeros_like(mask)
    mm = np.zeros_like(mask)
    sl_hi = [slice(None)] * 2
    sl_lo = [slice(None)] * 2
    sl_hi[axis] = slice(1, None)
    sl_lo[axis] = slice(None, -1)
    sl_hi, sl_lo = tuple(sl_hi), tuple(sl_lo)
    zp[sl_lo] = z[sl_hi]       # value at index + 1
    mp[sl_lo] = mask[sl_hi]
    zm[sl_hi] = z[sl_lo]       # value at index - 1
    mm[sl_hi] = mask[sl_lo]
    d = np.where(mp & mm, 0.5 * (zp - zm), np.where(mp, zp - z, np.where(mm, z - zm, 0.0)))
    return sign * np.where(mask, d, 0.0)
