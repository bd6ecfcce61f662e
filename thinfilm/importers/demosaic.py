"""Demosaicing a colour-polarization mosaic in floating point, and the pixels it cannot serve.

:func:`demosaic` turns one raw image of a colour polarization sensor (layout:
:mod:`thinfilm.core.mosaic`) into one RGB image per polarizer angle, by bilinear
interpolation of each (colour, angle) plane on its own lattice:

* a plane sampled once per period (red and blue: every 4th row and column) is interpolated
  bilinearly between its four surrounding samples;
* a plane sampled on a checkerboard of two lattices (green) is interpolated bilinearly on the
  checkerboard's own 45° axes, i.e. between the four nearest samples of the diamond around the
  pixel.

Both are written as normalized convolutions (weights renormalized where samples are missing, at
the image border), in float64: no value is rescaled or rounded, and every sampled pixel keeps its
value exactly. Interpolation in the raw domain is linear, so it commutes with the per-colour
white-balance gains.

Why bilinear: on the project's datasets, a cubic (Keys) interpolant is more accurate on
noise-free smooth images but carries more noise into the polarization channels, and the
reconstructions through the mosaic came out better with the bilinear one
(``benchmarks/bench_mosaic.py`` prints both).

Two kinds of output pixel cannot be trusted (:func:`footprint`, :func:`edge_pixels`):

* those whose interpolation used a saturated sample;
* those whose interpolation reaches across a high-contrast edge — the silhouette of a lit object
  against a dark background: the four polarizer planes of such a pixel come from different
  sides of the edge, and their differences (the polarization) are meaningless there. Such
  pixels are found on a polarization-insensitive intensity image (the largest plane-normalized
  value in each 2 × 2 window, which always holds a polarizer angle within 45° of the light's
  polarization), split into dark and lit on its logarithm (Otsu's classes, split halfway
  between their medians) when the two classes lie more than a decade apart, and marked within
  the interpolation reach of the split (plus a margin).
"""

from __future__ import annotations

import numpy as np

from thinfilm.core.masks import otsu_threshold

__all__ = ["demosaic", "footprint", "edge_pixels"]


def _kernel_weight(pattern, checker: bool, dr, dc, widen: int = 1):
    P, Q = (widen * n for n in pattern.shape)
    x, y = dr / P, dc / Q
    if not checker:
        return max(0.0, 1.0 - abs(x)) * max(0.0, 1.0 - abs(y))
    return max(0.0, 1.0 - abs(x + y)) * max(0.0, 1.0 - abs(x - y))


def _interpolate(values, pattern, sites, widen: int = 1):
    """Normalized convolution of the samples of one plane with its kernel, computed phase by
    phase of the period (every output pixel of a phase sees the same sample offsets): returns
    (numerator, weight sum), both (H, W)."""
    values = np.asarray(values, dtype=np.float64)
    H, W = values.shape
    P, Q = pattern.shape
    checker = len(sites) > 1
    reach = widen + 1
    rows, cols = -(-H // P) + 2 * reach + 1, -(-W // Q) + 2 * reach + 1
    num = np.zeros((H, W))
    den = np.zeros((H, W))
    grids = []
    for r0, c0 in sites:
        sub = values[r0::P, c0::Q]
        g = np.zeros((rows, cols))
        v = np.zeros((rows, cols))
        g[reach:reach + sub.shape[0], reach:reach + sub.shape[1]] = sub
        v[reach:reach + sub.shape[0], reach:reach + sub.shape[1]] = 1.0
        grids.append((r0, c0, g, v))
    for pr in range(min(P, H)):
        n_r = len(range(pr, H, P))
        for pc in range(min(Q, W)):
            n_c = len(range(pc, W, Q))
            acc = np.zeros((n_r, n_c))
            wsum = np.zeros((n_r, n_c))
            for r0, c0, g, v in grids:
                for di in range(-reach, reach + 1):
                    for dj in range(-reach, reach + 1):
                        w = _kernel_weight(pattern, checker, r0 + P * di - pr, c0 + Q * dj - pc, widen)
                        if w <= 0.0:
                            continue
                        sl = (slice(reach + di, reach + di + n_r), slice(reach + dj, reach + dj + n_c))
                        acc += w * g[sl]
                        wsum += w * v[sl]
            num[pr::P, pc::Q] = acc
            den[pr::P, pc::Q] = wsum
    return num, den


def _plane(values, pattern, sites):
    """Bilinear interpolation of one plane (see the module docstring), float64."""
    num, den = _interpolate(values, pattern, sites)
    empty = den <= 1e-12
    if empty.any():  # image corners the kernel does not reach from any sample
        num2, den2 = _interpolate(values, pattern, sites, widen=2)
        num, den = np.where(empty, num2, num), np.where(empty, den2, den)
    return num / np.where(den > 1e-12, den, 1.0)


def _plane_mask(shape, pattern, sites) -> np.ndarray:
    P, Q = pattern.shape
    m = np.zeros(shape, dtype=bool)
    for r0, c0 in sites:
        m[r0::P, c0::Q] = True
    return m


def demosaic(raw, pattern) -> dict:
    """One RGB image per polarizer angle from a colour-polarization mosaic.

    Parameters
    ----------
    raw : (H, W) array
        The mosaic (any linear units: digital numbers, or values already calibrated).
    pattern : :class:`thinfilm.core.mosaic.MosaicPattern`

    Returns
    -------
    dict
        angle (degrees) → (H, W, 3) float64; at each pixel sampled for a (colour, angle) the
        value is the sample itself.

    Examples
    --------
    >>> from thinfilm.core.mosaic import parse_pattern, DEFAULT_PATTERN, mosaic_from_images
    >>> p = parse_pattern(DEFAULT_PATTERN)
    >>> yy, xx = np.mgrid[0:16, 0:16]
    >>> images = {a: np.stack([1 + 0.1 * xx + 0.2 * yy + a] * 3, axis=-1) for a in p.angles}
    >>> out = demosaic(mosaic_from_images(images, p), p)
    >>> bool(np.allclose(out[45][4:12, 4:12], images[45][4:12, 4:12]))   # exact for linear images
    True
    """
    raw = np.asarray(raw, dtype=np.float64)
    if raw.ndim != 2:
        raise ValueError(f"a mosaic is one 2-D image, got shape {raw.shape}")
    out = {a: np.zeros(raw.shape + (3,)) for a in pattern.angles}
    for a in pattern.angles:
        for c in range(3):
            sites = pattern.lattices(c, a)
            m = _plane_mask(raw.shape, pattern, sites)
            v = _plane(raw, pattern, sites)
            v[m] = raw[m]
            out[a][..., c] = v
    return out


def footprint(samples, pattern) -> np.ndarray:
    """Output pixels whose interpolation, in any plane, used one of the flagged ``samples``
    ((H, W) bool, e.g. saturated ones)."""
    samples = np.asarray(samples, dtype=bool)
    hit = samples.copy()
    if not samples.any():
        return hit
    for a in pattern.angles:
        for c in range(3):
            hit |= _plane(samples.astype(np.float64), pattern, pattern.lattices(c, a)) > 0
    return hit


def edge_pixels(raw, pattern, margin: int = 2) -> np.ndarray:
    """Pixels within the interpolation reach (plus ``margin``) of a dark/lit split of the
    scene (see the module docstring); all False when the image is not split into a dark
    background and a lit object a decade or more brighter.

    Parameters
    ----------
    raw : (H, W) mosaic, linear, dark level removed.
    pattern : :class:`thinfilm.core.mosaic.MosaicPattern`
    """
    from scipy import ndimage

    raw = np.asarray(raw, dtype=np.float64)
    colour, angle = pattern.maps(raw.shape)
    index = colour * 1000 + angle
    level = np.ones(raw.shape)
    for key in np.unique(index):
        sel = index == key
        mean = raw[sel].mean()
        level[sel] = mean if mean > 0 else 1.0
    bright = ndimage.maximum_filter(raw / level, size=2, mode="nearest")
    pos = bright > 0
    if pos.sum() < 16:
        return np.zeros(raw.shape, dtype=bool)
    floor = max(float(np.percentile(bright[pos], 0.1)) * 1e-2, 1e-12)
    lb = np.log10(np.maximum(bright, floor))
    t = otsu_threshold(lb.ravel())
    lo, hi = lb[lb <= t], lb[lb > t]
    if lo.size == 0 or hi.size == 0 or np.median(hi) - np.median(lo) < 1.0:
        return np.zeros(raw.shape, dtype=bool)
    # Otsu's threshold only separates the classes (it may sit at the edge of a tight one):
    # split halfway between their medians, in the gap
    lit = lb > 0.5 * (np.median(lo) + np.median(hi))
    P, Q = pattern.shape
    reach = np.ones((2 * (P - 1 + margin) + 1, 2 * (Q - 1 + margin) + 1), dtype=bool)
    return ndimage.binary_dilation(lit, reach) & ndimage.binary_dilation(~lit, reach)
