"""Input checks of the spectral methods: the cube, the object mask, the physics they assume.

The methods need a dielectric substrate (``k3 = 0``): the capture ``S0 + sqrt(S1² + S2²)`` is
``max(R_s, R_p)``, which is ``R_s`` for a film on a dielectric but not on an absorbing
substrate. The paper's peak analysis needs a film optically thinner than the substrate
(``n2 < n3``); :func:`check_peak_assumption` reads that from the spectra.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from thinfilm.core.errors import UserError

from . import spectral_model as _sm
from .masks import mask_from_intensity
from .peaks import PEAK_NONE, PEAK_OK, PEAK_SEVERAL, find_peaks

__all__ = ["MIN_BANDS", "check_cube", "object_mask", "check_peak_assumption", "check_dielectric_substrate",
           "peaks_of"]

MIN_BANDS = 10


def check_cube(cube, wavelengths_nm, where="spectral_s"):
    cube = np.asarray(cube, dtype=np.float64)
    wl = np.asarray(wavelengths_nm, dtype=np.float64)
    if cube.ndim != 3:
        raise UserError(f"{where}: expected an (H, W, bands) cube, got shape {cube.shape}")
    if wl.ndim != 1 or wl.size != cube.shape[2]:
        raise UserError(f"{where}: {cube.shape[2]} bands but {wl.size} wavelengths in 'wavelengths_nm'")
    if wl.size < MIN_BANDS:
        raise UserError(f"{where}: only {wl.size} spectral bands, the spectral method needs at least {MIN_BANDS}")
    if np.any(np.diff(wl) <= 0):
        raise UserError(f"{where}: 'wavelengths_nm' must be strictly increasing")
    if not np.all(np.isfinite(cube)):
        raise UserError(f"{where}: spectra contain NaN or infinite values")
    return cube, wl


def object_mask(cube):
    """Object pixels of a spectral cube against its dark background: the project's intensity
    mask (:func:`thinfilm.reconstruction.masks.mask_from_intensity`) of the band mean."""
    return mask_from_intensity(np.asarray(cube).mean(axis=2))


def check_peak_assumption(spectra, substrate_ior, noise=None):
    """Raise :class:`UserError` when the spectra say ``n2 >= n3`` (peaks are minima).

    With ``n2 < n3`` a film's reflectance dips below the bare substrate's (the quarter-wave
    troughs; at small angles below the substrate's normal-incidence value ``R0``). With
    ``n2 > n3`` it never does: every extremum at ``e^{iΔ} = 1`` is a *minimum* equal to the
    substrate's, and Eq. 21 would read minima as peaks. The test: among pixels whose spectra
    oscillate clearly, almost none dips below ``R0``.

    Parameters
    ----------
    spectra : (N, B) object spectra.
    substrate_ior : float.
    noise : (N,) per-band noise, optional.
    """
    S = np.asarray(spectra, dtype=np.float64)
    if S.shape[0] < 20:
        return
    r0 = float(_sm.peak_reflectance(0.0, substrate_ior))
    lo = ndimage.gaussian_filter1d(S, 1.5, axis=1).min(axis=1)
    hi = ndimage.gaussian_filter1d(S, 1.5, axis=1).max(axis=1)
    nz = np.zeros(S.shape[0]) if noise is None else np.asarray(noise)
    oscillating = (hi - lo) > np.maximum(0.15 * hi, 6.0 * nz)
    if oscillating.sum() < 20:
        return
    dips = lo[oscillating] < r0 * 0.97
    if dips.mean() < 0.02:
        raise UserError(
            f"spectral_s: the spectra never dip below the bare substrate's reflectance "
            f"({r0:.4f} for substrate index {substrate_ior:g}), so the film index is not below the "
            f"substrate's and the constructive-interference peaks are minima; the spectral method "
            f"needs n2 < n3 (check --substrate-ior)")


def check_dielectric_substrate(film, where):
    """Refuse an absorbing substrate (a :class:`thinfilm.core.film.Film`): the capture is then
    ``max(R_s, R_p)``, not ``R_s``."""
    if film.absorbing_substrate:
        k = float(np.max(film.substrate_n_k(np.linspace(300.0, 1000.0, 141))[1]))
        raise UserError(f"{where}: substrate_k = {k:g} (absorbing substrate); the spectral method "
                        f"assumes a dielectric substrate, where spectral_s = S0 + sqrt(S1² + S2²) is R_s "
                        f"(on an absorbing one it is max(R_s, R_p))")


def peaks_of(cube, mask, wl):
    """Object spectra, their peaks (:func:`.peaks.find_peaks`) and peak statistics."""
    spectra = cube[mask]
    pk = find_peaks(spectra, wl)
    stats = {
        "peak_one": int(np.sum(pk.status == PEAK_OK)),
        "peak_several": int(np.sum(pk.status == PEAK_SEVERAL)),
        "peak_none": int(np.sum(pk.status == PEAK_NONE)),
    }
    return spectra, pk, stats
