"""The paper's spectral method as published (Kobayashi et al., Sec. 6).

1. peak (constructive interference, ``e^{iΔ} = 1``) per pixel; the incident angle from the
   peak reflectance by inverting Eq. 21 (monotone in θ);
2. normals by Horn's characteristic strip expansion (Sec. 6.2,
   :func:`thinfilm.reconstruction.eikonal.characteristic_strips`);
3. ``n2`` and ``d`` per pixel by the integer-order search of Eqs. 28–30: ``n2`` from 1.00 to
   ``n3`` in steps of 0.01, every order ``m`` with ``d = m λ_peak / (2 sqrt(n2² - sin² θ))``
   below 1000 nm, least squares over the whole spectrum; the object's ``n2`` is the median.

Pixels without a peak in the measured range get no angle and stay invalid.
"""

from __future__ import annotations

import time

import numpy as np

from thinfilm.core.io import Estimate

from . import eikonal as _eik
from . import spectral_model as _sm
from .spectral_checks import check_peak_assumption, peaks_of
from .spectral_fit import MAX_THICKNESS_NM, film_ior_grid, order_candidates, thickness_limits

__all__ = ["kobayashi_search", "reconstruct_kobayashi"]


def kobayashi_search(spectra, theta_rad, peak_wl_nm, substrate_ior, wavelengths_nm,
                     max_thickness_nm=MAX_THICKNESS_NM, limits=None):
    """The paper's per-pixel search (Eqs. 28–30) over ``n2`` ∈ {1.00, 1.01, …} < n3 and orders m
    (thickness below ``max_thickness_nm``, or within the
    :class:`~.spectral_fit.ThicknessRange` ``limits``).

    Returns
    -------
    film_ior, thickness_nm, sse : (N,) arrays (NaN where the pixel has no peak).
    """
    S = np.asarray(spectra, dtype=np.float64)
    th = np.asarray(theta_rad, dtype=np.float64)
    lam = np.asarray(peak_wl_nm, dtype=np.float64)
    n = S.shape[0]
    out_n2 = np.full(n, np.nan)
    out_d = np.full(n, np.nan)
    out_e = np.full(n, np.nan)
    ok = np.isfinite(th) & np.isfinite(lam)
    if not ok.any():
        return out_n2, out_d, out_e
    grid = film_ior_grid(substrate_ior)
    if limits is None:
        d, n2, _ = order_candidates(th[ok], lam[ok], grid, max_thickness_nm)
    else:
        d, n2, _ = order_candidates(th[ok], lam[ok], grid, limits.hi, limits.lo, limits.max_optical_nm)
    sse = _sm.grid_sse(S[ok], th[ok], d, n2, substrate_ior, wavelengths_nm)
    best = np.argmin(sse, axis=1)
    rows = np.arange(best.size)
    out_n2[ok] = n2[rows, best]
    out_d[ok] = d[rows, best]
    out_e[ok] = sse[rows, best]
    return out_n2, out_d, out_e


def reconstruct_kobayashi(cube, wavelengths_nm, substrate_ior, mask, thickness_range_nm=None, band_fwhm_nm=0.0):
    """The paper's method as published (see the module docstring), its (n2, m) search over
    ``thickness_range_nm`` (default: the paper's span, up to :data:`.spectral_fit.MAX_THICKNESS_NM`;
    cut to what the bands resolve)."""
    limits = thickness_limits(wavelengths_nm, thickness_range_nm or (0.0, MAX_THICKNESS_NM), band_fwhm_nm)
    t = {}
    t0 = time.perf_counter()
    spectra, pk, stats = peaks_of(cube, mask, wavelengths_nm)
    check_peak_assumption(spectra, wavelengths_nm, substrate_ior)
    theta = _sm.angle_from_peak(pk.value, substrate_ior)
    t["peaks_and_angle"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    theta_img = np.full(mask.shape, np.nan)
    theta_img[mask] = theta
    normals, reached, height = _eik.characteristic_strips(theta_img, mask)
    t["normals_strips"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    n2_px, d_px, _ = kobayashi_search(spectra, theta, pk.wavelength_nm, substrate_ior, wavelengths_nm,
                                      limits=limits)
    t["search_n2_m"] = time.perf_counter() - t0
    film_ior = float(np.nanmedian(n2_px)) if np.isfinite(n2_px).any() else float("nan")
    if np.isfinite(film_ior):
        limits.warn_if_cut(film_ior)

    thickness = np.full(mask.shape, np.nan)
    thickness[mask] = d_px
    valid = mask & reached & np.isfinite(thickness)
    info = {"peaks": stats, "timings_s": t,
            "thickness_range_nm": [limits.lo, limits.upper(film_ior) if np.isfinite(film_ior) else limits.hi]}
    return Estimate(normals=normals, thickness_nm=thickness, valid=valid, film_ior=film_ior,
                    substrate_ior=float(substrate_ior), height=height, info=info)
