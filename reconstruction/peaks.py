"""Constructive-interference peaks of reflectance spectra, with sub-band precision.

A film thinner than the substrate's index (``n2 < n3``) reflects most where the round-trip
phase is a whole number of turns, ``Δ = 2π m``; there the s reflectance equals the bare
substrate's, a function of the incident angle alone (the paper's Eq. 21). This module finds
those maxima in sampled spectra, one pixel per row, all pixels at once:

1. the spectrum is smoothed along the bands with a Gaussian (noise of a few percent per band
   would otherwise make spurious maxima);
2. candidates are the interior local maxima of the smoothed spectrum that are also the largest
   value within ``±window_nm`` and rise above the smallest value within ``±2 window_nm`` by more
   than ``min_prominence`` times the pixel's noise;
3. each candidate is refined by a least-squares parabola through the *raw* samples within
   ``±fit_nm`` of it: the vertex gives the peak wavelength (between bands) and the peak value.

Maxima on the first or last band are *not* peaks (the true maximum lies outside the measured
range); such pixels, and pixels with several peaks, are reported through ``count`` and
``status`` rather than dropped.

Examples
--------
>>> import numpy as np
>>> from thinfilm.bsdf.optics import reflectances
>>> wl = np.arange(400.0, 721.0, 4.0)
>>> R_s, _ = reflectances(np.cos(np.radians(30.0)), wl, 400.0, 1.37, 1.6)
>>> p = find_peaks(R_s[None], wl)
>>> int(p.count[0]), round(float(p.wavelength_nm[0]), 1)
(1, 510.2)
>>> round(float(2 * 400.0 * np.sqrt(1.37 ** 2 - 0.5 ** 2) / 2), 1)  # Eq. 28, order m = 2
510.2
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter1d, maximum_filter1d, minimum_filter1d

__all__ = ["PeakResult", "find_peaks", "band_noise", "PEAK_OK", "PEAK_SEVERAL", "PEAK_NONE"]

#: exactly one constructive-interference peak inside the measured range
PEAK_OK = 0
#: several peaks inside the range (all reported; ``wavelength_nm``/``value`` hold the primary one)
PEAK_SEVERAL = 1
#: no peak inside the range (monotone spectrum, or the maximum sits on the first/last band)
PEAK_NONE = 2


@dataclass
class PeakResult:
    """Peaks of ``N`` spectra.

    Attributes
    ----------
    count : (N,) int
        Number of peaks found inside the measured range.
    status : (N,) int
        :data:`PEAK_OK`, :data:`PEAK_SEVERAL` or :data:`PEAK_NONE`.
    wavelength_nm, value : (N,) float
        Primary peak (the highest one): sub-band wavelength in nm and reflectance at the vertex.
        NaN where ``count == 0``.
    mean_value : (N,) float
        Mean vertex reflectance over all peaks of the pixel (NaN where none). Every
        constructive peak has the same reflectance in theory, so this is the less noisy value.
    all_wavelength_nm, all_value : (N, K) float
        Every peak, longest wavelength first, NaN-padded (``K`` = most peaks in any pixel, >= 1).
    noise : (N,) float
        Per-pixel noise estimate of one band (robust, from second differences of the raw spectrum).
    """

    count: np.ndarray
    status: np.ndarray
    wavelength_nm: np.ndarray
    value: np.ndarray
    mean_value: np.ndarray
    all_wavelength_nm: np.ndarray
    all_value: np.ndarray
    noise: np.ndarray


def band_noise(spectra):
    """Robust per-spectrum noise of one band: the median absolute second difference (about
    zero: a smooth spectrum's own second differences are far smaller than the noise's)
    × 1.4826 / sqrt(6)."""
    if spectra.shape[1] < 3:
        return np.zeros(spectra.shape[0])
    d2 = np.abs(spectra[:, 2:] - 2.0 * spectra[:, 1:-1] + spectra[:, :-2])
    k = d2.shape[1] // 2
    return 1.4826 * np.partition(d2, k, axis=1)[:, k] / np.sqrt(6.0)


def find_peaks(spectra, wavelengths_nm, smooth_nm=8.0, window_nm=20.0, fit_nm=24.0,
               min_prominence=4.0) -> PeakResult:
    """Find the constructive-interference maxima of spectra with sub-band precision.

    Parameters
    ----------
    spectra : (N, B) array_like
        Reflectance spectra, one per row, bands in the order of ``wavelengths_nm``.
    wavelengths_nm : (B,) array_like
        Band centres in nm, strictly increasing.
    smooth_nm : float
        Standard deviation of the Gaussian used to find candidates, in nm (0: no smoothing).
    window_nm : float
        A candidate must be the largest smoothed value within ``±window_nm``.
    fit_nm : float
        Largest half-width of the parabola fit around a candidate, in nm (at least 2 bands
        either side; also at most a quarter of the distance to the nearest trough).
    min_prominence : float
        Required rise of a candidate above the smallest smoothed value within
        ``±2 window_nm``, in units of the smoothed noise.

    Returns
    -------
    PeakResult
    """
    R = np.asarray(spectra, dtype=np.float64)
    wl = np.asarray(wavelengths_nm, dtype=np.float64)
    if R.ndim != 2 or R.shape[1] != wl.size:
        raise ValueError(f"spectra must be (N, {wl.size}), got {R.shape}")
    if wl.size < 5 or np.any(np.diff(wl) <= 0):
        raise ValueError("wavelengths_nm must hold at least 5 strictly increasing values")
    n, b = R.shape
    step = float(np.median(np.diff(wl)))
    sigma_b = smooth_nm / step
    S = gaussian_filter1d(R, sigma_b, axis=1, mode="nearest") if sigma_b > 0 else R
    noise = band_noise(R)
    # noise left after smoothing (white noise through a unit-area Gaussian of sigma_b bands)
    smooth_noise = noise / np.sqrt(max(1.0, 2.0 * np.sqrt(np.pi) * sigma_b))

    win = max(1, int(round(window_nm / step)))
    local = np.zeros_like(S, dtype=bool)
    local[:, 1:-1] = (S[:, 1:-1] > S[:, :-2]) & (S[:, 1:-1] >= S[:, 2:])
    local &= S >= maximum_filter1d(S, 2 * win + 1, axis=1, mode="nearest")
    base = minimum_filter1d(S, 4 * win + 1, axis=1, mode="nearest")
    local &= (S - base) > min_prominence * smooth_noise[:, None] + 1e-12
    local[:, 0] = local[:, -1] = False

    rows, cols = np.nonzero(local)
    half = max(2, int(round(fit_nm / step)))
    half = min(half, (b - 1) // 2)
    # The fit window also stays within a quarter of the distance to the nearest trough
    # (about ±π/4 of phase), so that the parabola holds for thick films with narrow peaks.
    ar = np.broadcast_to(np.arange(b), S.shape)
    lmin = np.zeros_like(local)
    lmin[:, 1:-1] = (S[:, 1:-1] <= S[:, :-2]) & (S[:, 1:-1] < S[:, 2:])
    prev_min = np.maximum.accumulate(np.where(lmin, ar, 0), axis=1)
    next_min = (b - 1) - np.maximum.accumulate(np.where(lmin, b - 1 - ar, 0)[:, ::-1], axis=1)[:, ::-1]
    dist = np.minimum(cols - prev_min[rows, cols], next_min[rows, cols] - cols)
    half_k = np.clip(np.round(0.25 * dist), 2, half).astype(int)
    # window of 2*half+1 bands (weights zero beyond the candidate's own half-width), shifted
    # inwards at the ends of the range
    start = np.clip(cols - half_k, 0, b - 1 - 2 * half_k) - (half - half_k)
    idx = start[:, None] + np.arange(2 * half + 1)[None, :]
    inwin = (idx >= start[:, None] + (half - half_k)[:, None]) & (idx <= start[:, None] + (half + half_k)[:, None])
    idx = np.clip(idx, 0, b - 1)
    # Least-squares parabola y = c0 + c1 x + c2 x² in wavenumber x = 1/λ (centred on the
    # candidate, scaled): the phase Δ is proportional to 1/λ and R is even in Δ about a peak,
    # so the parabola is symmetric there and its vertex unbiased.
    k_c = 1.0 / wl[cols]
    scale = half_k * step / wl[cols] ** 2
    xs = (1.0 / wl[idx] - k_c[:, None]) / scale[:, None]
    y = R[rows[:, None], idx]
    V = np.stack([np.ones_like(xs), xs, xs * xs], axis=-1)
    wgt = inwin.astype(np.float64)
    VtV = np.einsum("kij,ki,kil->kjl", V, wgt, V)
    Vty = np.einsum("kij,ki,ki->kj", V, wgt, y)
    coef = np.linalg.solve(VtV, Vty[..., None])[..., 0] if rows.size else np.zeros((0, 3))
    c0, c1, c2 = coef[:, 0], coef[:, 1], coef[:, 2]
    good = c2 < 0
    with np.errstate(divide="ignore", invalid="ignore"):
        xv = np.where(good, -c1 / (2.0 * c2), 0.0)
    # the vertex must lie within the fit window and inside the measured range
    good &= np.abs(xv) <= 1.0
    peak_wl = 1.0 / (k_c + xv * scale)
    good &= (peak_wl > wl[0]) & (peak_wl < wl[-1])
    peak_val = c0 + c1 * xv + c2 * xv * xv
    rows, peak_wl, peak_val = rows[good], peak_wl[good], peak_val[good]
    # two candidates refined onto the same vertex count once
    order = np.lexsort((-peak_wl, rows))
    rows, peak_wl, peak_val = rows[order], peak_wl[order], peak_val[order]
    if rows.size:
        dup = np.zeros(rows.size, dtype=bool)
        dup[1:] = (rows[1:] == rows[:-1]) & (np.abs(peak_wl[1:] - peak_wl[:-1]) < 2 * step)
        rows, peak_wl, peak_val = rows[~dup], peak_wl[~dup], peak_val[~dup]

    count = np.bincount(rows, minlength=n)
    k = max(1, int(count.max()) if n else 1)
    all_wl = np.full((n, k), np.nan)
    all_val = np.full((n, k), np.nan)
    first = np.zeros(n + 1, dtype=np.int64)
    first[1:] = np.cumsum(count)
    slot = np.arange(rows.size) - first[rows]
    all_wl[rows, slot] = peak_wl
    all_val[rows, slot] = peak_val

    with np.errstate(invalid="ignore"):
        best = np.argmax(np.where(np.isnan(all_val), -np.inf, all_val), axis=1)
        mean_value = np.nanmean(np.where(count[:, None] > 0, all_val, 0.0), axis=1)
    has = count > 0
    wavelength = np.where(has, all_wl[np.arange(n), best], np.nan)
    value = np.where(has, all_val[np.arange(n), best], np.nan)
    mean_value = np.where(has, mean_value, np.nan)
    status = np.where(count == 1, PEAK_OK, np.where(count > 1, PEAK_SEVERAL, PEAK_NONE))
    return PeakResult(count=count, status=status, wavelength_nm=wavelength, value=value,
                      mean_value=mean_value, all_wavelength_nm=all_wl, all_value=all_val,
                      noise=noise)
