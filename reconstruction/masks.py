"""Object masks from captures or files, occluding-boundary directions, and the resolution of
the 180° azimuth ambiguity of polarization by propagation from the boundary.

Everything here uses only the captured data (no ground truth), so it works on real captures.
"""

from __future__ import annotations


import numpy as np

from thinfilm.core.masks import otsu_threshold

__all__ = ["mask_from_intensity", "otsu_threshold", "outward_directions", "resolve_azimuth", "masked_median"]


def mask_from_intensity(intensity, min_pixels: int = 16):
    """Object mask of a capture against a dark background.

    The threshold is Otsu's on ``log10(intensity)``: the background of a specular object in a
    dark surround sits orders of magnitude below the object. When the image holds no dark
    background (the two classes lie less than a factor 10 apart) every pixel with a positive
    value is kept. Connected parts smaller than ``min_pixels`` are dropped. Pixels enclosed
    by the object, or in gaps of a few pixels across it, that are more than three times
    brighter than the brightest background (its 99.9th percentile) join it.

    Parameters
    ----------
    intensity : (H, W) non-negative image, e.g. the mean of the RGB channels of S0.

    Returns
    -------
    (H, W) bool
    """
    from scipy import ndimage

    v = np.asarray(intensity, dtype=np.float64)
    pos = v > 0
    if pos.sum() < min_pixels:
        return np.zeros(v.shape, dtype=bool)
    floor = max(np.percentile(v[pos], 0.1) * 1e-2, 1e-9)
    lv = np.log10(np.maximum(v, floor))
    t = otsu_threshold(lv.ravel())
    lo, hi = lv[lv <= t], lv[lv > t]
    if lo.size == 0 or hi.size == 0 or np.median(hi) - np.median(lo) < 1.0:
        mask = pos
    else:
        mask = lv > t
    labels, count = ndimage.label(mask)
    if count:
        sizes = ndimage.sum(mask, labels, index=np.arange(1, count + 1))
        keep = np.zeros(count + 1, dtype=bool)
        keep[1:] = sizes >= min_pixels
        mask = keep[labels]
    # pixels enclosed by the object, or in a gap of a few pixels across it, that are clearly
    # brighter than the background belong to it (a film near its anti-reflection minimum
    # is dark, but not black: thin dark rings); a hole that shows the background (a ring's)
    # or reflects nothing (the camera's hole in the dome) stays out
    filled = ndimage.binary_fill_holes(ndimage.binary_closing(mask, np.ones((3, 3), bool), iterations=2) | mask)
    gaps = filled & ~mask
    if gaps.any() and (~filled).sum() >= min_pixels:
        background = float(np.percentile(v[~filled], 99.9))
        mask = mask | (gaps & (v > 3.0 * max(background, floor)))
    return mask


def masked_median(values, mask, size: int = 5):
    """Median of ``values`` over the mask pixels of the ``size`` × ``size`` window around each
    mask pixel (a median filter that ignores everything outside the mask).

    Returns an (H, W) array: the median at mask pixels, ``values`` elsewhere.

    >>> v = np.array([[1.0, 2.0, 9.0], [3.0, 4.0, 9.0]])
    >>> m = np.array([[True, True, False], [True, True, False]])
    >>> masked_median(v, m, 3)[0].tolist()
    [2.5, 2.5, 9.0]
    """
    values = np.asarray(values, dtype=np.float64)
    mask = np.asarray(mask, dtype=bool)
    pad = size // 2
    v = np.pad(np.where(mask, values, np.nan), pad, constant_values=np.nan)
    rows, cols = np.nonzero(mask)
    win = np.lib.stride_tricks.sliding_window_view(v, (size, size))[rows, cols].reshape(rows.size, -1)
    win = np.sort(win, axis=1)                      # NaN (outside the mask) sort last
    k = np.sum(np.isfinite(win), axis=1)            # >= 1: the pixel itself is in the mask
    lo = np.take_along_axis(win, ((k - 1) // 2)[:, None], axis=1)[:, 0]
    hi = np.take_along_axis(win, (k // 2)[:, None], axis=1)[:, 0]
    out = values.copy()
    out[rows, cols] = 0.5 * (lo + hi)
    return out


def outward_directions(mask, smooth_px: float = 1.5):
    """Unit vectors (H, W, 2), in the (x right, y up) frame, pointing out of the mask: the
    negated gradient of the smoothed inside distance to the mask's edge."""
    from scipy import ndimage

    dist = ndimage.distance_transform_edt(mask)
    dist = ndimage.gaussian_filter(dist, smooth_px)
    gy, gx = np.gradient(dist)           # along rows (down) and columns (right)
    out = np.stack([-gx, gy], axis=-1)   # -∇d with y up: rows grow downwards
    norm = np.linalg.norm(out, axis=-1, keepdims=True)
    return np.where(norm > 1e-12, out / np.maximum(norm, 1e-12), 0.0)


def resolve_azimuth(azimuth_deg, zenith_deg, mask, confidence=None, seed_band_px: float = 2.0,
                    min_alignment: float = 0.5, window: int = 2):
    """Pick φ or φ + 180° per pixel: outwards at the occluding boundary, then inwards by
    agreement with the already-resolved neighbours (the paper's Sec. 4.3).

    1. Seeds: mask pixels within ``seed_band_px`` of the outer edge (holes do not count) whose polarization direction is
       aligned with the edge's outward direction (|cos| >= ``min_alignment``; pixels where the
       edge is not an occluding contour, such as the cut ends of a cylinder, are skipped).
       Their normals are made to point outwards.
    2. Propagation, most confident pixels first (a priority flood; confidence = sin θ times
       ``confidence``, in ten levels, ties taken in order of distance from the edge): the next pixel of the resolved set's frontier takes the candidate whose
       direction agrees with the weighted mean of the resolved normals' image-plane components
       in a (2 ``window`` + 1)² neighbourhood. Low-confidence regions (near normal incidence,
       where the azimuth is mostly noise) are thus entered last and cannot carry a wrong sign
       into well-determined regions.

    Parameters
    ----------
    azimuth_deg : (H, W) azimuth modulo 180°.
    zenith_deg : (H, W) zenith (weights: sin θ, the length of the normal's image-plane part).
    mask : (H, W) bool.
    confidence : optional (H, W) extra weights.

    Returns
    -------
    (H, W) azimuth in [0, 360); NaN outside the mask.
    """
    import heapq

    from scipy import ndimage

    mask = np.asarray(mask, dtype=bool)
    H, W = mask.shape
    phi = np.radians(np.nan_to_num(np.asarray(azimuth_deg, dtype=np.float64)))
    d = np.stack([np.cos(phi), np.sin(phi)], axis=-1)
    wgt = np.sin(np.radians(np.nan_to_num(np.asarray(zenith_deg, dtype=np.float64))))
    if confidence is not None:
        wgt = wgt * np.nan_to_num(np.asarray(confidence, dtype=np.float64))
    wgt = np.where(mask, np.maximum(wgt, 1e-9), 0.0)
    sign = np.zeros((H, W))

    # Occluding contours are the outer edge of the object: holes in the mask (e.g. where the
    # camera sees its own hole in the lighting dome) are filled before measuring "outwards".
    filled = ndimage.binary_fill_holes(mask)
    out_dir = outward_directions(filled)
    dist = ndimage.distance_transform_edt(filled)
    align = np.sum(d * out_dir, axis=-1)
    band = mask & (dist <= seed_band_px)
    seeds = band & (np.abs(align) >= min_alignment)
    if seeds.any():
        # Keep the confident half of the aligned edge pixels.
        seeds &= wgt >= np.median(wgt[seeds]) * 0.5
    labels, count = ndimage.label(mask)
    for part in range(1, count + 1):  # every part of the mask needs seeds
        inside = labels == part
        if not (seeds & inside).any():
            seeds |= band & inside
    sign[seeds] = np.where(align[seeds] >= 0, 1.0, -1.0)

    # Priority: confidence in coarse levels, then distance from the edge (so that pixels of
    # equal confidence are resolved ring by ring from the boundary inwards).
    level = np.floor(wgt / max(float(wgt.max()), 1e-12) * 10.0)
    resolved = seeds.copy()
    # Resolved normals' image-plane parts, weighted, as complex numbers x + iy, and their
    # sums over each pixel's window (kept up to date as pixels are resolved).
    dz = d[..., 0] + 1j * d[..., 1]
    v = np.where(resolved, sign * wgt * dz, 0.0)
    vp = np.pad(v, window)
    box = sum(vp[i:i + H, j:j + W] for i in range(2 * window + 1) for j in range(2 * window + 1))
    # Per-pixel scalars as flat Python lists: the flood below is sequential.
    acc = box.ravel().tolist()
    key_level = (-level).ravel().tolist()
    key_dist = dist.ravel().tolist()
    open_ = (mask & ~resolved).ravel().tolist()      # in the mask, not yet queued
    dzf = dz.ravel().tolist()
    wf = wgt.ravel().tolist()
    alf = align.ravel().tolist()
    signf = sign.ravel()
    heap = []
    push, pop = heapq.heappush, heapq.heappop
    offsets = [(dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1) if dy or dx]

    def push_neighbours(r, c):
        for dy, dx in offsets:
            rr, cc = r + dy, c + dx
            if 0 <= rr < H and 0 <= cc < W:
                k = rr * W + cc
                if open_[k]:
                    open_[k] = False
                    push(heap, (key_level[k], key_dist[k], k))

    for r, c in zip(*np.nonzero(seeds)):
        push_neighbours(int(r), int(c))
    while heap:
        k = pop(heap)[2]
        r, c = divmod(k, W)
        a = acc[k]
        dk = dzf[k]
        agree = dk.real * a.real + dk.imag * a.imag
        s = 1.0 if (agree > 0 or (agree == 0 and alf[k] >= 0)) else -1.0
        signf[k] = s
        val = s * wf[k] * dk
        c0, c1 = max(c - window, 0), min(c + window + 1, W)
        for rr in range(max(r - window, 0), min(r + window + 1, H)):
            for kk in range(rr * W + c0, rr * W + c1):
                acc[kk] += val
        push_neighbours(r, c)
    sign = signf.reshape(H, W)
    az = np.where(sign < 0, phi + np.pi, phi)
    return np.where(mask, np.mod(np.degrees(az), 360.0), np.nan)
