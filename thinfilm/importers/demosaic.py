"""Demosaicing a colour-polarization mosaic in floating point, and the pixels it cannot serve.

:func:`demosaic` turns one raw image of a colour polarization sensor (layout:
:mod:`thinfilm.core.mosaic`) into one RGB image per polarizer angle. Two methods
(:data:`METHODS`, ``thinfilm import polarization --demosaic``):

``residual`` (default)
    Polarization- and colour-aware residual interpolation, mask-aware at the object's
    silhouette (:func:`residual_demosaic`). It follows the residual-interpolation scheme of
    Kiku, Monno, Tanaka and Okutomi, *Residual interpolation for color image demosaicking*
    (ICIP 2013), in the form Morimatsu, Monno, Tanaka and Okutomi give it for colour
    polarization filter arrays in *Monochrome and Color Polarization Demosaicking Using
    Edge-Aware Residual Interpolation* (ICIP 2020, arXiv:2007.14292): a dense,
    polarization-insensitive intensity image guides the interpolation of every (colour,
    angle) plane, and only the residual between the samples and the guided estimate is
    interpolated bilinearly. Our guide is built from the physics of a linear polarizer rather
    than from their edge detector: each sample is divided by its own polarizer's smooth
    Malus-law modulation ``1 + q1 cos 2α + q2 sin 2α`` (``q = (S1, S2) / S0``, which varies
    slowly over a surface), so that every sample of a colour, whatever its polarizer, becomes
    a sample of that colour's intensity ``S0``: four times denser than one plane; the
    colours share the direction of polarization (that of the most densely sampled colour),
    which a specular reflection has at every wavelength. Where a
    mask of the object is given or found (:func:`object_mask`), every step interpolates
    each pixel from samples on its own side of the silhouette only, so the object keeps
    its edge: the importer marks invalid only the object's outermost
    :data:`DEFAULT_EDGE_MARGIN` pixels (``--edge-margin``; 0 keeps them all), where a curved
    object's limb changes faster than one side's samples follow, instead of a band on both
    sides of the silhouette as wide as the bilinear reach plus a margin.
``bilinear``
    Bilinear interpolation of each (colour, angle) plane on its own lattice, for comparison
    (and the behaviour of earlier versions):

    * a plane sampled once per period (red and blue: every 4th row and column) is
      interpolated bilinearly between its four surrounding samples;
    * a plane sampled on a checkerboard of two lattices (green) is interpolated bilinearly
      on the checkerboard's own 45° axes, i.e. between the four nearest samples of the
      diamond around the pixel.

Both are normalized convolutions (weights renormalized where samples are missing, at the image
border or across the silhouette), in float64: no value is rescaled or rounded, and every
sampled pixel keeps its value exactly. Both are linear in the raw values or (``residual``)
invariant to a per-colour gain, so they commute with the white-balance gains.

Two kinds of output pixel cannot be trusted (:func:`footprint`, :func:`edge_pixels`):

* those whose bilinear interpolation would use a saturated sample (the ``residual`` method
  leaves such samples out of every step, the bilinear one uses them);
* with ``bilinear`` only, those whose interpolation reaches across a high-contrast edge — the
  silhouette of a lit object against a dark background: the four polarizer planes of such a
  pixel come from different sides of the edge, and their differences (the polarization) are
  meaningless there. Such pixels are found on a polarization-insensitive intensity image (the
  largest plane-normalized value in each 2 × 2 window, which always holds a polarizer angle
  within 45° of the light's polarization), split into dark and lit on its logarithm (Otsu's
  classes, split halfway between their medians) when the two classes lie more than a decade
  apart, and marked within the interpolation reach of the split (plus a margin).
"""

from __future__ import annotations

import numpy as np

from thinfilm.core.masks import otsu_threshold

__all__ = ["METHODS", "DEFAULT_METHOD", "DEFAULT_EDGE_MARGIN", "demosaic", "residual_demosaic", "object_mask",
           "silhouette_band", "footprint", "edge_pixels"]

#: demosaicing methods of :func:`demosaic` (``--demosaic``)
METHODS = ("residual", "bilinear")
#: the default method: bilinear, which on rendered captures (``benchmarks/bench_mosaic.py``,
#: 64 px presets, 4 x 4 and 2 x 2 raw pixels per pixel) keeps the normals and thickness closer
#: to the direct captures' than ``residual`` does (which is the more accurate one on smooth
#: analytic fields, and keeps more of the silhouette)
DEFAULT_METHOD = "bilinear"
#: object pixels within this many pixels of the silhouette (chessboard distance) that the
#: ``residual`` method marks invalid by default: a curved object's limb changes faster there
#: than any interpolation from one side follows (on the presets, the polarization of the
#: first three pixels is off by a third to all of the signal, that of the next ones by a
#: sixth of it, as bilinear's is in the interior)
DEFAULT_EDGE_MARGIN = 3


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


def demosaic(raw, pattern, method: str = DEFAULT_METHOD, mask=None, exclude=None) -> dict:
    """One RGB image per polarizer angle from a colour-polarization mosaic.

    Parameters
    ----------
    raw : (H, W) array
        The mosaic (any linear units: digital numbers, or values already calibrated).
    pattern : :class:`thinfilm.core.mosaic.MosaicPattern`
    method : one of :data:`METHODS` (see the module docstring).
    mask, exclude : for ``residual`` (:func:`residual_demosaic`): the object's pixels, and
        samples to leave out (saturated ones); ignored by ``bilinear``.

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
    >>> out = demosaic(mosaic_from_images(images, p), p, "bilinear")
    >>> bool(np.allclose(out[45][4:12, 4:12], images[45][4:12, 4:12]))   # exact for linear images
    True
    >>> S0 = 1 + 0.1 * xx + 0.2 * yy                 # a linear intensity, uniformly polarized
    >>> images = {a: np.stack([0.5 * S0 * (1 + 0.3 * np.cos(np.radians(2 * a) - 1))] * 3, -1) for a in p.angles}
    >>> out = demosaic(mosaic_from_images(images, p), p, "residual")      # residual: exact everywhere
    >>> bool(np.allclose(out[45], images[45]))
    True
    """
    raw = np.asarray(raw, dtype=np.float64)
    if raw.ndim != 2:
        raise ValueError(f"a mosaic is one 2-D image, got shape {raw.shape}")
    if method not in METHODS:
        raise ValueError(f"demosaicing method must be one of {', '.join(METHODS)}, got {method!r}")
    if method == "residual":
        return residual_demosaic(raw, pattern, mask=mask, exclude=exclude)[0]
    out = {a: np.zeros(raw.shape + (3,)) for a in pattern.angles}
    for a in pattern.angles:
        for c in range(3):
            sites = pattern.lattices(c, a)
            m = _plane_mask(raw.shape, pattern, sites)
            v = _plane(raw, pattern, sites)
            v[m] = raw[m]
            out[a][..., c] = v
    return out


# -- residual interpolation ---------------------------------------------------------------------

#: half-width of the tent window of the local fit of a colour's intensity, in periods of the
#: pattern (a window of 7 x 7 pixels for a 4 x 4 period)
_S0_HALF_WIDTH = 1.0
#: the Malus-law modulation of a polarizer is never taken below this (a sample behind a
#: polarizer crossed with fully polarized light carries no intensity information)
_MIN_MODULATION = 0.02
#: Gaussian σ (in periods of the pattern) of the local means whose ratios give the smooth
#: polarization q = (S1, S2) / S0, one per pass: the first from the bilinear planes, the next
#: from the previous pass's planes
_Q_SIGMAS = (0.25,)
#: Gaussian σ (in periods) of the local means whose ratio gives each colour's degree of
#: polarization relative to the densest colour's
_DOLP_SIGMA = 1.0


def _plane_kernel(pattern, checker: bool, widen: int = 1) -> np.ndarray:
    P, Q = pattern.shape
    rr = range(-(widen * P - 1), widen * P)
    cc = range(-(widen * Q - 1), widen * Q)
    return np.array([[_kernel_weight(pattern, checker, dr, dc, widen) for dc in cc] for dr in rr])


def _correlate(x, kernel):
    from scipy import ndimage

    return ndimage.correlate(x, kernel, mode="constant", cval=0.0)


def _correlate_separable(x, k_rows, k_cols):
    from scipy import ndimage

    x = ndimage.correlate1d(x, k_rows, axis=0, mode="constant", cval=0.0)
    return ndimage.correlate1d(x, k_cols, axis=1, mode="constant", cval=0.0)


def _masked_plane(values, samples, pattern, checker: bool):
    """Bilinear normalized convolution of the ``samples`` (bool (H, W)) of one plane, with
    the plane's kernel; where the kernel's window is only partly covered by samples (at the
    silhouette, at the image border) the local weighted least-squares plane through the
    samples of a window of two periods instead (first-order normalized
    convolution), which extrapolates a gradient instead of flattening it: (values, served)."""
    K = _plane_kernel(pattern, checker)
    w = samples.astype(np.float64)
    num, den = _correlate(values * w, K), _correlate(w, K)
    P, Q = pattern.shape
    lattice_sum = float(K.sum()) / (P * Q) * (2 if checker else 1)
    partial = den < lattice_sum * (1.0 - 1e-6)
    out = num / np.where(den > 1e-12, den, 1.0)
    served = den > 1e-12
    if partial.any():
        fit, ok = _local_linear_fit(values, np.ones_like(w), samples, 2.0 * max(P, Q), wide_fallback=False)
        out = np.where(partial & ok, fit, out)
        served = served | (partial & ok)
    return out, served


def _local_linear_fit(raw, gain, samples, half_width: float, wide_fallback: bool = True):
    """First-order normalized convolution (Knutsson and Westin, 1993): at every pixel the
    weighted least-squares fit of ``raw_i ≈ gain_i (β0 + β1 dr_i + β2 dc_i)`` over the
    ``samples`` i in a tent window of ``half_width`` pixels; returns (β0, served). Exact for
    a linear intensity; slopes that the window's samples do not determine shrink to zero."""
    r = int(np.ceil(half_width)) - 1 if float(half_width).is_integer() else int(np.floor(half_width))
    d = np.arange(-r, r + 1, dtype=np.float64)
    t = np.clip(1.0 - np.abs(d) / half_width, 0.0, None)
    w = samples * gain * gain
    y = samples * gain * raw
    # moments of the window (correlation: the kernel offsets are sample minus pixel); the tent
    # window and the monomials are separable: one pass along the rows, one along the columns
    m = {k: _correlate_separable(w, t * d ** pr, t * d ** pc) for k, pr, pc in
         (("1", 0, 0), ("r", 1, 0), ("c", 0, 1), ("rr", 2, 0), ("rc", 1, 1), ("cc", 0, 2))}
    b = np.stack([_correlate_separable(y, t, t), _correlate_separable(y, t * d, t),
                  _correlate_separable(y, t, t * d)], axis=-1)
    A = np.stack([np.stack([m["1"], m["r"], m["c"]], -1),
                  np.stack([m["r"], m["rr"], m["rc"]], -1),
                  np.stack([m["c"], m["rc"], m["cc"]], -1)], axis=-2)
    served = m["1"] > 1e-12 * max(float(m["1"].max()), 1e-300)
    ridge = 1e-6 * np.where(served, m["1"], 1.0)
    A[..., 1, 1] += ridge
    A[..., 2, 2] += ridge
    A[~served] = np.eye(3)
    b[~served] = 0.0
    beta = np.linalg.solve(A, b[..., None])[..., 0]
    if wide_fallback:
        # a window whose samples lie on one row or one column cannot extrapolate a slope
        # across it (at the image border, beside the silhouette): refit on a window of twice
        # the width there
        m1 = np.where(served, m["1"], 1.0)
        spread = np.minimum(m["rr"] / m1 - (m["r"] / m1) ** 2, m["cc"] / m1 - (m["c"] / m1) ** 2)
        flat = served & (spread < 0.25)
        if flat.any():
            wide, ok = _local_linear_fit(raw, gain, samples, 2.0 * half_width, wide_fallback=False)
            beta[..., 0] = np.where(flat & ok, wide, beta[..., 0])
    return beta[..., 0], served


def _smooth(x, sigma):
    from scipy import ndimage

    return ndimage.gaussian_filter(x, sigma, mode="constant", cval=0.0, truncate=3.0)


def _residual_side(raw, pattern, use, use_side):
    """The residual method's images from the samples ``use`` only (``use_side``: the pixels
    of the side): (dict, served)."""
    shape = raw.shape
    angles = pattern.angles
    colour_map, angle_map = pattern.maps(shape)
    out = {a: np.zeros(shape + (3,)) for a in angles}
    served = np.ones(shape, dtype=bool)
    P, Q = pattern.shape
    inside = use_side.astype(np.float64)
    planes, masks = {}, {}
    for c in range(3):
        planes[c], masks[c] = [], []
        for a in angles:
            sites = pattern.lattices(c, a)
            m = _plane_mask(shape, pattern, sites) & use
            v, ok = _masked_plane(raw, m, pattern, len(sites) > 1)
            planes[c].append(v)
            masks[c].append((m, len(sites) > 1))
            served &= ok
    # the colour sampled most densely gives the direction of the polarization (the plane of
    # incidence, the same at every wavelength); each colour scales it by its own degree
    dense = max(range(3), key=lambda c: int((colour_map == c).sum()))
    q_dense = _polarization(planes[dense], inside, angles, _Q_SIGMAS[0] * max(P, Q))
    dolp_dense = np.hypot(*_polarization(planes[dense], inside, angles, _DOLP_SIGMA * max(P, Q)))
    for c in range(3):
        if c == dense:
            q = q_dense
        else:
            dolp = np.hypot(*_polarization(planes[c], inside, angles, _DOLP_SIGMA * max(P, Q)))
            ratio = np.clip(dolp / np.maximum(dolp_dense, 1e-6), 0.0, 4.0)
            q = (q_dense[0] * ratio, q_dense[1] * ratio)
        col = (colour_map == c) & use
        out_c, ok = _guided_planes(raw, q, masks[c], col, colour_map == c, angle_map, angles, pattern)
        served &= ok
        for k, a in enumerate(angles):
            out[a][..., c] = out_c[k]
    return out, served


def _polarization(planes, inside, angles, sigma):
    """q = (S1, S2) / S0 of one colour's planes: the ratio of their Gaussian local means over
    the side's pixels (q varies slowly, S0 need not)."""
    from thinfilm.core.conventions import fit_stokes

    S0b, S1b, S2b = fit_stokes(np.stack(planes), angles)
    S0s, S1s, S2s = (_smooth(v * inside, sigma) if sigma > 0 else v for v in (S0b, S1b, S2b))
    pos = S0s > 0
    return (np.where(pos, S1s / np.where(pos, S0s, 1.0), 0.0), np.where(pos, S2s / np.where(pos, S0s, 1.0), 0.0))


def _guided_planes(raw, q, masks, col, colour_sel, angle_map, angles, pattern):
    """Steps 2-3 of :func:`residual_demosaic` for one colour of polarization ``q``:
    (planes, served)."""
    P, Q = pattern.shape
    q1, q2 = q
    norm = np.hypot(q1, q2)
    shrink = np.where(norm > 1.0 - _MIN_MODULATION, (1.0 - _MIN_MODULATION) / np.maximum(norm, 1e-300), 1.0)
    q1, q2 = q1 * shrink, q2 * shrink
    rad = np.radians(np.asarray(angles, dtype=np.float64))
    modulation = [0.5 * (1.0 + q1 * np.cos(2 * t) + q2 * np.sin(2 * t)) for t in rad]
    # every sample of the colour, divided by its polarizer's modulation, samples S0
    gain = np.zeros(raw.shape)
    for k, a in enumerate(angles):
        sel = colour_sel & (angle_map == a)
        gain[sel] = modulation[k][sel]
    S0, served = _local_linear_fit(raw, gain, col, _S0_HALF_WIDTH * max(P, Q))
    # the guided estimate of each plane, and the bilinear interpolation of its residual
    out = []
    for k in range(len(angles)):
        tentative = modulation[k] * S0
        m, checker = masks[k]
        res, _ = _masked_plane(raw - tentative, m, pattern, checker)
        out.append(tentative + res)
    return out, served


def residual_demosaic(raw, pattern, mask=None, exclude=None):
    """Polarization- and colour-aware residual interpolation (see the module docstring).

    Steps, for each (colour, angle) plane, from the samples of the pixel's own side of the
    silhouette only:

    1. bilinear interpolation of every plane (at the silhouette and the image border, where
       the bilinear window is only partly covered, a local least-squares plane that
       extrapolates the gradient), and from those the smooth polarization ``q = (S1, S2) /
       S0``: the ratio of Gaussian local means of the least-squares Stokes fit over the
       angles. Its direction (the plane of incidence of a specular reflection, the same at
       every wavelength) comes from the most densely sampled colour (green, σ a quarter
       period); each other colour scales it by the ratio of its degree of polarization to
       green's (σ one period);
    2. every sample of the colour divided by its polarizer's modulation
       ``½ (1 + q1 cos 2α + q2 sin 2α)`` samples the colour's intensity ``S0``: ``S0`` at
       every pixel is the local weighted least-squares plane through them (first-order
       normalized convolution, a 7 × 7 tent window for a 4 × 4 period, twice that where the
       samples of the window do not fix a slope), the samples weighted by the square of their
       modulation;
    3. the guided estimate of the plane is its modulation times ``S0``; the residual between
       the plane's samples and that estimate is interpolated bilinearly and added back, so
       every sample keeps its value.

    Parameters
    ----------
    raw : (H, W) mosaic, linear.
    pattern : :class:`thinfilm.core.mosaic.MosaicPattern`
    mask : (H, W) bool, optional
        The object's pixels: those inside are interpolated from samples inside, those outside
        from samples outside. None: one side (the whole image).
    exclude : (H, W) bool, optional
        Samples left out of every step (saturated ones); their pixels keep their sample.

    Returns
    -------
    (images, unserved)
        angle → (H, W, 3) float64, and the (H, W) pixels that some plane could not serve
        (no sample of it on their side within twice the kernel's reach).
    """
    raw = np.asarray(raw, dtype=np.float64)
    if raw.ndim != 2:
        raise ValueError(f"a mosaic is one 2-D image, got shape {raw.shape}")
    avail = np.ones(raw.shape, dtype=bool) if exclude is None else ~np.asarray(exclude, dtype=bool)
    sides = [np.ones(raw.shape, dtype=bool)]
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != raw.shape:
            raise ValueError(f"the mask has shape {mask.shape}, the mosaic {raw.shape}")
        if mask.any() and (~mask).any():
            sides = [mask, ~mask]
    out = {a: np.zeros(raw.shape + (3,)) for a in pattern.angles}
    unserved = np.zeros(raw.shape, dtype=bool)
    for side in sides:
        images, served = _residual_side(raw, pattern, avail & side, side)
        for a in out:
            out[a][side] = images[a][side]
        unserved |= side & ~served
    colour_map, angle_map = pattern.maps(raw.shape)
    for a in pattern.angles:
        sel = angle_map == a
        out[a][sel, colour_map[sel]] = raw[sel]
    return out, unserved


def silhouette_band(mask, margin: int) -> np.ndarray:
    """The object pixels (``mask``) within ``margin`` pixels (chessboard distance) of a
    background pixel; none for ``margin`` 0."""
    from scipy import ndimage

    mask = np.asarray(mask, dtype=bool)
    if margin <= 0 or mask.all() or not mask.any():
        return np.zeros(mask.shape, dtype=bool)
    return mask & ~ndimage.binary_erosion(mask, np.ones((3, 3), dtype=bool), iterations=int(margin), border_value=1)


def object_mask(raw, pattern):
    """The lit object's pixels of a mosaic of a lit object before a dark background, or None
    when the image is not split into two classes a decade or more apart (see the module
    docstring: the classes of the 2 × 2 window maxima). A pixel is the object's when its own
    plane-normalized value lies on the lit side of the split, or when at least three of its
    four direct neighbours do (a sample behind a polarizer crossed with strongly polarized
    light is dark inside the object)."""
    from scipy import ndimage

    split = _split(raw, pattern)
    if split is None:
        return None
    value, threshold = split
    lit = np.log10(np.maximum(value, 1e-300)) > threshold
    cross = np.array([[0, 1, 0], [1, 0, 1], [0, 1, 0]])
    neighbours = ndimage.correlate(lit.astype(np.int64), cross, mode="nearest")
    return lit | (neighbours >= 3)


def _split(raw, pattern):
    """(plane-normalized values, log10 threshold between dark and lit) of a mosaic, or None
    when it is not split a decade or more."""
    from scipy import ndimage

    raw = np.asarray(raw, dtype=np.float64)
    colour, angle = pattern.maps(raw.shape)
    index = colour * 1000 + angle
    level = np.ones(raw.shape)
    for key in np.unique(index):
        sel = index == key
        mean = raw[sel].mean()
        level[sel] = mean if mean > 0 else 1.0
    value = raw / level
    bright = ndimage.maximum_filter(value, size=2, mode="nearest")
    pos = bright > 0
    if pos.sum() < 16:
        return None
    floor = max(float(np.percentile(bright[pos], 0.1)) * 1e-2, 1e-12)
    lb = np.log10(np.maximum(bright, floor))
    t = otsu_threshold(lb.ravel())
    lo, hi = lb[lb <= t], lb[lb > t]
    if lo.size == 0 or hi.size == 0 or np.median(hi) - np.median(lo) < 1.0:
        return None
    # Otsu's threshold only separates the classes (it may sit at the edge of a tight one):
    # split halfway between their medians, in the gap
    return value, 0.5 * (np.median(lo) + np.median(hi))


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
    """Pixels within the bilinear interpolation reach (plus ``margin``) of a dark/lit split
    of the scene (see the module docstring); all False when the image is not split into a
    dark background and a lit object a decade or more brighter.

    Parameters
    ----------
    raw : (H, W) mosaic, linear, dark level removed.
    pattern : :class:`thinfilm.core.mosaic.MosaicPattern`
    """
    from scipy import ndimage

    split = _split(raw, pattern)
    if split is None:
        return np.zeros(np.shape(raw), dtype=bool)
    value, threshold = split
    bright = ndimage.maximum_filter(value, size=2, mode="nearest")
    pos = bright > 0
    floor = max(float(np.percentile(bright[pos], 0.1)) * 1e-2, 1e-12)
    lit = np.log10(np.maximum(bright, floor)) > threshold
    P, Q = pattern.shape
    reach = np.ones((2 * (P - 1 + margin) + 1, 2 * (Q - 1 + margin) + 1), dtype=bool)
    return ndimage.binary_dilation(lit, reach) & ndimage.binary_dilation(~lit, reach)
